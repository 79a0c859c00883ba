"""Kannala-Brandt (``cv2.fisheye``) lens for the renderer: the views' cameras, their image circle and the exact inverse.

The model (``cv2.fisheye``'s, with ``k1..k4``): a camera-frame point at angle ``theta`` from the optical axis and
azimuth ``phi`` is imaged at radius ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` on
the normalised plane, ``x_d = theta_d cos(phi)``, ``y_d = theta_d sin(phi)``, then ``u = fx x_d + cx``,
``v = fy y_d + cy``, with ``theta = atan2(rho, z)`` (``rho = sqrt(x^2 + y^2)``), so that points beyond 90 degrees
project and fields of view up to 200 degrees (and more) render correctly. The forward map is the camera value's
(:data:`~ccs_kornia.geometry.models.FISHEYE`, :func:`fisheye_cameras`); this module adds what a render needs beyond
it: the lens' image circle and its exact inverse on a pixel grid.

A view's lens is the row ``(k1, k2, k3, k4, theta_max)`` of a ``(B, 5)`` tensor: ``theta_max`` (radians) is the
half field of view, the edge of the lens' image circle (pixels beyond it are black); ``theta_max = 0`` marks a
view that is not a fisheye (pinhole, possibly with OpenCV or the paper's distortion).

Inverse (rendering): pixel -> normalised ``(x_d, y_d)`` -> ``theta_d`` -> ``theta`` (a monotone 1-D table of the
radial profile :func:`kb_distort_theta`, then Newton steps: error ~1e-7 rad in float32) -> unit ray -> intersection
with the board plane. Rays that miss the board or meet its plane behind the camera show background.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ccs_kornia.data.batching import padded_object_points
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.models.factory import FISHEYE

__all__ = [
    "fisheye_cameras",
    "kb_distort_theta",
    "kb_reach",
    "kb_unproject",
    "kb_fold",
    "sample_fisheye_cameras",
    "sample_fisheye_poses",
]

_NO_FISHEYE_EPS = 1e-9


def is_fisheye(fisheye: Tensor | None) -> Tensor | None:
    """``(B,)`` mask of the views that are fisheyes (``theta_max > 0``), or ``None``."""
    return None if fisheye is None else fisheye[:, 4] > _NO_FISHEYE_EPS


def kb_distort_theta(theta: Tensor, k: Tensor) -> tuple[Tensor, Tensor]:
    """The lens' radial profile ``theta_d(theta)`` and its slope, the 1-D function the inverse tabulates and
    polishes by Newton's method, and whose slope says where the model folds over (:func:`kb_fold`); ``k``
    broadcasts as ``(..., 4)`` slices ``k[..., i]``."""
    k1, k2, k3, k4 = (k[..., i] for i in range(4))
    t2 = theta * theta
    poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    return theta * poly, dpoly


def kb_fold(k: Tensor, theta_cap: float = math.pi) -> Tensor:
    """First ``theta`` (rad) where ``theta_d`` stops increasing (slope below 0.05), capped at ``theta_cap``;
    ``(B, 4)`` coefficients in, ``(B,)`` float64 out."""
    t = torch.linspace(0.0, theta_cap, 4097, dtype=torch.float64, device=k.device)
    _, slope = kb_distort_theta(t, k.to(torch.float64).unsqueeze(1).expand(-1, t.numel(), 4))
    bad = slope <= 0.05
    first = bad.to(torch.uint8).argmax(-1)
    return torch.where(bad.any(-1), t[first], torch.full_like(t[:1].expand(k.shape[0]), theta_cap))


def fisheye_cameras(K: Tensor, fisheye: Tensor, image_size: tuple[int, int] | None = None) -> camera.Camera:
    """The views' Kannala-Brandt cameras (:data:`~ccs_kornia.geometry.models.FISHEYE`): ``K`` :math:`(B, 3, 3)` (zero
    skew) and the lens rows :math:`(B, 5)` (their ``k1..k4``), in ``K``'s dtype."""
    return camera.Camera(FISHEYE, FISHEYE.params_from(K, fisheye[:, :4].to(K.dtype)), image_size)


def kb_reach(points_cam: Tensor, fisheye: Tensor) -> Tensor:
    """Which camera-frame points :math:`(B, N, 3)` a lens :math:`(B, 5)` images, :math:`(B, N)` bool: inside its image
    circle (``theta < theta_max``) and inside the part of the model that does not fold over."""
    x, y, z = points_cam.unbind(-1)
    rho = (x * x + y * y).sqrt()
    theta = torch.atan2(rho, z)
    lim = torch.minimum(fisheye[:, 4].to(torch.float64), kb_fold(fisheye[:, :4])).to(points_cam.dtype)
    return (theta < lim.unsqueeze(-1)) & (rho + z.abs() > 0)


def kb_unproject(xd: Tensor, yd: Tensor, fisheye: Tensor, table: int = 2048, newton: int = 3):
    """Normalised distorted coordinates ``(b, ...)`` to unit rays through the Kannala-Brandt lens.

    ``theta_d -> theta`` is inverted on the model's monotonic range ``[0, min(theta_max, fold)]`` by a table
    lookup (``searchsorted``) and ``newton`` Newton steps.

    Returns:
        ray components ``dx, dy, dz`` (unit length) and ``reach`` (inside the image circle).
    """
    b = xd.shape[0]
    shape = (b,) + (1,) * (xd.dim() - 1)
    dt = xd.dtype
    lim = torch.minimum(fisheye[:, 4].to(torch.float64), kb_fold(fisheye[:, :4]))  # (b,)
    k64 = fisheye[:, :4].to(torch.float64)
    frac = torch.linspace(0.0, 1.0, table, dtype=torch.float64, device=xd.device)
    t_tab = lim[:, None] * frac  # (b, T)
    td_tab, _ = kb_distort_theta(t_tab, k64[:, None, :].expand(-1, table, 4))
    rd = (xd * xd + yd * yd).sqrt()
    flat = rd.reshape(b, -1)
    idx = torch.searchsorted(td_tab.to(dt).contiguous(), flat.contiguous()).clamp(1, table - 1)
    lo_d, hi_d = td_tab.to(dt).gather(1, idx - 1), td_tab.to(dt).gather(1, idx)
    lo_t, hi_t = t_tab.to(dt).gather(1, idx - 1), t_tab.to(dt).gather(1, idx)
    w = ((flat - lo_d) / (hi_d - lo_d).clamp_min(1e-30)).clamp(0.0, 1.0)
    theta = (lo_t + w * (hi_t - lo_t)).view_as(rd)
    k = fisheye[:, :4].to(dt).view(*shape, 4)
    for _ in range(newton):
        f, df = kb_distort_theta(theta, k)
        theta = theta - (f - rd) / df.clamp_min(1e-6)
    reach = rd <= td_tab[:, -1].to(dt).view(shape)
    theta = theta.clamp_min(0.0)
    s = torch.sin(theta)
    inv = torch.where(rd > 1e-12, 1.0 / rd.clamp_min(1e-30), torch.zeros_like(rd))
    return xd * inv * s, yd * inv * s, torch.cos(theta), reach


# ----------------------------------------------------------------------------------------------
# sampling: fisheye cameras and board poses
# ----------------------------------------------------------------------------------------------


def _u(g: torch.Generator, shape, lo: float, hi: float) -> Tensor:
    return lo + (hi - lo) * torch.rand(shape, generator=g, dtype=torch.float64)


def sample_fisheye_cameras(
    num: int,
    image_size: tuple[int, int],
    generator: torch.Generator,
    fov_range: tuple[float, float] = (120.0, 200.0),
    circle_range: tuple[float, float] = (0.5, 1.0),
    k_ranges: tuple[tuple[float, float], ...] = ((-0.06, 0.08), (-0.012, 0.012), (-0.003, 0.003), (-0.0005, 0.0005)),
) -> tuple[Tensor, Tensor]:
    """Random Kannala-Brandt cameras whose image circle spans ``fov_range`` degrees.

    ``k1..k4 ~ U[k_ranges]`` (equisolid ``k1 = -1/24``, stereographic ``k1 = 1/12`` and equidistant ``k = 0``
    lie inside the default ranges), redrawn until ``theta_d`` grows steadily up to the half field of view; the
    image circle's radius ``f theta_d(theta_max)`` is a fraction ``circle_range`` of the way from
    ``min(W, H) / 2`` (a circular fisheye) to half the image diagonal (a full-frame fisheye).

    Returns:
        ``K`` :math:`(num, 3, 3)` float64 and ``fisheye`` :math:`(num, 5)` float64 ``(k1..k4, theta_max)``.

    Example:
        >>> K, fe = sample_fisheye_cameras(2, (640, 480), torch.Generator().manual_seed(0))
        >>> K.shape, fe.shape
        (torch.Size([2, 3, 3]), torch.Size([2, 5]))
    """
    w, h = int(image_size[0]), int(image_size[1])
    n = int(num)
    g = generator
    theta_max = torch.deg2rad(_u(g, (n,), *fov_range)) / 2
    k = torch.zeros(n, 4, dtype=torch.float64)
    todo = torch.arange(n)
    for attempt in range(200):
        m = todo.numel()
        shrink = 0.7 ** (attempt // 20)
        cand = torch.stack([_u(g, (m,), *r) * shrink for r in k_ranges], -1)
        ok = kb_fold(cand, theta_cap=math.pi) > theta_max[todo] * 1.05
        k[todo[ok]] = cand[ok]
        todo = todo[~ok]
        if todo.numel() == 0:
            break
    td_max, _ = kb_distort_theta(theta_max, k)
    lo, hi = min(w, h) / 2.0, 0.5 * math.hypot(w, h)
    radius = lo + (hi - lo) * _u(g, (n,), *circle_range)
    fx = radius / td_max
    fy = fx * _u(g, (n,), 0.98, 1.02)
    cx = (w - 1) / 2 + 0.03 * w * _u(g, (n,), -1.0, 1.0)
    cy = (h - 1) / 2 + 0.03 * h * _u(g, (n,), -1.0, 1.0)
    K = camera.intrinsics_matrix(torch.stack([fx, fy, cx, cy], -1))
    return K, torch.cat([k, theta_max.unsqueeze(-1)], -1)


def _rotation_between_z_and(d: Tensor) -> Tensor:
    """Rotations ``(B, 3, 3)`` taking the z axis onto the unit vectors ``d`` ``(B, 3)``."""
    z = torch.zeros_like(d)
    z[:, 2] = 1.0
    axis = torch.cross(z, d, dim=-1)
    s = axis.norm(dim=-1, keepdim=True)
    angle = torch.atan2(s, d[:, 2:3])
    axis = torch.where(s > 1e-12, axis / s.clamp_min(1e-12), torch.tensor([1.0, 0.0, 0.0], dtype=d.dtype))
    return camera.axis_angle_to_rotation_matrix(axis * angle)


def sample_fisheye_poses(
    K: Tensor,
    fisheye: Tensor,
    cols: Tensor,
    rows: Tensor,
    square: Tensor,
    image_size: tuple[int, int],
    generator: torch.Generator,
    max_tilt_deg: float = 70.0,
    span_deg: tuple[float, float] = (25.0, 110.0),
    border_bias: float = 0.5,
    margin: float = 4.0,
    min_square_px: float = 6.0,
    partial: Tensor | None = None,
    min_visible: float = 0.3,
    candidates: int = 32,
    max_rounds: int = 60,
    strict: bool = True,
) -> tuple[Tensor, Tensor] | tuple[Tensor, Tensor, Tensor]:
    """Board poses for fisheye views: anywhere in the field of view, often near its edge, steep and curved.

    The board's centre lies along a ray at angle ``theta_c`` from the axis (``theta_c = 0.95 theta_max u^b``,
    ``u ~ U[0, 1]``, ``b = border_bias``: below 1 favours the border where boards bend and shrink), at a distance
    where the board spans ``span_deg`` degrees; it faces the camera, then tilts by up to ``max_tilt_deg`` about
    a random in-plane axis and rolls freely. Accepted when the camera sees its front, every corner (or, for
    ``partial`` views, at least ``min_visible`` of them) lies inside the image circle and the image with
    ``margin`` px, and neighbouring visible corners are at least ``min_square_px`` apart.

    Args:
        K: :math:`(B, 3, 3)`; fisheye: :math:`(B, 5)`; cols, rows: :math:`(B,)` long; square: :math:`(B,)`.

    Returns:
        rvec, tvec :math:`(B, 3)` float64; raises when some board finds no pose, unless ``strict=False``: then
        ``(rvec, tvec, done)`` with ``done`` :math:`(B,)` bool (zeros where not done; the caller falls back).
    """
    w, h = image_size
    b = K.shape[0]
    g = generator
    K, fisheye, square = K.double().cpu(), fisheye.double().cpu(), square.double().cpu()
    part = torch.zeros(b, dtype=torch.bool) if partial is None else partial.cpu()
    rv_out, tv_out = torch.zeros(b, 3, dtype=torch.float64), torch.zeros(b, 3, dtype=torch.float64)
    done = torch.zeros(b, dtype=torch.bool)
    n_max = int((cols * rows).max())
    for _ in range(max_rounds):
        pend = (~done).nonzero().squeeze(1)
        if pend.numel() == 0:
            break
        sel = pend.repeat_interleave(candidates)
        m = sel.numel()
        Kc, fe, cc, rc, sc, pc = K[sel], fisheye[sel], cols[sel].cpu(), rows[sel].cpu(), square[sel], part[sel]
        theta_c = 0.95 * fe[:, 4] * _u(g, (m,), 0.0, 1.0).pow(border_bias)
        phi = _u(g, (m,), 0.0, 2 * math.pi)
        ray = torch.stack([theta_c.sin() * phi.cos(), theta_c.sin() * phi.sin(), theta_c.cos()], -1)
        span = torch.deg2rad(_u(g, (m,), *span_deg))
        width = (torch.maximum(cc, rc) + 1).double() * sc
        dist = width / (2 * torch.tan(span / 2))
        roll = _u(g, (m,), -math.pi, math.pi)
        tilt = torch.deg2rad(_u(g, (m,), 0.0, max_tilt_deg))
        azim = _u(g, (m,), 0.0, 2 * math.pi)
        zeros = torch.zeros_like(roll)
        r_roll = camera.axis_angle_to_rotation_matrix(torch.stack([zeros, zeros, roll], -1))
        r_tilt = camera.axis_angle_to_rotation_matrix(torch.stack([azim.cos(), azim.sin(), zeros], -1) * tilt[:, None])
        R = _rotation_between_z_and(ray) @ r_tilt @ r_roll
        centre = torch.stack([(cc - 1).double() * sc / 2, (rc - 1).double() * sc / 2, torch.zeros_like(sc)], -1)
        tvec = dist[:, None] * ray - (R @ centre.unsqueeze(-1)).squeeze(-1)
        rvec = camera.rotation_matrix_to_axis_angle(R)
        obj, exists = padded_object_points(cc, rc, sc, n_max)
        cam = camera.transform_points_rt(obj, rvec, tvec)
        pix = fisheye_cameras(Kc, fe).project(cam)
        ok = kb_reach(cam, fe)
        # the camera must see the board's front: the normal points away from the camera at every corner
        normal = R[:, :, 2]
        facing = ((cam * normal[:, None, :]).sum(-1) / cam.norm(dim=-1).clamp_min(1e-12)) > math.cos(math.radians(85))
        inside = (
            ok & facing & torch.isfinite(pix).all(-1)
            & (pix[..., 0] >= margin) & (pix[..., 0] <= w - 1 - margin)
            & (pix[..., 1] >= margin) & (pix[..., 1] <= h - 1 - margin)
        )
        vis = (inside & exists).sum(-1).double() / exists.sum(-1).double()
        full_ok = (inside | ~exists).all(-1)
        part_ok = (vis >= min_visible) & ((facing & ok) | ~exists).all(-1)
        # spacing between visible neighbours along rows and columns
        nn = torch.arange(n_max).unsqueeze(0)
        c1 = cc.unsqueeze(1)
        safe = torch.where(inside.unsqueeze(-1), pix, torch.zeros_like(pix))
        spacing = torch.full((m,), math.inf, dtype=torch.float64)
        for step, has in ((1, torch.remainder(nn, c1) < c1 - 1), (c1, nn + c1 < c1 * rc.unsqueeze(1))):
            nb = (nn + step).clamp_max(n_max - 1).expand(m, -1)
            both = exists & has & inside & inside.gather(1, nb)
            d = (safe.gather(1, nb.unsqueeze(-1).expand(-1, -1, 2)) - safe).norm(dim=-1)
            spacing = torch.minimum(spacing, torch.where(both, d, torch.full_like(d, math.inf)).amin(-1))
        valid = torch.where(pc, part_ok, full_ok) & (spacing >= min_square_px) & torch.isfinite(tvec).all(-1)
        valid = valid.view(-1, candidates)
        got = valid.any(-1)
        pick = torch.arange(pend.numel()) * candidates + valid.to(torch.uint8).argmax(-1)
        rv_out[pend[got]], tv_out[pend[got]] = rvec[pick[got]], tvec[pick[got]]
        done[pend[got]] = True
    if not strict:
        return rv_out, tv_out, done
    if not bool(done.all()):
        raise RuntimeError(f"Could not place {int((~done).sum())} board(s) in the fisheye view(s); relax the pose ranges.")
    return rv_out, tv_out
