"""Projection uncertainty of a calibration and the projection difference of two, batched over cameras (mrcal-style).

The covariance of the camera parameters (``CalibrationResult.cov_camera``: ``fx, fy, cx, cy`` and the distortion
coefficients jointly) is propagated through the projection of fixed rays; two calibrations of one camera are
compared by projecting, with one, the rays the other sees at a grid of pixels. Optionally the camera rotation
that the data cannot tell from a principal-point shift is fitted out, as mrcal does.
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.camera import kb_unproject_points, undistort_pixels
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import camera_model

__all__ = ["ROUNDTRIP_TOL_PX", "image_points", "projection_uncertainty", "projection_difference", "unprojectable_fraction"]


def image_points(image_size: tuple[int, int], grid: tuple[int, int] | None = None, dtype=torch.float64) -> torch.Tensor:
    r"""The image centre and four corners, or a ``grid = (across, down)`` of pixels spanning the image.

    Returns:
        :math:`(5, 2)` (centre, top-left, top-right, bottom-left, bottom-right) or :math:`(down * across, 2)`.

    Example:
        >>> image_points((640, 480)).tolist()[:2]
        [[319.5, 239.5], [0.0, 0.0]]
    """
    W, H = float(image_size[0]) - 1, float(image_size[1]) - 1
    if grid is None:
        return torch.tensor([[W / 2, H / 2], [0, 0], [W, 0], [0, H], [W, H]], dtype=dtype)
    ys, xs = torch.linspace(0, H, int(grid[1]), dtype=dtype), torch.linspace(0, W, int(grid[0]), dtype=dtype)
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([xx.reshape(-1), yy.reshape(-1)], -1)


#: a pixel whose unprojected ray does not project back within this (px) has no inverse under the model
ROUNDTRIP_TOL_PX = 0.01

#: projects the coefficients of any OpenCV variant (in OpenCV order, every one present)
_OPENCV_ALL = camera_model("rational")


def _lens(model: str | CameraModel) -> CameraModel:
    """The model projecting ``dist`` as the functions here get it: a fisheye model's own, else OpenCV's with every
    coefficient. ``model``: a model, a model name, or ``"opencv"`` (any OpenCV variant)."""
    if isinstance(model, str):
        model = _OPENCV_ALL if model == _OPENCV_ALL.opencv_family else camera_model(model)
    return model if model.is_fisheye else _OPENCV_ALL


def _rays(K: torch.Tensor, dist: torch.Tensor, pixels: torch.Tensor,
          model: str | CameraModel = "opencv") -> torch.Tensor:
    """(C, G, 3) camera-frame rays (z = 1; unit rays for a fisheye model, which sees beyond 90 degrees) of pixels
    (G, 2) under each camera; NaN where the distortion model has no inverse (it folds before reaching that pixel:
    the ray does not project back onto it)."""
    lens = _lens(model)
    C, G = K.shape[0], pixels.shape[0]
    px = pixels.to(K).expand(C, G, 2)
    if lens.is_fisheye:
        rays = kb_unproject_points(px, K, dist)
    else:
        ideal = undistort_pixels(px, K, dist) if dist.shape[-1] else px
        x = (ideal[..., 0] - K[:, None, 0, 2]) / K[:, None, 0, 0]
        y = (ideal[..., 1] - K[:, None, 1, 2]) / K[:, None, 1, 1]
        rays = torch.stack([x, y, torch.ones_like(x)], -1)
    back = _project_rays(rays.nan_to_num(0.0), K, dist, model=lens)
    ok = ((back - px).norm(dim=-1) <= ROUNDTRIP_TOL_PX) & rays.isfinite().all(-1)
    return torch.where(ok[..., None], rays, torch.full_like(rays, float("nan")))


def unprojectable_fraction(K: torch.Tensor, dist: torch.Tensor, image_size: tuple[int, int],
                           grid: tuple[int, int] = (16, 12), model: str | CameraModel = "opencv") -> torch.Tensor:
    r"""Fraction of an image grid where the distortion model has no inverse: it folds before reaching those pixels
    (two rays onto one pixel), which no lens does — the model's extrapolation has gone wrong there.

    Args:
        K: :math:`(C, 3, 3)`.
        dist: :math:`(C, D)` (OpenCV order, or Kannala-Brandt ``k1..k4`` with ``model="fisheye"``).
        image_size: ``(W, H)``.
        grid: ``(across, down)`` pixels tested, corners included.
        model: the cameras' model or its name (``"opencv"``: any OpenCV variant).

    Returns:
        :math:`(C,)` in [0, 1].

    Example:
        >>> K = torch.tensor([[[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]], dtype=torch.float64)
        >>> unprojectable_fraction(K, torch.tensor([[-0.1, 0.0, 0, 0, 0]], dtype=torch.float64), (640, 480)).tolist()
        [0.0]
        >>> unprojectable_fraction(K, torch.tensor([[-0.6, 0.0, 0, 0, 0]], dtype=torch.float64), (640, 480)).item() > 0
        True
    """
    if K.dim() != 3 or K.shape[-2:] != (3, 3) or dist.dim() != 2 or dist.shape[0] != K.shape[0]:
        raise ValueError(f"Expected K (C, 3, 3) and dist (C, D), got {tuple(K.shape)} and {tuple(dist.shape)}.")
    px = image_points(image_size, grid, dtype=K.dtype).to(K.device)
    return _rays(K, dist, px, model).isnan().any(-1).to(K.dtype).mean(-1)


def _project_rays(rays: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, jacobians: bool = False,
                  model: str | CameraModel = "opencv"):
    """Pixels (C, G, 2) of rays (C, G, 3); with ``jacobians`` also d pixel / d (fx, fy, cx, cy, dist)
    (C, G, 2, 4+D) and d pixel / d camera rotation (C, G, 2, 3)."""
    lens = _lens(model)
    D = dist.shape[-1]
    # OpenCV: every coefficient present, in OpenCV order: the first 4 + D columns
    uv, J, Jx = lens.project(rays, lens.params_from(K, dist), jacobians)
    if not jacobians:
        return uv
    # the camera rotated, R <- exp(w) R at w = 0: d Xc / d w = -[Xc]_x, so each row becomes Xc x (d uv / d Xc)
    Jw = torch.linalg.cross(rays[..., None, :].expand_as(Jx), Jx, dim=-1)
    return uv, J[..., : 4 + D], Jw


def _remove_rotation(field: torch.Tensor, A: torch.Tensor, fit: torch.Tensor) -> torch.Tensor:
    """Subtract from ``field`` (C, G, 2, P) the least-squares fit over the points ``fit`` (G,) or (C, G) bool of a camera
    rotation, ``A`` (C, G, 2, 3) = d pixel / d rotation; points with non-finite values are left out of the fit."""
    fit = fit.to(A.device)
    use = (fit if fit.dim() == 2 else fit[None]) & A.isfinite().flatten(2).all(-1) & field.isfinite().flatten(2).all(-1)
    w8 = use[..., None, None].to(A.dtype)
    Af = (A.nan_to_num(0.0) * w8).flatten(1, 2)  # (C, 2G, 3)
    ff = (field.nan_to_num(0.0) * w8).flatten(1, 2)  # (C, 2G, P)
    eye = 1e-12 * torch.eye(3, dtype=A.dtype, device=A.device)
    w = torch.linalg.solve(Af.transpose(-1, -2) @ Af + eye, Af.transpose(-1, -2) @ ff)  # (C, 3, P)
    return field - (A.flatten(1, 2) @ w).unflatten(1, field.shape[1:3])


def projection_uncertainty(
    K: torch.Tensor,
    dist: torch.Tensor,
    cov_camera: torch.Tensor,
    pixels: torch.Tensor,
    worst: bool = True,
    compensate_rotation: torch.Tensor | None = None,
    model: str | CameraModel = "opencv",
) -> torch.Tensor:
    r"""Standard deviation (px) of the projection of the rays seen at ``pixels``, from the camera covariance.

    The ray through each pixel is fixed (unprojected with the estimate), and the covariance of the camera
    parameters (``fx, fy, cx, cy`` and the distortion coefficients, jointly) is propagated through its
    projection to first order: :math:`\Sigma_q = J \Sigma J^T`.

    With ``compensate_rotation`` (a bool mask of the pixels to fit over, e.g. a grid), the part of each
    parameter perturbation that a small rotation of the camera explains is removed first (least squares over
    those pixels), as mrcal does: a shift of the principal point is largely indistinguishable from a rotation
    of the camera, which the boards' poses absorb and which any extrinsic calibration re-estimates anyway.

    Args:
        K: :math:`(C, 3, 3)`.
        dist: :math:`(C, D)` OpenCV coefficients.
        cov_camera: :math:`(C, 4 + D, 4 + D)` (``CalibrationResult.cov_camera``).
        pixels: :math:`(G, 2)` pixels, e.g. from :func:`image_points`.
        worst: worst-direction standard deviation (square root of the largest eigenvalue of
            :math:`\Sigma_q`, as mrcal); else the RMS over both directions (:math:`\sqrt{tr \Sigma_q / 2}`).
        compensate_rotation: :math:`(G,)` or per camera :math:`(C, G)` bool, pixels over which a camera rotation is
            fitted out (None: no).
        model: the cameras' model or its name: ``dist`` in OpenCV order (``"opencv"``: any OpenCV variant), or
            k1..k4 for a fisheye model.

    Returns:
        :math:`(C, G)` px; NaN where the distortion model has no inverse (see :data:`ROUNDTRIP_TOL_PX`).

    Example:
        >>> K = torch.tensor([[[500., 0, 320], [0, 500, 240], [0, 0, 1]]], dtype=torch.float64)
        >>> cov = torch.diag(torch.tensor([4.0, 4.0, 1.0, 1.0], dtype=torch.float64))[None]  # std 2, 2, 1, 1 px
        >>> projection_uncertainty(K, torch.zeros(1, 0, dtype=torch.float64), cov, torch.tensor([[320., 240.]]))
        tensor([[1.]], dtype=torch.float64)
    """
    lens = _lens(model)
    rays = _rays(K, dist, pixels, lens)
    _, J, A = _project_rays(rays, K, dist, jacobians=True, model=lens)
    if compensate_rotation is not None:
        J = _remove_rotation(J, A, compensate_rotation.to(J.device))
    S = J @ cov_camera[:, None] @ J.transpose(-1, -2)  # (C, G, 2, 2)
    if not worst:
        return (S.diagonal(dim1=-2, dim2=-1).sum(-1) / 2).clamp_min(0).sqrt()
    a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    lam = (a + d) / 2 + (((a - d) / 2) ** 2 + b * b).sqrt()
    return lam.clamp_min(0).sqrt()


def projection_difference(
    K_a: torch.Tensor,
    dist_a: torch.Tensor,
    K_b: torch.Tensor,
    dist_b: torch.Tensor,
    pixels: torch.Tensor,
    compensate_rotation: torch.Tensor | None = None,
    model: str | CameraModel = "opencv",
) -> torch.Tensor:
    r"""Distance (px) between where two calibrations of one camera project the same ray.

    The ray seen at each pixel by camera ``a`` is projected by camera ``b``: mrcal's difference of two
    calibrations. With ``compensate_rotation`` (bool mask of the pixels to fit over), the rotation between the
    two camera frames that best aligns them is fitted out first (linearised), as in
    :func:`projection_uncertainty`.

    Args:
        K_a, K_b: :math:`(C, 3, 3)`.
        dist_a, dist_b: :math:`(C, D)`.
        pixels: :math:`(G, 2)`.
        compensate_rotation: :math:`(G,)` bool, pixels over which the rotation is fitted (None: no).
        model: both calibrations' model or its name (``"opencv"``: any OpenCV variant).

    Returns:
        :math:`(C, G)` px; NaN where camera ``a``'s distortion model has no inverse.

    Example:
        >>> K = torch.tensor([[[500., 0, 320], [0, 500, 240], [0, 0, 1]]], dtype=torch.float64)
        >>> K2 = K.clone(); K2[0, 0, 2] += 0.5
        >>> d0 = torch.zeros(1, 5, dtype=torch.float64)
        >>> projection_difference(K, d0, K2, d0, torch.tensor([[0., 0.], [320., 240.]]))
        tensor([[0.5000, 0.5000]], dtype=torch.float64)
    """
    lens = _lens(model)
    rays = _rays(K_a, dist_a, pixels, lens)
    if compensate_rotation is None:
        q = _project_rays(rays, K_b, dist_b, model=lens)
        return (q - pixels.to(q)).norm(dim=-1)
    q, _, A = _project_rays(rays, K_b, dist_b, jacobians=True, model=lens)
    d = _remove_rotation((q - pixels.to(q))[..., None], A, compensate_rotation.to(q.device))
    return d[..., 0].norm(dim=-1)
