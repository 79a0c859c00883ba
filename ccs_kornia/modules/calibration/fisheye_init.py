"""Fisheye initialisation without an intrinsic guess: focal-length hypotheses kept in a batch.

For each hypothesis ``f`` (a geometric grid), the camera is the equidistant fisheye ``r = f theta`` (Kannala–Brandt
with ``k = 0``) centred on the image. The corners are lifted to unit viewing rays and each view's board-to-ray
homography is fitted by a DLT on the cross-product constraint ``[ray]_x H [X, Y, 1]^T = 0``: unlike a homography
to the normalised image plane this stays valid for rays at and beyond 90 degrees from the axis, so steep views
and boards at the rim of a 200-degree lens initialise like any other. ``H = lambda [r1 r2 t]`` then gives the
pose. Each hypothesis is scored by the reprojection error of its poses; the best few (local minima of the score
over ``f``) are kept for the Levenberg–Marquardt refinement, which runs them as extra cameras of its batch.
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.camera import Camera, rotation_matrix_to_axis_angle
from ccs_kornia.geometry.models.factory import FISHEYE
from ccs_kornia.runtime.checks import broadcast_shapes, check_shape, check_tensor

__all__ = ["board_to_ray_poses", "focal_hypotheses", "init_fisheye"]


def board_to_ray_poses(
    rays: torch.Tensor, object_xy: torch.Tensor, weights: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Pose of a planar board from unit viewing rays (DLT on ``[ray]_x H [X, Y, 1]^T = 0``).

    Args:
        rays: :math:`(*, N, 3)` viewing rays of the corners (any length; at any angle from the axis).
        object_xy: :math:`(*, N, 2)` board coordinates (broadcast against ``rays``).
        weights: :math:`(*, N)` corner weights (0 = unused); default all 1.

    Returns:
        rvec :math:`(*, 3)`, tvec :math:`(*, 3)` (world-to-camera) and ``ok`` :math:`(*)` (at least 4 corners and a
        finite fit).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import transform_points_rt
        >>> obj = board_object_points(4, 3, 0.1, dtype=torch.float64)
        >>> rvec, tvec = torch.tensor([0.1, 1.7, 0.2], dtype=torch.float64), torch.tensor([0.5, 0.0, 0.1], dtype=torch.float64)
        >>> rays = transform_points_rt(obj, rvec, tvec)  # the board is beside the camera: rays beyond 90 degrees
        >>> r, t, ok = board_to_ray_poses(rays, obj[:, :2])
        >>> bool(ok), bool((r - rvec).abs().max() < 1e-9), bool((t - tvec).abs().max() < 1e-9)
        (True, True, True)
    """
    check_shape(rays, ["*", "3"], "rays must be (*, N, 3)")
    check_shape(object_xy, ["*", "2"], "object_xy must be (*, N, 2)")
    shape = broadcast_shapes(rays.shape[:-1], object_xy.shape[:-1])
    a = rays.expand(*shape, 3)
    a = a / a.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    xy = object_xy.to(a.dtype).expand(*shape, 2)
    w = torch.ones(shape, dtype=a.dtype, device=a.device) if weights is None else weights.to(a.dtype).expand(shape)
    w = torch.where(a.isfinite().all(-1) & xy.isfinite().all(-1), w, 0.0)
    a, xy = torch.where(w[..., None] > 0, a, 0.0), torch.where(w[..., None] > 0, xy, 0.0)
    # normalise the board coordinates (weighted centroid, mean distance sqrt(2))
    wsum = w.sum(-1, keepdim=True).clamp_min(1e-300)
    mean = (xy * w[..., None]).sum(-2, keepdim=True) / wsum[..., None]
    spread = (((xy - mean) ** 2).sum(-1).sqrt() * w).sum(-1, keepdim=True) / wsum
    s = math.sqrt(2.0) / spread.clamp_min(1e-300)
    xn = (xy - mean) * s[..., None]
    xt = torch.cat([xn, torch.ones_like(xn[..., :1])], -1)  # (*, N, 3)
    z = torch.zeros_like(xt)
    a1, a2, a3 = (a[..., i : i + 1] for i in range(3))
    rows = torch.stack(
        [torch.cat([z, -a3 * xt, a2 * xt], -1), torch.cat([a3 * xt, z, -a1 * xt], -1), torch.cat([-a2 * xt, a1 * xt, z], -1)],
        -2,
    )  # (*, N, 3, 9)
    rows = rows * w.sqrt()[..., None, None]
    L = rows.flatten(-3, -2)
    M = L.transpose(-1, -2) @ L
    ok = (w > 0).sum(-1) >= 4
    M = torch.where((ok & M.flatten(-2).isfinite().all(-1))[..., None, None], M, torch.eye(9, dtype=M.dtype, device=M.device))
    Hn = torch.linalg.eigh(M).eigenvectors[..., :, 0].unflatten(-1, (3, 3))
    # undo the normalisation: H = Hn T, T = [[s, 0, -s mx], [0, s, -s my], [0, 0, 1]]
    T = torch.zeros(*shape[:-1], 3, 3, dtype=a.dtype, device=a.device)
    T[..., 0, 0], T[..., 1, 1], T[..., 2, 2] = s[..., 0], s[..., 0], 1.0
    T[..., 0, 2], T[..., 1, 2] = -s[..., 0] * mean[..., 0, 0], -s[..., 0] * mean[..., 0, 1]
    H = Hn @ T
    lam = 0.5 * (H[..., :, 0].norm(dim=-1) + H[..., :, 1].norm(dim=-1))
    xh = torch.cat([xy, torch.ones_like(xy[..., :1])], -1)
    sign = torch.sign(((xh @ H.transpose(-1, -2)) * a * w[..., None]).sum((-1, -2)))
    H = H * (torch.where(sign == 0, 1.0, sign) / lam.clamp_min(1e-300))[..., None, None]
    r1, r2 = H[..., :, 0], H[..., :, 1]
    U, _, Vh = torch.linalg.svd(torch.stack([r1, r2, torch.linalg.cross(r1, r2)], -1))
    d = torch.det(U @ Vh)
    U = torch.cat([U[..., :2], U[..., 2:] * d[..., None, None]], -1)
    R = U @ Vh
    rvec = rotation_matrix_to_axis_angle(R.reshape(-1, 3, 3)).reshape(*shape[:-1], 3)
    tvec = H[..., :, 2]
    ok = ok & rvec.isfinite().all(-1) & tvec.isfinite().all(-1)
    return torch.where(ok[..., None], rvec, 0.0), torch.where(ok[..., None], tvec, 0.0), ok


def focal_hypotheses(
    image_size: tuple[int, int], num: int = 32, low: float = 0.15, high: float = 2.5, dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Geometric grid of focal lengths ``f`` in ``[low, high] * half diagonal`` (px): :math:`(num,)`.

    An equidistant lens ``r = f theta`` with the image's half diagonal at ``theta`` sees ``2 theta`` across the
    diagonal: the default range covers fields of view from about 45 to 760 degrees over the diagonal, i.e. every
    fisheye whose image circle is at least a fifth of the diagonal.

    Example:
        >>> f = focal_hypotheses((640, 480), num=4)
        >>> [round(float(v), 1) for v in f]
        [60.0, 153.3, 391.5, 1000.0]
    """
    half_diag = 0.5 * math.hypot(float(image_size[0]), float(image_size[1]))
    return torch.logspace(math.log10(low * half_diag), math.log10(high * half_diag), num, dtype=dtype, device=device)


def init_fisheye(
    corners: torch.Tensor,
    weights: torch.Tensor,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    num_hypotheses: int = 32,
    keep: int = 3,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Best ``keep`` equidistant-fisheye hypotheses per camera, with every view's pose.

    Args:
        corners: :math:`(C, V, N, 2)` pixels.
        weights: :math:`(C, V, N)` corner weights (0 = unused).
        object_points: :math:`(N, 3)` planar board points (``Z = 0``).
        image_size: ``(W, H)``.
        num_hypotheses: focal lengths tried (:func:`focal_hypotheses`).
        keep: hypotheses returned per camera (the best local minima of the score over ``f``, then the next best).

    Returns:
        params :math:`(C, keep, 8)` Kannala–Brandt parameters ``fx, fy, cx, cy, 0, 0, 0, 0``, rvec and tvec
        :math:`(C, keep, V, 3)`, per-view init RMS :math:`(C, keep, V)` (px, inf where the pose failed) and the
        score :math:`(C, keep)` (mean of per-view squared RMS, capped; lower is better).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import Camera
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> obj = board_object_points(6, 4, 0.05, dtype=torch.float64)
        >>> cam = Camera(FISHEYE, torch.tensor([200., 200, 319.5, 239.5, 0, 0, 0, 0], dtype=torch.float64))
        >>> rv = torch.tensor([[[0.3, 0.2, 0.0], [-0.2, 0.9, 0.1], [0.1, -0.4, 0.3]]], dtype=torch.float64)
        >>> tv = torch.tensor([[[-0.1, -0.05, 0.3], [0.0, -0.05, 0.25], [-0.2, 0.0, 0.3]]], dtype=torch.float64)
        >>> uv = cam.project(obj, rv, tv)  # (1 camera, 3 views, 24 corners, 2)
        >>> params, rvec, tvec, view_rms, score = init_fisheye(uv, torch.ones(1, 3, 24), obj, (640, 480))
        >>> bool(abs(params[0, 0, 0] - 200) < 15)
        True
    """
    check_tensor(corners, "corners", ["C", "V", "N", "2"])
    C, V, N = corners.shape[:3]
    check_tensor(weights, "weights", [C, V, N])
    check_tensor(object_points, "object_points", [N, 3])
    dt, dev = torch.float64, corners.device
    uv = corners.to(dt)
    w = torch.where(uv.isfinite().all(-1), weights.to(dt), 0.0)
    uv = torch.where(w[..., None] > 0, uv, 0.0)
    obj = object_points.to(device=dev, dtype=dt)
    f = focal_hypotheses(image_size, num_hypotheses, dtype=dt, device=dev)  # (Hn,)
    Hn = f.shape[0]
    centre = torch.tensor([(image_size[0] - 1) / 2.0, (image_size[1] - 1) / 2.0], dtype=dt, device=dev)
    hypotheses = torch.zeros(Hn, 8, dtype=dt, device=dev)
    hypotheses[:, 0], hypotheses[:, 1], hypotheses[:, 2], hypotheses[:, 3] = f, f, centre[0], centre[1]
    lens = Camera(FISHEYE, hypotheses)  # the hypotheses first: each is a camera
    rays = lens.unproject(uv[None].expand(Hn, C, V, N, 2)).transpose(0, 1)  # (C, Hn, V, N, 3)
    wb = w[:, None].expand(C, Hn, V, N)
    rvec, tvec, ok = board_to_ray_poses(rays, obj[:, :2], wb)
    proj = lens.project(obj, rvec.transpose(0, 1), tvec.transpose(0, 1)).transpose(0, 1)  # (C, Hn, V, N, 2)
    sq = (((proj - uv[:, None]) ** 2).sum(-1) * wb).sum(-1)
    view_rms = (sq / wb.sum(-1).clamp_min(1)).sqrt()
    view_rms = torch.where(ok & view_rms.isfinite(), view_rms, float("inf"))
    cap = 0.05 * math.hypot(float(image_size[0]), float(image_size[1]))
    has = w.sum(-1)[:, None] > 0  # (C, 1, V)
    score = (view_rms.clamp_max(cap) ** 2 * has).sum(-1) / has.sum(-1).clamp_min(1)  # (C, Hn)
    # local minima along f first (distinct basins), then the rest by score
    padded = torch.nn.functional.pad(score[:, None], (1, 1), mode="replicate")[:, 0]
    local_min = (score <= padded[:, :-2]) & (score <= padded[:, 2:])
    rank_key = score + torch.where(local_min, 0.0, score.amax(-1, keepdim=True) + 1.0)
    k = min(keep, Hn)
    best = rank_key.topk(k, dim=-1, largest=False).indices  # (C, k)
    fsel = f[best]
    params = torch.zeros(C, k, 8, dtype=dt, device=dev)
    params[..., 0], params[..., 1], params[..., 2], params[..., 3] = fsel, fsel, centre[0], centre[1]

    def pick(x):
        return torch.gather(x, 1, best.view(C, k, *([1] * (x.dim() - 2))).expand(C, k, *x.shape[2:]))

    return params, pick(rvec), pick(tvec), pick(view_rms), torch.gather(score, 1, best)
