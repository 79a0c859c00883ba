"""The renderer's camera model: forward projection (ground truth) and its exact inverse (rendering).

A view's lens is its camera (the camera value's map, :class:`~ccs_kornia.geometry.camera.Camera`: a pinhole, OpenCV's
``k1, k2, p1, p2, k3`` or a Kannala-Brandt fisheye, :func:`view_cameras`) followed by the paper's radial model about
the image centre (``radial_distort_points``); the forward map (:func:`project_board`) is the camera's.

The inverse distortion on the pixel grid is exact, not interpolated: the paper's model is inverted
through a fine 1-D table plus a Newton step, the OpenCV model from a coarse exact grid plus Newton
steps (both agree with the per-point float64 inverse :func:`board_coordinates` to ~1e-5 squares).

The OpenCV inverse here (:func:`undistort_opencv_pixels`) is kornia's fixed point (``undistort_points``) polished by Newton
steps on the normalized plane, with a safe start where the fixed point stalls (a bisection on the radial factor over
its monotonic range) and more Newton steps: the fixed point alone leaves errors of pixels near the image corners
under strong barrel distortion (kornia #4285), which the renderer's ground truth cannot afford. Its checks measure
the residual through the camera's forward map.

Where a model folds over (its radius stops growing) the image beyond the fold has no preimage; those pixels
are rendered black (outside the lens' image circle), and corners beyond the fold are never valid.
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.calibration import undistort_points
from torch import Tensor

from ccs_kornia.data.render.fisheye import (
    fisheye_cameras,
    is_fisheye,
    kb_reach,
    kb_unproject,
)
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.models.factory import FISHEYE, OPENCV5, PINHOLE
from ccs_kornia.geometry.radial import (
    radial_centre_scale,
    radial_distort_points,
    radial_undistort_points,
)

__all__ = [
    "view_cameras",
    "project_board",
    "board_coordinates",
    "FAR_BOARD_COORDINATE",
    "radial_is_identity",
    "opencv_fold_radius",
    "pixels_to_normalized",
    "undistort_opencv_pixels",
    "board_homography_inverse",
    "normalized_to_board",
    "opencv_inverse_grid",
    "grid_board_coordinates",
]

#: board coordinate (in squares) given to pixels that see no board plane (behind the camera) or have no preimage under
#: the lens: far outside every board, so they are shaded as background
FAR_BOARD_COORDINATE = 1.0e6


def radial_is_identity(radial: Tensor) -> Tensor:
    """Which views' paper radial coefficients are exactly ``(1, 0, 0)``: the model moves no pixel, so those views skip
    its inverse (and the background of an undistorted view is not warped).

    Args:
        radial: :math:`(B, 3)` coefficients ``(k0, k1, k2)``.

    Returns:
        :math:`(B,)` bool.

    Example:
        >>> radial_is_identity(torch.tensor([[1.0, 0.0, 0.0], [1.0, -0.2, 0.0]])).tolist()
        [True, False]
    """
    ident = torch.tensor([1.0, 0.0, 0.0], device=radial.device, dtype=radial.dtype)
    return (radial - ident).abs().amax(-1) == 0


def _radial_fold(coeffs: Tensor) -> tuple[Tensor, Tensor]:
    """Ideal radius where ``r (k0 + k1 r^2 + k2 r^4)`` stops increasing, and the distorted radius there.

    Radii in the paper's units (``max(W, H)``); ``inf`` where the model never folds before ``r = 3``.
    """
    r = torch.linspace(0.0, 3.0, 3001, device=coeffs.device, dtype=torch.float64)
    k = coeffs.to(torch.float64).unsqueeze(-1)
    r2 = r * r
    slope = k[:, 0] + 3 * k[:, 1] * r2 + 5 * k[:, 2] * r2 * r2
    bad = slope <= 0.02 * k[:, 0].abs()
    first = torch.where(bad.any(-1), bad.to(torch.uint8).argmax(-1), torch.full_like(bad[:, 0], -1, dtype=torch.long))
    r_fold = torch.where(first >= 0, r[first.clamp_min(0)], torch.full_like(k[:, 0, 0], math.inf))
    rf = r_fold.clamp_max(3.0)
    rd_max = rf * (k[:, 0, 0] + k[:, 1, 0] * rf**2 + k[:, 2, 0] * rf**4)
    rd_max = torch.where(torch.isinf(r_fold), torch.full_like(rd_max, math.inf), rd_max)
    return r_fold, rd_max


def opencv_fold_radius(dist: Tensor) -> tuple[Tensor, Tensor]:
    """Where OpenCV's radial map ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` folds over: the ideal radius where its slope
    first falls to 0.05 (searched on ``r <= 5``), and the distorted radius there. Beyond the fold the model has no
    inverse, so pixels there are not rendered and corners there are never valid.

    Args:
        dist: :math:`(B, 5)` OpenCV coefficients ``(k1, k2, p1, p2, k3)`` (the tangential terms are ignored).

    Returns:
        ``r_fold`` :math:`(B,)` and ``rd_max`` :math:`(B,)`, float64 radii on the normalized plane (``inf`` where
        the map does not fold before ``r = 5``).

    Example:
        >>> r_fold, rd_max = opencv_fold_radius(torch.tensor([[0.0, 0, 0, 0, 0], [-0.3, 0, 0, 0, 0]]))
        >>> r_fold.tolist()
        [inf, 1.028]
    """
    r = torch.linspace(0.0, 5.0, 5001, device=dist.device, dtype=torch.float64)
    d = dist.to(torch.float64)
    k1, k2, k3 = d[:, 0:1], d[:, 1:2], d[:, 4:5]
    r2 = r * r
    slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3
    bad = slope <= 0.05
    first = torch.where(bad.any(-1), bad.to(torch.uint8).argmax(-1), torch.full_like(bad[:, 0], -1, dtype=torch.long))
    r_fold = torch.where(first >= 0, r[first.clamp_min(0)], torch.full_like(k1[:, 0], math.inf))
    rf = r_fold.clamp_max(5.0)
    rd_max = rf * (1 + k1[:, 0] * rf**2 + k2[:, 0] * rf**4 + k3[:, 0] * rf**6)
    rd_max = torch.where(torch.isinf(r_fold), torch.full_like(rd_max, math.inf), rd_max)
    return r_fold, rd_max


def _paper_radius(points: Tensor, image_size: tuple[int, int]) -> Tensor:
    """The radius of pixels :math:`(*, 2)` in the paper's radial model's frame (:func:`radial_centre_scale`)."""
    centre, scale = radial_centre_scale(image_size, points)
    return ((points - centre) / scale).norm(dim=-1)


# ----------------------------------------------------------------------------------------------
# Forward model (ground truth) and inverse model (rendering)
# ----------------------------------------------------------------------------------------------


def view_cameras(K: Tensor, dist: Tensor | None = None, fisheye: Tensor | None = None,
                 image_size: tuple[int, int] | None = None) -> camera.Camera:
    """The views' cameras as one value: a Kannala-Brandt camera where ``fisheye`` marks a view as one, else OpenCV's
    ``k1, k2, p1, p2, k3`` where ``dist`` is given, else a pinhole.

    Args:
        K: :math:`(B, 3, 3)` (zero skew: the package's cameras have none).
        dist: optional :math:`(B, 5)` OpenCV coefficients.
        fisheye: optional :math:`(B, 5)` lens rows (:mod:`ccs_kornia.data.render.fisheye`).
        image_size: ``(W, H)``.

    Example:
        >>> K = torch.tensor([[400., 0, 319.5], [0, 400, 239.5], [0, 0, 1]]).expand(2, 3, 3)
        >>> fe = torch.tensor([[0.0, 0, 0, 0, 0], [0.01, 0, 0, 0, 1.5]])
        >>> [str(m) for m in view_cameras(K, torch.zeros(2, 5), fe, (640, 480)).models]
        ['opencv5', 'fisheye']
    """
    if bool((K[:, 0, 1] != 0).any()):
        raise ValueError("the renderer's cameras have zero skew (K[0, 1] = 0).")
    base = PINHOLE if dist is None else OPENCV5
    fe_mask = is_fisheye(fisheye)
    if fe_mask is None or not bool(fe_mask.any()):
        return camera.Camera(base, base.params_from(K, dist), image_size)
    fe_cams = fisheye_cameras(K[fe_mask], fisheye[fe_mask], image_size)
    if bool(fe_mask.all()):
        return fe_cams
    models = tuple(FISHEYE if f else base for f in fe_mask.tolist())
    params = K.new_full((K.shape[0], max(base.num_params, FISHEYE.num_params)), float("nan"))
    rest = ~fe_mask
    params[rest, : base.num_params] = base.params_from(K[rest], None if dist is None else dist[rest])
    params[fe_mask, : FISHEYE.num_params] = fe_cams.params
    return camera.Camera(models, params, image_size)


def project_board(
    object_points: Tensor,
    K: Tensor,
    rvec: Tensor,
    tvec: Tensor,
    image_size: tuple[int, int],
    dist: Tensor | None = None,
    radial: Tensor | None = None,
    fisheye: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Forward model: world points to distorted pixels, with a visibility flag.

    Applies the pose, the views' cameras (:func:`view_cameras`: the pinhole ``K`` with OpenCV distortion, or the
    Kannala-Brandt lens for views marked as fisheyes in ``fisheye``) and then the paper's radial distortion
    (``radial_distort_points``).

    Args:
        object_points: :math:`(B, N, 3)` world points.
        K: :math:`(B, 3, 3)`.
        rvec, tvec: :math:`(B, 3)`.
        image_size: ``(W, H)``.
        dist: optional :math:`(B, 5)` OpenCV coefficients.
        radial: optional :math:`(B, 3)` paper coefficients.
        fisheye: optional :math:`(B, 5)` ``(k1, k2, k3, k4, theta_max)``; rows with ``theta_max = 0`` are not
            fisheyes.

    Returns:
        pixels :math:`(B, N, 2)` and ``ok`` :math:`(B, N)`: in front of the camera and inside the part of
        each distortion model that does not fold over (where the renderer can show them); for fisheyes,
        inside the lens' image circle.
    """
    cam = camera.transform_points_rt(object_points, rvec, tvec)
    fe_mask = is_fisheye(fisheye)
    fe_any = fe_mask is not None and bool(fe_mask.any())
    z = cam[..., 2]
    ok = z > 1e-9
    # a pinhole projects the points in front of it (the others, not ok, at a finite stand-in depth); a fisheye all
    safe = torch.cat([cam[..., :2], torch.where(ok, z, torch.ones_like(z)).unsqueeze(-1)], -1)
    if dist is not None:
        r_fold, _ = opencv_fold_radius(dist)
        rn = (safe[..., :2] / safe[..., 2:3]).norm(dim=-1)
        ok = ok & (rn < r_fold.to(rn.dtype).unsqueeze(-1))
    if fe_any:
        safe = torch.where(fe_mask.view(-1, 1, 1), cam, safe)
    pix = view_cameras(K, dist, fisheye, image_size).project(safe)
    if radial is not None:
        r_fold, _ = _radial_fold(radial)
        ok = ok & (_paper_radius(pix, image_size) < r_fold.to(pix.dtype).unsqueeze(-1))
        pix = radial_distort_points(pix, radial.to(pix.dtype), image_size)
    if fe_any:
        sel = fe_mask.view(-1, 1)
        ok = torch.where(sel, kb_reach(cam, fisheye), ok)
    return pix, ok


def _opencv_newton(xi: Tensor, yi: Tensor, xt: Tensor, yt: Tensor, dist: Tensor, steps: int):
    """Newton steps solving ``distort(xi, yi) = (xt, yt)`` on the normalized plane (OpenCV k1,k2,p1,p2,k3).

    ``dist`` broadcasts against the points (e.g. ``(B, 1, 1)`` slices). Returns the refined points and the
    length of the last step (a convergence indicator).
    """
    k1, k2, p1, p2, k3 = dist
    step = torch.zeros_like(xi)
    for _ in range(steps):
        r2 = xi * xi + yi * yi
        g = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        gp = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # dg / d(r^2)
        xy = xi * yi
        ex = xi * g + 2 * p1 * xy + p2 * (r2 + 2 * xi * xi) - xt
        ey = yi * g + p1 * (r2 + 2 * yi * yi) + 2 * p2 * xy - yt
        a = g + 2 * xi * xi * gp + 2 * p1 * yi + 6 * p2 * xi
        c = 2 * xy * gp + 2 * p1 * xi + 2 * p2 * yi  # the Jacobian is symmetric
        d = g + 2 * yi * yi * gp + 6 * p1 * yi + 2 * p2 * xi
        det = a * d - c * c
        det = torch.where(det.abs() < 1e-12, torch.full_like(det, 1e-12), det)
        dx = ((d * ex - c * ey) / det).clamp(-1.0, 1.0)
        dy = ((a * ey - c * ex) / det).clamp(-1.0, 1.0)
        xi, yi = xi - dx, yi - dy
        step = (dx * dx + dy * dy).sqrt()
    return xi, yi, step


def _dist_slices(dist: Tensor, ndim: int) -> tuple[Tensor, ...]:
    shape = (dist.shape[0],) + (1,) * (ndim - 1)
    return tuple(dist[:, i].reshape(shape) for i in (0, 1, 2, 3, 4))


def pixels_to_normalized(px: Tensor, py: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    """Pixels to the normalized plane ``z = 1`` through ``K^-1`` (skew included), one camera per view: the plane
    the OpenCV and Kannala-Brandt models distort on.

    Args:
        px, py: :math:`(B, *)` pixel coordinates (points ``(B, P)`` or grids ``(B, H, W)``).
        K: :math:`(B, 3, 3)`.

    Returns:
        ``xn``, ``yn``, each of ``px``'s shape.

    Example:
        >>> K = torch.tensor([[[200.0, 0, 100], [0, 100, 50], [0, 0, 1]]])
        >>> pixels_to_normalized(torch.tensor([[300.0]]), torch.tensor([[150.0]]), K)
        (tensor([[1.]]), tensor([[1.]]))
    """
    shape = (K.shape[0],) + (1,) * (px.dim() - 1)
    fx, fy = K[:, 0, 0].reshape(shape), K[:, 1, 1].reshape(shape)
    cx, cy, skew = K[:, 0, 2].reshape(shape), K[:, 1, 2].reshape(shape), K[:, 0, 1].reshape(shape)
    yn = (py - cy) / fy
    return (px - cx - skew * yn) / fx, yn


def _radial_start(xt: Tensor, yt: Tensor, dist: Tensor) -> tuple[Tensor, Tensor]:
    """Robust start for the OpenCV inverse: bisection on the radial factor over its monotonic range
    (tangential terms ignored), ``(B, P)`` normalized points in and out."""
    r_fold, _ = opencv_fold_radius(dist)
    hi = torch.where(torch.isinf(r_fold), torch.full_like(r_fold, 5.0), r_fold).to(xt.dtype).unsqueeze(-1).expand_as(xt)
    lo = torch.zeros_like(xt)
    rd = (xt * xt + yt * yt).sqrt()
    k1, k2, k3 = dist[:, 0, None].to(xt.dtype), dist[:, 1, None].to(xt.dtype), dist[:, 4, None].to(xt.dtype)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        m2 = mid * mid
        below = mid * (1 + m2 * (k1 + m2 * (k2 + m2 * k3))) < rd
        lo, hi = torch.where(below, mid, lo), torch.where(below, hi, mid)
    rc = 0.5 * (lo + hi)
    ratio = torch.where(rd > 0, rc / rd.clamp_min(1e-30), torch.ones_like(rd))
    return xt * ratio, yt * ratio


def _to_pixels(xn: Tensor, yn: Tensor, K: Tensor) -> Tensor:
    """Normalized points ``(B, P)`` to pixels ``(B, P, 2)`` (:func:`pixels_to_normalized`'s inverse)."""
    fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]
    cx, cy, skew = K[:, 0, 2, None], K[:, 1, 2, None], K[:, 0, 1, None]
    return torch.stack([fx * xn + skew * yn + cx, fy * yn + cy], -1)


def _opencv_residual(ideal: Tensor, pix: Tensor, K: Tensor, dist: Tensor) -> Tensor:
    """How far the camera's forward map takes ideal pixels from ``pix`` (``(B, P, 2)`` each), px ``(B, P)``."""
    xn, yn = pixels_to_normalized(ideal[..., 0], ideal[..., 1], K)
    back = view_cameras(K, dist).distort(torch.stack([xn, yn], -1))
    return (back - pix).norm(dim=-1)


def undistort_opencv_pixels(pix: Tensor, K: Tensor, dist: Tensor, fixed_iters: int = 8, newton_iters: int = 4):
    """Distorted to ideal pixels under OpenCV's model, exactly: kornia's fixed-point inverse (``undistort_points``)
    polished by Newton steps. The fixed point alone can stall or cycle for strong barrel distortion near the image
    corners (kornia #4285); where the polished point is still off the forward map by more than 0.01 px the start is
    replaced by a bisection on the radial factor, which is safe over the model's monotonic range, and the Newton
    steps are run again.

    Args:
        pix: :math:`(B, P, 2)` distorted pixels.
        K: :math:`(B, 3, 3)`.
        dist: :math:`(B, 5)` OpenCV coefficients ``(k1, k2, p1, p2, k3)``.
        fixed_iters: iterations of the fixed point.
        newton_iters: Newton steps after it.

    Returns:
        ideal pixels :math:`(B, P, 2)` and the forward-model residual in pixels :math:`(B, P)` (where it is above
        about 0.01 px the pixel has no preimage: it lies beyond the model's fold).

    Example:
        >>> K = torch.tensor([[[400.0, 0, 319.5], [0, 400, 239.5], [0, 0, 1]]], dtype=torch.float64)
        >>> dist = torch.tensor([[-0.3, 0.1, 0.0, 0.0, 0.0]], dtype=torch.float64)
        >>> ideal, residual = undistort_opencv_pixels(torch.tensor([[[600.0, 400.0]]], dtype=torch.float64), K, dist)
        >>> bool(residual.max() < 1e-6)
        True
    """
    xt, yt = pixels_to_normalized(pix[..., 0], pix[..., 1], K)
    start = undistort_points(pix, K, dist, num_iters=fixed_iters)
    xi, yi = pixels_to_normalized(start[..., 0], start[..., 1], K)
    xi, yi, _ = _opencv_newton(xi, yi, xt, yt, _dist_slices(dist, 2), newton_iters)
    ideal = _to_pixels(xi, yi, K)
    stalled = _opencv_residual(ideal, pix, K, dist) > 1e-2
    xi, yi = pixels_to_normalized(ideal[..., 0], ideal[..., 1], K)
    if bool(stalled.any()):
        sx, sy = _radial_start(xt, yt, dist)
        xi, yi = torch.where(stalled, sx, xi), torch.where(stalled, sy, yi)
    xi, yi, _ = _opencv_newton(xi, yi, xt, yt, _dist_slices(dist, 2), newton_iters)
    ideal = _to_pixels(xi, yi, K)
    return ideal, _opencv_residual(ideal, pix, K, dist)


def board_homography_inverse(rvec: Tensor, tvec: Tensor, square: Tensor, dtype) -> Tensor:
    """The board plane's inverse homography in squares, ``diag(1/s, 1/s, 1) [r1 r2 t]^-1``: it takes a normalized
    ideal point ``(x, y, 1)`` to ``(u, v, 1) / depth``, ``(u, v)`` the board coordinates in squares (inner corner
    ``(i, j)`` at ``(i, j)``). Inverted in float64, then cast.

    Args:
        rvec, tvec: :math:`(B, 3)` the board's pose (world-to-camera axis-angle and translation).
        square: :math:`(B,)` square sides in world units.
        dtype: the result's dtype.

    Returns:
        :math:`(B, 3, 3)`.

    Example:
        >>> G = board_homography_inverse(torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([0.5]),
        ...                              torch.float64)
        >>> G[0].diagonal().tolist()
        [2.0, 2.0, 0.5]
    """
    R = camera.axis_angle_to_rotation_matrix(rvec.to(torch.float64))
    M = torch.stack([R[:, :, 0], R[:, :, 1], tvec.to(torch.float64)], -1)
    scale = torch.ones(rvec.shape[0], 3, 1, device=rvec.device, dtype=torch.float64)
    scale[:, :2] = 1.0 / square.to(torch.float64).view(-1, 1, 1)
    return (scale * torch.linalg.inv(M)).to(dtype)


def normalized_to_board(xn: Tensor, yn: Tensor, G: Tensor, zn: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Board coordinates where the rays ``(xn, yn, zn)`` (``zn = 1``: normalised pixels) meet the board plane.

    Args:
        xn, yn: :math:`(B, *)` ray directions (points ``(B, P)`` or grids ``(B, H, W)``).
        G: :math:`(B, 3, 3)` the plane's inverse homography (:func:`board_homography_inverse`).
        zn: optional third components of the rays, of ``xn``'s shape (a fisheye sees rays at any angle); ``None``
            is 1.

    Returns:
        ``u``, ``v`` in squares and ``front`` (bool: the ray meets the plane in front of the camera), each of
        ``xn``'s shape; ``u = v =`` :data:`FAR_BOARD_COORDINATE` where not ``front``.

    Example:
        >>> G = board_homography_inverse(torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([0.5]),
        ...                              torch.float64)
        >>> u, v, front = normalized_to_board(torch.tensor([[0.25]]), torch.tensor([[0.0]]), G)
        >>> u.item(), v.item(), front.item()
        (1.0, 0.0, True)
    """
    shape = (G.shape[0],) + (1,) * (xn.dim() - 1)
    q = [G[:, r, 0].reshape(shape) * xn + G[:, r, 1].reshape(shape) * yn for r in range(3)]
    q = [qr + (G[:, r, 2].reshape(shape) if zn is None else G[:, r, 2].reshape(shape) * zn) for r, qr in enumerate(q)]
    # third component is 1 / depth along the ray: positive where the plane is hit in front of the camera
    front = q[2] > 1e-12
    inv = 1.0 / torch.where(front, q[2], torch.ones_like(q[2]))
    far = torch.full_like(xn, FAR_BOARD_COORDINATE)
    return torch.where(front, q[0] * inv, far), torch.where(front, q[1] * inv, far), front


def board_coordinates(
    pixels: Tensor,
    K: Tensor,
    rvec: Tensor,
    tvec: Tensor,
    square: Tensor,
    image_size: tuple[int, int],
    dist: Tensor | None = None,
    radial: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Inverse model: distorted pixels to board coordinates in squares (inner corner ``(i, j)`` at ``(i, j)``).

    distorted pixel -> ideal pixel (``radial_undistort_points``, then :func:`undistort_opencv_pixels`) -> ray -> intersection with the board plane through the inverse homography
    ``(K [r1 r2 t])^-1``. This is the exact per-point path; the renderer uses the same chain on its pixel
    grid with a faster but equally exact inversion (tabulated / coarse-grid start, then Newton).

    Args:
        pixels: :math:`(B, P, 2)` distorted pixel coordinates.
        K: :math:`(B, 3, 3)`; rvec, tvec: :math:`(B, 3)`; square: :math:`(B,)`.
        image_size: ``(W, H)``.
        dist: optional :math:`(B, 5)`; radial: optional :math:`(B, 3)`.

    Returns:
        ``uv`` :math:`(B, P, 2)`, ``reach`` :math:`(B, P)` (the pixel has a preimage under the distortion
        models) and ``front`` :math:`(B, P)` (the pixel's ray meets the board plane in front of the camera).
    """
    dtype = pixels.dtype
    pts = pixels
    reach = torch.ones(pts.shape[:2], dtype=torch.bool, device=pts.device)
    if radial is not None:
        idx = (~radial_is_identity(radial)).nonzero().squeeze(1)
        if idx.numel() > 0:
            sub, coeff = pts[idx], radial[idx].to(dtype)
            _, rd_max = _radial_fold(radial[idx])
            ok = _paper_radius(sub, image_size) < (rd_max * (1 - 1e-3)).to(dtype).unsqueeze(-1)
            ideal = radial_undistort_points(sub, coeff, image_size)
            back = radial_distort_points(ideal, coeff, image_size)
            ok = ok & ((back - sub).norm(dim=-1) < 1e-2)
            pts = pts.index_copy(0, idx, torch.where(ok.unsqueeze(-1), ideal, sub))
            reach = reach.index_copy(0, idx, ok)
    if dist is not None:
        idx = (dist.abs().amax(-1) > 0).nonzero().squeeze(1)
        if idx.numel() > 0:
            Ki, di = K[idx].to(dtype), dist[idx].to(dtype)
            ideal, residual = undistort_opencv_pixels(pts[idx], Ki, di)
            r_fold, _ = opencv_fold_radius(dist[idx])
            xn, yn = pixels_to_normalized(ideal[..., 0], ideal[..., 1], Ki)
            ok = (residual < 1e-2) & ((xn * xn + yn * yn).sqrt() < r_fold.to(dtype).unsqueeze(-1))
            pts = pts.index_copy(0, idx, torch.where(ok.unsqueeze(-1), ideal, pts[idx]))
            reach = reach.index_copy(0, idx, reach[idx] & ok)
    xn, yn = pixels_to_normalized(pts[..., 0], pts[..., 1], K.to(dtype))
    u, v, front = normalized_to_board(xn, yn, board_homography_inverse(rvec, tvec, square, dtype))
    return torch.stack([u, v], -1), reach, front


def _radial_inverse_grid(px: Tensor, py: Tensor, radial: Tensor, image_size: tuple[int, int], table: int = 2048):
    """Paper-model inverse on image grids ``(b, H, W)``: a 1-D table of ``radial_undistort_points``
    (exact Newton) interpolated per pixel, then one Newton step on the radius (error ~1e-9 px)."""
    w, h = image_size
    b = px.shape[0]
    dt = px.dtype
    scale = float(max(w, h))
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    qx, qy = (px - cx) / scale, (py - cy) / scale
    rd = (qx * qx + qy * qy).sqrt()
    top = float(rd.max()) * 1.001 + 1e-6
    step = top / (table - 1)
    rd_tab = torch.arange(table, device=px.device, dtype=dt) * step
    probe = torch.stack([cx + rd_tab * scale, torch.full_like(rd_tab, cy)], -1).expand(b, table, 2)
    rc_tab = (radial_undistort_points(probe, radial.to(dt), image_size)[..., 0] - cx) / scale  # (b, T)
    t = (rd / step).reshape(b, -1)
    i0 = t.floor().clamp(0, table - 2)
    frac = t - i0
    i0 = i0.long()
    rc = rc_tab.gather(1, i0) * (1 - frac) + rc_tab.gather(1, i0 + 1) * frac
    rc = rc.view_as(rd)
    k0, k1, k2 = (radial[:, i].to(dt).view(b, 1, 1) for i in range(3))
    r2 = rc * rc
    f = rc * (k0 + r2 * (k1 + k2 * r2)) - rd
    df = k0 + r2 * (3 * k1 + 5 * k2 * r2)
    rc = rc - f / df.clamp_min(1e-6)
    _, rd_max = _radial_fold(radial)
    reach = rd < (rd_max * (1 - 1e-3)).to(dt).view(b, 1, 1)
    ratio = torch.where(rd > 0, rc / rd.clamp_min(1e-12), 1.0 / k0)
    return qx * ratio * scale + cx, qy * ratio * scale + cy, reach


def opencv_inverse_grid(
    xt: Tensor, yt: Tensor, K: Tensor, dist: Tensor, image_size: tuple[int, int], stride: int = 8, rows=None
):
    """OpenCV-model inverse for a pixel grid of normalized distorted coordinates, as fast as a grid allows and as
    exact as :func:`undistort_opencv_pixels`.

    The exact inverse on a coarse grid every ``stride`` pixels, bilinearly upsampled as the start (error ~1e-2 px),
    then Newton steps on every pixel (quadratic convergence: ~1e-7 px).

    Args:
        xt, yt: :math:`(B, H, W)` normalized distorted coordinates of the pixel centres of image rows
            ``rows = (y0, y1)`` (``H = y1 - y0``).
        K: :math:`(B, 3, 3)`.
        dist: :math:`(B, 5)` OpenCV coefficients.
        image_size: ``(W, H_{image})``.
        stride: pixels between the points of the coarse grid.
        rows: ``(y0, y1)``; default all the image's rows.

    Returns:
        ``xi``, ``yi`` :math:`(B, H, W)` normalized ideal coordinates and ``ok`` :math:`(B, H, W)` bool (converged,
        and inside the model's fold).

    Example:
        >>> K = torch.tensor([[[40.0, 0, 15.5], [0, 40, 11.5], [0, 0, 1]]], dtype=torch.float64)
        >>> dist = torch.tensor([[-0.2, 0.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
        >>> ys, xs = torch.meshgrid(torch.arange(24.0), torch.arange(32.0), indexing="ij")
        >>> xt, yt = pixels_to_normalized(xs[None].double(), ys[None].double(), K)
        >>> xi, yi, ok = opencv_inverse_grid(xt, yt, K, dist, (32, 24))
        >>> xi.shape, bool(ok.all())
        (torch.Size([1, 24, 32]), True)
    """
    w = image_size[0]
    y0, y1 = (0, image_size[1]) if rows is None else rows
    h = y1 - y0
    b = xt.shape[0]
    dt = xt.dtype
    wc, hc = max(2, math.ceil((w - 1) / stride) + 1), max(2, math.ceil((h - 1) / stride) + 1)
    ys, xs = torch.meshgrid(
        torch.linspace(y0, y1 - 1, hc, device=xt.device, dtype=dt), torch.linspace(0, w - 1, wc, device=xt.device, dtype=dt),
        indexing="ij",
    )
    coarse = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).unsqueeze(0).expand(b, -1, -1)
    ideal, _ = undistort_opencv_pixels(coarse, K.to(dt), dist.to(dt))
    xi, yi = pixels_to_normalized(ideal[..., 0], ideal[..., 1], K.to(dt))
    start = torch.stack([xi, yi], 1).view(b, 2, hc, wc)
    start = torch.nn.functional.interpolate(start, size=(h, w), mode="bilinear", align_corners=True)
    xi, yi, step = _opencv_newton(start[:, 0], start[:, 1], xt, yt, _dist_slices(dist.to(dt), 3), 3)
    r_fold, _ = opencv_fold_radius(dist)
    fx = K[:, 0, 0].to(dt).view(b, 1, 1)
    ok = (step * fx < 1e-2) & ((xi * xi + yi * yi).sqrt() < r_fold.to(dt).view(b, 1, 1))
    return xi, yi, ok


def grid_board_coordinates(K, rvec, tvec, square, image_size, dist, radial, fisheye=None, rows=None):
    """:func:`board_coordinates` of every pixel centre, as the renderer needs them: board coordinates, where they are
    defined, and the ideal pixel each pixel sees (to warp the background by the same lens).

    ``rows = (y0, y1)`` restricts the grid to image rows ``y0 <= y < y1`` (the renderer's bands); ``fisheye``
    views (``(B, 5)``, see :mod:`ccs_kornia.data.render.fisheye`) use the Kannala-Brandt inverse. Computed in float32.

    Args:
        K: :math:`(B, 3, 3)`; rvec, tvec: :math:`(B, 3)`; square: :math:`(B,)`.
        image_size: ``(W, H_{image})``.
        dist: optional :math:`(B, 5)` OpenCV coefficients; radial: optional :math:`(B, 3)` paper coefficients.
        fisheye: optional :math:`(B, 5)` lens rows ``(k1, k2, k3, k4, theta_max)``.
        rows: ``(y0, y1)``; default all the image's rows (``H = y1 - y0``).

    Returns:
        ``u``, ``v`` (squares), ``reach`` (bool: the pixel has a preimage under the lens), ``front`` (bool: its ray
        meets the board plane in front of the camera), ``ix``, ``iy`` (the ideal pixel it sees), each
        :math:`(B, H, W)`.

    Example:
        >>> K = torch.tensor([[[40.0, 0, 15.5], [0, 40, 11.5], [0, 0, 1]]])
        >>> u, v, reach, front, ix, iy = grid_board_coordinates(
        ...     K, torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor([0.1]), (32, 24), None, None)
        >>> u.shape, bool(reach.all() and front.all())
        (torch.Size([1, 24, 32]), True)
    """
    w, h_img = image_size
    y0, y1 = (0, h_img) if rows is None else (int(rows[0]), int(rows[1]))
    h = y1 - y0
    b = K.shape[0]
    dev, dt = K.device, torch.float32
    ys, xs = torch.meshgrid(torch.arange(y0, y1, device=dev, dtype=dt), torch.arange(w, device=dev, dtype=dt), indexing="ij")
    px, py = xs.expand(b, h, w), ys.expand(b, h, w)
    reach = torch.ones(b, h, w, dtype=torch.bool, device=dev)
    rad_idx = torch.zeros(0, dtype=torch.long, device=dev)
    if radial is not None:
        rad_idx = (~radial_is_identity(radial)).nonzero().squeeze(1)
        if rad_idx.numel() > 0:
            sx, sy, ok = _radial_inverse_grid(px[rad_idx], py[rad_idx], radial[rad_idx], image_size)
            px, py = px.index_copy(0, rad_idx, sx), py.index_copy(0, rad_idx, sy)
            reach = reach.index_copy(0, rad_idx, ok)
    Kf = K.to(dt)
    xn, yn = pixels_to_normalized(px, py, Kf)
    if dist is not None:
        cv_mask = dist.abs().amax(-1) > 0
        rad_mask = torch.zeros_like(cv_mask)
        rad_mask[rad_idx] = True
        only, both = cv_mask & ~rad_mask, cv_mask & rad_mask
        idx = only.nonzero().squeeze(1)
        if idx.numel() > 0:  # regular distorted grid: coarse exact start + Newton
            xi, yi, ok = opencv_inverse_grid(xn[idx], yn[idx], Kf[idx], dist[idx].to(dt), image_size, rows=(y0, y1))
            xn, yn = xn.index_copy(0, idx, xi), yn.index_copy(0, idx, yi)
            reach = reach.index_copy(0, idx, reach[idx] & ok)
        idx = both.nonzero().squeeze(1)
        if idx.numel() > 0:  # both models on one view (rare): exact per-point inverse
            pts = torch.stack([px[idx], py[idx]], -1).reshape(idx.numel(), -1, 2)
            ideal, residual = undistort_opencv_pixels(pts, Kf[idx], dist[idx].to(dt))
            xi, yi = pixels_to_normalized(ideal[..., 0], ideal[..., 1], Kf[idx])
            r_fold, _ = opencv_fold_radius(dist[idx])
            ok = (residual < 1e-2) & ((xi * xi + yi * yi).sqrt() < r_fold.to(dt).unsqueeze(-1))
            xn, yn = xn.index_copy(0, idx, xi.view(-1, h, w)), yn.index_copy(0, idx, yi.view(-1, h, w))
            reach = reach.index_copy(0, idx, reach[idx] & ok.view(-1, h, w))
    G = board_homography_inverse(rvec, tvec, square, dt)
    u, v, front = normalized_to_board(xn, yn, G)
    # ideal (undistorted) pixel of every pixel centre, for warping the background like the board
    ix = Kf[:, 0, 0, None, None] * xn + Kf[:, 0, 1, None, None] * yn + Kf[:, 0, 2, None, None]
    iy = Kf[:, 1, 1, None, None] * yn + Kf[:, 1, 2, None, None]
    fe_mask = is_fisheye(fisheye)
    if fe_mask is not None and bool(fe_mask.any()):
        idx = fe_mask.nonzero().squeeze(1)
        rx, ry, rz, ok = kb_unproject(xn[idx], yn[idx], fisheye[idx].to(dev))
        fu, fv, ff = normalized_to_board(rx, ry, G[idx], rz)
        u, v, front = u.index_copy(0, idx, fu), v.index_copy(0, idx, fv), front.index_copy(0, idx, ff)
        reach = reach.index_copy(0, idx, ok)
        # the background is a scene seen through the same lens: a pinhole image of it (focal 0.35 fx, rays
        # beyond 80 degrees clamped) is looked up along each pixel's ray, so its straight edges bend like the board's
        zc = rz.clamp_min(math.cos(math.radians(80.0)))
        fb = 0.35 * Kf[idx, 0, 0].view(-1, 1, 1)
        bx = Kf[idx, 0, 2].view(-1, 1, 1) + fb * rx / zc
        by = Kf[idx, 1, 2].view(-1, 1, 1) + 0.35 * Kf[idx, 1, 1].view(-1, 1, 1) * ry / zc
        ix, iy = ix.index_copy(0, idx, bx), iy.index_copy(0, idx, by)
    return u, v, reach, front, ix, iy
