"""Projection uncertainty of a calibration and the projection difference of two, batched over cameras (mrcal-style).

The covariance of the camera parameters (``CalibrationResult.cov_camera``: ``fx, fy, cx, cy`` and the distortion
coefficients jointly) is propagated through the projection of fixed rays; two calibrations of one camera are
compared by projecting, with one, the rays the other sees at a grid of pixels. Optionally the camera rotation
that the data cannot tell from a principal-point shift is fitted out, as mrcal does.
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.camera import Camera

__all__ = ["ROUNDTRIP_TOL_PX", "image_points", "image_rays", "projection_difference", "projection_uncertainty",
           "remove_rotation", "storage_jacobians", "unprojectable_fraction"]


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


def image_rays(camera: Camera, pixels: torch.Tensor) -> torch.Tensor:
    """Unit camera-frame rays :math:`(C, G, 3)` of pixels :math:`(G, 2)` (or :math:`(C, G, 2)`) under each camera;
    NaN where the model has no inverse (it folds before reaching that pixel: the ray does not project back onto it).

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([500., 500, 320, 240], dtype=torch.float64))
        >>> image_rays(cam, torch.tensor([[320., 240.]])).tolist()
        [[[0.0, 0.0, 1.0]]]
    """
    C = len(camera)
    px = pixels.to(device=camera.device, dtype=camera.dtype).expand(C, *pixels.shape[-2:])
    rays = camera.unproject(px)
    back = camera.project(rays.nan_to_num(0.0))
    ok = ((back - px).norm(dim=-1) <= ROUNDTRIP_TOL_PX) & rays.isfinite().all(-1)
    return torch.where(ok[..., None], rays, torch.full_like(rays, float("nan")))


def unprojectable_fraction(camera: Camera, image_size: tuple[int, int] | None = None,
                           grid: tuple[int, int] = (16, 12)) -> torch.Tensor:
    r"""Fraction of an image grid where the camera model has no inverse: it folds before reaching those pixels
    (two rays onto one pixel), which no lens does — the model's extrapolation has gone wrong there.

    Args:
        camera: ``C`` cameras.
        image_size: ``(W, H)`` (default: the cameras').
        grid: ``(across, down)`` pixels tested, corners included.

    Returns:
        :math:`(C,)` in [0, 1].

    Example:
        >>> from ccs_kornia.geometry.models import OPENCV5
        >>> K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> mild = Camera.from_opencv(OPENCV5, K, torch.tensor([-0.1, 0.0, 0, 0, 0], dtype=torch.float64), (640, 480))
        >>> unprojectable_fraction(mild).tolist()
        [0.0]
        >>> strong = Camera.from_opencv(OPENCV5, K, torch.tensor([-0.6, 0.0, 0, 0, 0], dtype=torch.float64))
        >>> unprojectable_fraction(strong, (640, 480)).item() > 0
        True
    """
    px = image_points(image_size or camera.image_size, grid, dtype=camera.dtype).to(camera.device)
    return image_rays(camera, px).isnan().any(-1).to(camera.dtype).mean(-1)


def storage_jacobians(camera: Camera, rays: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pixels :math:`(C, G, 2)` of rays :math:`(C, G, 3)`, d pixel / d ``(fx, fy, cx, cy, dist)`` in OpenCV's storage
    :math:`(C, G, 2, 4 + D)` (the layout of ``CalibrationResult.cov_camera``: zero columns for stored coefficients the
    model does not estimate) and d pixel / d camera rotation :math:`(C, G, 2, 3)`."""
    uv, J, Jx = camera.project(rays, jacobians=True)
    width = 4 + camera.dist.shape[-1]
    out = J.new_zeros(*J.shape[:-1], width)
    for model, idx in camera._groups():
        part = J.new_zeros(idx.numel(), *J.shape[1:-1], width)
        part[..., [0, 1, 2, 3, *(4 + i for i in model.coeff_index)]] = J[idx][..., : model.num_params]
        out[idx] = part
    # the camera rotated, R <- exp(w) R at w = 0: d Xc / d w = -[Xc]_x, so each row becomes Xc x (d uv / d Xc)
    Jw = torch.linalg.cross(rays[..., None, :].expand_as(Jx), Jx, dim=-1)
    return uv, out, Jw


def remove_rotation(field: torch.Tensor, A: torch.Tensor, fit: torch.Tensor) -> torch.Tensor:
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
    camera: Camera,
    cov_camera: torch.Tensor,
    pixels: torch.Tensor,
    worst: bool = True,
    compensate_rotation: torch.Tensor | None = None,
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
        camera: ``C`` cameras.
        cov_camera: :math:`(C, 4 + D, 4 + D)` covariance of ``fx, fy, cx, cy`` and the coefficients in OpenCV's
            storage (``CalibrationResult.cov_camera``).
        pixels: :math:`(G, 2)` pixels, e.g. from :func:`image_points`.
        worst: worst-direction standard deviation (square root of the largest eigenvalue of
            :math:`\Sigma_q`, as mrcal); else the RMS over both directions (:math:`\sqrt{tr \Sigma_q / 2}`).
        compensate_rotation: :math:`(G,)` or per camera :math:`(C, G)` bool, pixels over which a camera rotation is
            fitted out (None: no).

    Returns:
        :math:`(C, G)` px; NaN where the distortion model has no inverse (see :data:`ROUNDTRIP_TOL_PX`).

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([500., 500, 320, 240], dtype=torch.float64))
        >>> cov = torch.diag(torch.tensor([4.0, 4.0, 1.0, 1.0], dtype=torch.float64))[None]  # std 2, 2, 1, 1 px
        >>> projection_uncertainty(cam, cov, torch.tensor([[320., 240.]]))
        tensor([[1.]], dtype=torch.float64)
    """
    rays = image_rays(camera, pixels)
    _, J, A = storage_jacobians(camera, rays)
    if compensate_rotation is not None:
        J = remove_rotation(J, A, compensate_rotation.to(J.device))
    S = J @ cov_camera[:, None] @ J.transpose(-1, -2)  # (C, G, 2, 2)
    if not worst:
        return (S.diagonal(dim1=-2, dim2=-1).sum(-1) / 2).clamp_min(0).sqrt()
    a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    lam = (a + d) / 2 + (((a - d) / 2) ** 2 + b * b).sqrt()
    return lam.clamp_min(0).sqrt()


def projection_difference(
    camera_a: Camera,
    camera_b: Camera,
    pixels: torch.Tensor,
    compensate_rotation: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""Distance (px) between where two calibrations of one camera project the same ray.

    The ray seen at each pixel by camera ``a`` is projected by camera ``b``: mrcal's difference of two
    calibrations. With ``compensate_rotation`` (bool mask of the pixels to fit over), the rotation between the
    two camera frames that best aligns them is fitted out first (linearised), as in
    :func:`projection_uncertainty`.

    Args:
        camera_a, camera_b: ``C`` cameras each (any models: each projects with its own).
        pixels: :math:`(G, 2)`.
        compensate_rotation: :math:`(G,)` bool, pixels over which the rotation is fitted (None: no).

    Returns:
        :math:`(C, G)` px; NaN where camera ``a``'s model has no inverse.

    Example:
        >>> from ccs_kornia.geometry.models import OPENCV5
        >>> a = Camera(OPENCV5, torch.tensor([500., 500, 320, 240, 0, 0, 0, 0, 0], dtype=torch.float64))
        >>> b = a.with_params(a.params + torch.tensor([0., 0, 0.5, 0, 0, 0, 0, 0, 0], dtype=torch.float64))
        >>> projection_difference(a, b, torch.tensor([[0., 0.], [320., 240.]]))
        tensor([[0.5000, 0.5000]], dtype=torch.float64)
    """
    rays = image_rays(camera_a, pixels)
    camera_b = camera_b.to(rays.device, rays.dtype)
    if compensate_rotation is None:
        q = camera_b.project(rays)
        return (q - pixels.to(q)).norm(dim=-1)
    q, _, A = camera_b.project(rays, jacobians=True)
    A = torch.linalg.cross(rays[..., None, :].expand_as(A), A, dim=-1)
    d = remove_rotation((q - pixels.to(q))[..., None], A, compensate_rotation.to(q.device))
    return d[..., 0].norm(dim=-1)
