r"""The splined stereographic camera (:class:`~ccs_kornia.geometry.models.splined.SplinedStereographicModel`) fitted on
the one LM core, from a parametric calibration of the same views.

mrcal's recipe: the core ``fx, fy, cx, cy`` comes from a simpler model and stays fixed (the spline can make any change
of it); the spline starts as the simpler model's lens (:func:`spline_from_camera`: a linear least-squares fit of the
control points to that camera's projection over the image), then the control points, every pose (and the board's sag
where the start had one) move on the LM core with a light regularisation in the cost (:func:`spline_prior`): every
control point pulled towards zero (the uncorrected stereographic projection, what the image's unobserved parts keep)
and the surface towards a smooth one (its second differences), each far below the data where there are data (:data:`PRIOR_ZERO`, :data:`PRIOR_CURVATURE`: a millionth and a hundred-thousandth of a corner's px^2
per pixel of correction).

:func:`splined_configuration` chooses the grid for a camera: the horizontal field of view its image spans (from the
start's rays at the image's left and right borders), and mrcal's density of 30 x 20 for a 3:2 image of many corners,
thinned where the corners are few. :func:`nearest_opencv` gives the OpenCV camera closest to a splined one, for tools
that take OpenCV's coefficients only, with how far it departs over the image.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import RATIONAL
from ccs_kornia.geometry.models.opencv import OpenCVModel
from ccs_kornia.geometry.models.splined import SplinedStereographicModel, stereographic
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.result import CalibrationResult

__all__ = ["PRIOR_CURVATURE", "PRIOR_ZERO", "calibrate_splined", "nearest_opencv", "spline_from_camera",
           "spline_prior", "splined_configuration"]

#: weight of each control point's pull towards zero: a pixel's worth (``f delta_u``) of a control point costs as much
#: as this many px^2 of one corner's residual (at the fit's mean corner weight)
PRIOR_ZERO = 1e-6
#: weight of each second difference of the surface (per component and direction), in the same units
PRIOR_CURVATURE = 1e-4
#: mrcal's grid for its wide lens (``Nx x Ny`` for a 3:2 image)
DEFAULT_GRID = (30, 20)
#: corners per control point below which the grid is thinned
CORNERS_PER_KNOT = 10


def spline_prior(model: SplinedStereographicModel, count: int, scale: torch.Tensor, zero: float = PRIOR_ZERO,
                 curvature: float = PRIOR_CURVATURE) -> torch.Tensor:
    r"""The regularisation ``x^T Lambda x`` :math:`(C, P, P)` of the control points: ``zero`` on each value, ``curvature``
    on each second difference along ``x`` and along ``y`` (per component), both times ``scale`` :math:`(C,)` (e.g.
    ``fx fy`` times the corners' mean weight: the penalty in the corners' px^2); the core is free of it.

    Example:
        >>> m = SplinedStereographicModel(4, 4, 90)
        >>> L = spline_prior(m, 1, torch.ones(1, dtype=torch.float64))
        >>> L.shape, bool((L[0, :4] == 0).all()), bool(torch.linalg.eigvalsh(L[0]).min() > -1e-9)
        (torch.Size([1, 36, 36]), True, True)
    """
    nx, ny = model.nx, model.ny
    n = nx * ny
    dtype = scale.dtype
    rows = []
    grid = torch.arange(n).reshape(ny, nx)
    for a, b, c in ((grid[:, :-2], grid[:, 1:-1], grid[:, 2:]), (grid[:-2], grid[1:-1], grid[2:])):
        d = torch.zeros(a.numel(), n, dtype=dtype)
        r = torch.arange(a.numel())
        d[r, a.reshape(-1)] += 1
        d[r, b.reshape(-1)] -= 2
        d[r, c.reshape(-1)] += 1
        rows.append(d)
    D = torch.cat(rows)
    knots = zero * torch.eye(n, dtype=dtype) + curvature * D.T @ D  # per component
    full = torch.zeros(model.num_params, model.num_params, dtype=dtype)
    for k in range(2):
        idx = 4 + 2 * torch.arange(n) + k
        full[idx[:, None], idx[None, :]] = knots
    return full.to(scale.device)[None].expand(count, -1, -1) * scale[:, None, None]


def splined_configuration(camera: Camera, corners: int, image_size: tuple[int, int]) -> SplinedStereographicModel:
    """The grid for ``camera`` (one, any model) whose views gave ``corners`` corners: the horizontal field of view of
    its image's left and right borders (plus 10 %, at most 350 degrees), mrcal's 30 x 20 density for a 3:2 image
    scaled to the image's aspect, thinned to about :data:`CORNERS_PER_KNOT` corners per control point.

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> K = torch.tensor([[500., 0, 319.5], [0, 500, 239.5], [0, 0, 1]], dtype=torch.float64)
        >>> splined_configuration(Camera(PINHOLE, torch.tensor([500., 500., 319.5, 239.5])), 600, (640, 480)).name
        'splined_stereographic_order=3_Nx=9_Ny=7_fov_x_deg=72'
    """
    w, h = image_size
    cam = camera.to(dtype=torch.float64)
    cy = float(cam.params[0, 3])
    edges = torch.tensor([[[0.0, cy], [w - 1.0, cy]]], dtype=torch.float64)
    rays = cam.unproject(edges)[0]
    angles = torch.atan2(rays[:, 0].abs(), rays[:, 2])
    fov = min(350.0, 1.1 * math.degrees(float(angles.sum())))
    nx = DEFAULT_GRID[0]
    # thin to the corners: nx * ny ~ corners / CORNERS_PER_KNOT, ny / nx ~ h / w
    most = max(16.0, corners / CORNERS_PER_KNOT)
    nx = int(min(nx, max(4, round(math.sqrt(most * w / h)))))
    ny = max(4, round(nx * h / w * DEFAULT_GRID[0] / DEFAULT_GRID[0]))
    return SplinedStereographicModel(nx, ny, round(fov))


def spline_from_camera(model: SplinedStereographicModel, camera: Camera, image_size: tuple[int, int],
                       samples: int = 60) -> torch.Tensor:
    """Parameters :math:`(C, P)` of ``model`` that image as ``camera`` (C cameras, any model) does over the image: its
    ``fx, fy, cx, cy`` as the core, the control points fitted by linear least squares to its projection at a
    ``samples x samples * H / W`` grid of pixels (their rays through ``camera``), lightly regularised as
    :func:`spline_prior`.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> K = torch.tensor([[400., 0, 320], [0, 400, 240], [0, 0, 1]], dtype=torch.float64)
        >>> cam = Camera.from_opencv(K1K2, K, torch.tensor([-0.2, 0.05], dtype=torch.float64), (640, 480))
        >>> m = SplinedStereographicModel(12, 9, 100)
        >>> spline = Camera(m, spline_from_camera(m, cam, (640, 480)), (640, 480))
        >>> q = torch.tensor([[[100.0, 80.0], [320.0, 240.0], [600.0, 400.0]]], dtype=torch.float64)
        >>> bool((spline.project(cam.unproject(q)) - q).abs().max() < 0.05)
        True
    """
    w, h = image_size
    cam = camera.to(dtype=torch.float64)
    C = len(cam)
    gx, gy = samples, max(2, round(samples * h / w))
    ys, xs = torch.meshgrid(torch.linspace(0, h - 1, gy, dtype=torch.float64),
                            torch.linspace(0, w - 1, gx, dtype=torch.float64), indexing="ij")
    q = torch.stack([xs, ys], -1).reshape(1, -1, 2).expand(C, -1, -1).to(cam.device)
    rays = cam.unproject(q)
    core = cam.params[:, :4]
    u, _ = stereographic(rays)
    target = (q - core[:, None, 2:4]) / core[:, None, 0:2] - u  # delta_u wanted at each sample
    ok = rays.isfinite().all(-1) & target.isfinite().all(-1) & (rays[..., 2] > -0.99)
    index, wts = model._patch(torch.where(ok[..., None], u, 0.0))[:2]  # (a sample without a ray: any patch, masked)
    n = model.nx * model.ny
    A = torch.zeros(C, q.shape[1], n, dtype=torch.float64, device=cam.device)
    A.scatter_add_(-1, index, torch.where(ok[..., None], wts, 0.0))
    b = torch.where(ok[..., None], target, 0.0)
    prior = spline_prior(model, 1, torch.ones(1, dtype=torch.float64, device=cam.device), 1e-6, 1e-4)[0]
    Lk = prior[4::2, 4::2]  # one component's block
    knots = torch.linalg.solve(A.transpose(-1, -2) @ A + Lk, A.transpose(-1, -2) @ b)  # (C, n, 2)
    return torch.cat([core, knots.reshape(C, 2 * n)], -1)


def calibrate_splined(
    start: CalibrationResult,
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    model: SplinedStereographicModel | None = None,
    weights: torch.Tensor | None = None,
    max_iters: int = 50,
    ftol: float = 1e-8,
) -> CalibrationResult:
    """A splined camera from ``start``, a parametric calibration of the same views (batched, C cameras): the spline
    set to ``start``'s lens (:func:`spline_from_camera`), then the control points, the poses of ``start``'s used views
    (and the board's sag, where ``start`` has one) fitted on the LM core with :func:`spline_prior`.

    Args:
        start: the parametric calibration (its camera, poses, used views and sag).
        corners: :math:`(C, V, N, 2)` observed pixels.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` board points (flat; the sag is ``start``'s).
        image_size: ``(W, H)``.
        model: the grid (default :func:`splined_configuration` of ``start``'s first camera).
        weights: optional :math:`(C, V, N)` per-corner inverse variances.
        max_iters, ftol: the LM's.

    Returns:
        a :class:`CalibrationResult` with the splined camera; the fields of ``start`` it does not refit
        (RANSAC's, the checks' and the residuals' structure) are ``start``'s.
    """
    C = corners.shape[0]
    dtype = torch.float64
    ok = valid & start.used[..., None] & corners.isfinite().all(-1)
    if model is None:
        model = splined_configuration(start.camera[0].nan_to_num(), int(ok[0].sum()), image_size)
    w = ok.to(dtype) if weights is None else torch.where(ok, weights.to(dtype), 0.0)
    if set(start.camera.models) == {model}:  # a splined start of this grid: its own values
        params = start.camera.params.to(dtype).nan_to_num(0.0)
    else:
        params = spline_from_camera(model, start.camera.nan_to_num(), image_size)
    mean_w = w.sum((1, 2)) / ok.sum((1, 2)).clamp_min(1)
    scale = params[:, 0] * params[:, 1] * mean_w  # delta_u to pixels, pixels to the corners' cost
    prior = spline_prior(model, C, scale)
    obj = object_points.to(dtype)
    warp = None if start.board_warp is None else start.board_warp.to(dtype).nan_to_num(0.0)
    res = levenberg_marquardt(model, params, start.rvec.to(dtype).nan_to_num(0.0), start.tvec.to(dtype).nan_to_num(0.0),
                              obj, corners.to(dtype), w, max_iters=max_iters, ftol=ftol, xtol=1e-12, lambda_init=1e-4,
                              board_warp=warp, prior=prior, stall_tol=1e-5)
    success = start.success & res.rms.isfinite()

    def fail_nan(x: torch.Tensor) -> torch.Tensor:
        return torch.where(success.view(C, *([1] * (x.dim() - 1))), x, torch.full_like(x, float("nan")))

    std = res.param_std
    used = start.used & res.view_used
    out = replace(
        start, camera=Camera(model, fail_nan(res.params), image_size), rvec=res.rvec, tvec=res.tvec,
        view_rms=torch.where(used, res.view_rms, float("nan")), used=used, rms=fail_nan(res.rms),
        std_intrinsics=fail_nan(std[:, :4]), std_dist=fail_nan(std[:, 4:]), success=success, lm_status=res.status,
        cov_camera=fail_nan(res.param_covariance),
        board_warp=None if res.warp is None else fail_nan(res.warp),
        std_board_warp=None if res.warp_covariance is None else fail_nan(
            res.warp_covariance.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()),
    )
    return out


def nearest_opencv(camera: Camera, model: OpenCVModel = RATIONAL, grid: tuple[int, int] = (16, 12),
                   samples: int = 80) -> tuple[Camera, torch.Tensor]:
    """The OpenCV camera closest to a splined one (one camera, with its image size), for tools that take OpenCV's
    coefficients only, and how far it departs over the image.

    Its ``K`` is the spline's core; its coefficients are fitted (OpenCV's model is linear in them: one least-squares
    solve) to the spline's projection at a ``samples``-wide grid of pixels in front of the camera (rays within 80
    degrees of the axis).

    Returns:
        the OpenCV camera and, over a ``grid`` (across, down) of the image's cell centres, how far (px) it projects
        the spline's ray of each from where the spline does: :math:`(H_g, W_g)`, NaN where the ray is beyond 80
        degrees.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> K = torch.tensor([[400., 0, 320], [0, 400, 240], [0, 0, 1]], dtype=torch.float64)
        >>> lens = Camera.from_opencv(K1K2, K, torch.tensor([-0.2, 0.05], dtype=torch.float64), (640, 480))
        >>> m = SplinedStereographicModel(10, 8, 110)
        >>> spline = Camera(m, spline_from_camera(m, lens, (640, 480)), (640, 480))
        >>> cam, departure = nearest_opencv(spline)
        >>> cam.model.name, departure.shape, bool(departure.nanmean() < 0.5)
        ('rational', torch.Size([12, 16]), True)
    """
    w, h = camera.image_size
    cam = camera.to(dtype=torch.float64)

    def grid_pixels(gx: int, gy: int) -> torch.Tensor:
        ys, xs = torch.meshgrid((torch.arange(gy, dtype=torch.float64) + 0.5) * h / gy - 0.5,
                                (torch.arange(gx, dtype=torch.float64) + 0.5) * w / gx - 0.5, indexing="ij")
        return torch.stack([xs, ys], -1).reshape(1, -1, 2).to(cam.device)

    K = cam.K
    q = grid_pixels(samples, max(2, round(samples * h / w)))
    rays = cam.unproject(q)
    front = rays[..., 2] > math.cos(math.radians(80))
    ideal = (rays[..., :2] / rays[..., 2:3].clamp_min(1e-9)) * cam.params[:, None, 0:2] + cam.params[:, None, 2:4]
    coeffs = model.fit_coeffs(torch.where(front[..., None], ideal, 0.0), q, K, front.to(torch.float64))
    opencv = Camera.from_opencv(model, K, coeffs, (w, h))
    g = grid_pixels(*grid)
    r = cam.unproject(g)
    d = (opencv.project(r) - g).norm(dim=-1)
    d = torch.where(r[..., 2] > math.cos(math.radians(80)), d, float("nan"))
    return opencv, d.reshape(grid[1], grid[0])
