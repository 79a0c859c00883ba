"""Removal of OpenCV-model distortion from images, the view's camera matrix, and the point maps to and from the
undistorted frame."""

from __future__ import annotations

import math

import torch
from kornia.geometry.calibration import distort_points, undistort_points
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap

from ccs_kornia.geometry import camera
from ccs_kornia.modules.undistort.view_camera import (
    MAX_VIEW_ANGLE_DEG,
    view_camera_matrix,
)

__all__ = [
    "opencv_undistort_image",
    "opencv_undistorted_frame",
    "opencv_distorted_frame",
    "opencv_valid_radius",
    "opencv_view_camera_matrix",
]

_RADIUS_SAMPLES = 4096


def _check(K: torch.Tensor, dist: torch.Tensor) -> None:
    if K.dim() != 3 or K.shape[-2:] != (3, 3):
        raise ValueError(f"K must be (B, 3, 3), got {tuple(K.shape)}.")
    if dist.dim() != 2 or dist.shape[0] != K.shape[0] or dist.shape[1] not in (4, 5, 8, 12, 14):
        raise ValueError(f"dist must be ({K.shape[0]}, 4|5|8|12|14), got {tuple(dist.shape)}.")


def opencv_valid_radius(K: torch.Tensor, dist: torch.Tensor, points: torch.Tensor | None = None) -> torch.Tensor:
    r"""The valid field of an OpenCV-model lens, as the largest radius on the normalised (``z = 1``) plane.

    The smallest of: the radius where the radial mapping ``r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) /
    (1 + k4 r^2 + k5 r^4 + k6 r^6)`` stops increasing (beyond it the image folds back: several rays on one pixel,
    the edge of a barrel lens undistorted into a smear) or its denominator reaches zero, the widest radius the
    undistorted ``points`` reach (the calibration's corners), and ``tan`` of
    :data:`~ccs_kornia.modules.undistort.view_camera.MAX_VIEW_ANGLE_DEG`. Tangential, thin-prism and tilt terms
    are small and left out of the monotonic test; the image's own extent is applied when the view is framed.

    Args:
        K: :math:`(B, 3, 3)`; dist: :math:`(B, D)` OpenCV coefficients, ``D`` in ``{4, 5, 8, 12, 14}``.
        points: :math:`(B, N, 2)` optional pixels seen in calibration (NaN rows are ignored).

    Returns:
        :math:`(B,)` radius (``tan`` of the angle from the axis).

    Example:
        >>> K = torch.tensor([[[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]]], dtype=torch.float64)
        >>> dist = torch.tensor([[-0.3, 0.0, 0.0, 0.0, 0.0]], dtype=torch.float64)  # r_d' = 1 - 0.9 r^2
        >>> round(opencv_valid_radius(K, dist).item(), 2)  # just below 1 / sqrt(0.9) = 1.054
        1.05
    """
    _check(K, dist)
    K, dist = K.to(torch.float64), dist.to(torch.float64)
    d = torch.nn.functional.pad(dist, [0, 14 - dist.shape[1]])
    top = math.tan(math.radians(MAX_VIEW_ANGLE_DEG))
    r = torch.linspace(0.0, top, _RADIUS_SAMPLES + 1, dtype=K.dtype, device=K.device)[None]
    r2 = r * r
    num = 1 + r2 * (d[:, 0, None] + r2 * (d[:, 1, None] + r2 * d[:, 4, None]))
    den = 1 + r2 * (d[:, 5, None] + r2 * (d[:, 6, None] + r2 * d[:, 7, None]))
    r_d = r * num / den
    bad = torch.zeros_like(r_d, dtype=torch.bool)
    bad[:, 1:] = (r_d[:, 1:] <= r_d[:, :-1]) | (den[:, 1:] <= 0)
    # two samples before the mapping first stops increasing: the peak lies between those before and after it (the top
    # where it never stops)
    index = torch.arange(_RADIUS_SAMPLES + 1, device=K.device)
    first_bad = torch.where(bad, index, _RADIUS_SAMPLES + 2).amin(-1)
    radius = r[0, (first_bad - 2).clamp(min=0)]
    if points is not None:
        if points.dim() != 3 or points.shape[0] != K.shape[0] or points.shape[-1] != 2:
            raise ValueError(f"points must be ({K.shape[0]}, N, 2), got {tuple(points.shape)}.")
        points = points.to(K)
        eye = torch.eye(3, dtype=K.dtype, device=K.device).expand_as(K)
        if dist.shape[1] <= 8:
            ideal = camera.undistort_pixels(points, K, dist)
            plane = undistort_points(ideal, K, torch.zeros_like(dist[:, :4]), new_K=eye, num_iters=0)
        else:
            plane = undistort_points(points, K, dist, new_K=eye, num_iters=20)
        seen = plane.norm(dim=-1)
        seen = torch.where(seen.isfinite(), seen, torch.zeros_like(seen)).amax(-1)
        radius = torch.minimum(radius, torch.where(seen > 0, seen, radius))
    return radius


def opencv_view_camera_matrix(
    K: torch.Tensor,
    dist: torch.Tensor,
    image_size: tuple[int, int],
    balance: float = 0.0,
    fov: float | None = None,
    max_radius: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""The camera of an undistorted view of an OpenCV-model image, framed within the lens's valid field.

    The analogue of ``cv2.getOptimalNewCameraMatrix(..., alpha=balance, centerPrincipalPoint=True)``: the view is
    centred on the optical axis with ``fy' / fx' = fy / fx``; ``balance = 0`` is the largest view without black
    pixels, ``balance = 1`` the smallest zoom showing all of the image, linear in the focal length between; ``fov``
    a horizontal field of view in degrees instead. Unlike OpenCV's, the region is limited to where the radial
    mapping is monotonic (``max_radius``), so a lens model that folds over inside the image gives no smear.

    Args:
        K: :math:`(B, 3, 3)`; dist: :math:`(B, D)` OpenCV coefficients.
        image_size: ``(W, H)`` of the images and of the view.
        balance: in ``[0, 1]``.
        fov: horizontal field of view in degrees (overrides ``balance``), clamped to the region.
        max_radius: :math:`(B,)` valid radius on the normalised plane (default: :func:`opencv_valid_radius`).

    Returns:
        :math:`(B, 3, 3)` camera matrix for :func:`opencv_undistort_image`'s ``new_K``.

    Example:
        >>> K = torch.tensor([[[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]]], dtype=torch.float64)
        >>> dist = torch.tensor([[-0.2, 0.05, 0.0, 0.0, 0.0]], dtype=torch.float64)
        >>> P0 = opencv_view_camera_matrix(K, dist, (640, 480))
        >>> P1 = opencv_view_camera_matrix(K, dist, (640, 480), balance=1.0)
        >>> P0[0, 0, 0] > P1[0, 0, 0]  # 1 shows more; for this barrel lens both more than K (cv2.undistort)
        tensor(True)
        >>> round(P0[0, 0, 0].item(), 1), round(P1[0, 0, 0].item(), 1)  # getOptimalNewCameraMatrix: 476.3, 433.1
        (476.3, 433.1)
    """
    _check(K, dist)
    K, dist = K.to(torch.float64), dist.to(torch.float64)
    if max_radius is None:
        max_radius = opencv_valid_radius(K, dist)
    eye = torch.eye(3, dtype=K.dtype, device=K.device).expand_as(K)

    def to_pixels(plane: torch.Tensor) -> torch.Tensor:
        return distort_points(plane, K, dist, new_K=eye)

    return view_camera_matrix(to_pixels, K, max_radius.to(K), image_size, balance, fov)


def opencv_undistorted_frame(points: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, zoom: float = 1.0) -> torch.Tensor:
    """Distorted pixels to pixels of :func:`opencv_undistort_image`'s output, :math:`(B, N, 2)`.

    Args:
        points: :math:`(B, N, 2)`; K: :math:`(B, 3, 3)`; dist: :math:`(B, D)` OpenCV coefficients.
        zoom: focal scale of the undistorted image (its camera is ``K`` with ``fx, fy`` times ``zoom``).
    """
    ideal = camera.undistort_pixels(points, K, dist)
    pp = K[..., None, :2, 2]
    return (ideal - pp) * zoom + pp


def opencv_distorted_frame(points: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, zoom: float = 1.0) -> torch.Tensor:
    """Pixels of :func:`opencv_undistort_image`'s output back to distorted pixels (inverse of
    :func:`opencv_undistorted_frame`)."""
    pp = K[..., None, :2, 2]
    return camera.distort_pixels((points - pp) / zoom + pp, K, dist)


def opencv_undistort_image(
    images: torch.Tensor,
    K: torch.Tensor,
    dist: torch.Tensor,
    zoom: float = 1.0,
    mode: str = "bilinear",
    new_K: torch.Tensor | None = None,
    max_radius: torch.Tensor | None = None,
) -> torch.Tensor:
    """Remove OpenCV-model distortion from images (as ``cv2.undistort`` with ``newCameraMatrix = K`` zoomed).

    ``zoom < 1`` keeps more of a barrel-distorted image's periphery in the frame.

    Args:
        images: :math:`(B, C, H, W)`.
        K: :math:`(B, 3, 3)`; dist: :math:`(B, D)` (``D`` in ``{0, 4, 5, 8}``; 12 and 14 with ``new_K``).
        zoom: focal scale of the output camera.
        mode: interpolation.
        new_K: :math:`(B, 3, 3)` camera of the output instead of ``K`` zoomed (``cv2.undistort``'s
            ``newCameraMatrix``; see :func:`opencv_view_camera_matrix`).
        max_radius: :math:`(B,)` optional valid radius on the normalised plane (:func:`opencv_valid_radius`): pixels
            whose ray is farther from the axis are zero too (no content folded back from beyond it).

    Returns:
        :math:`(B, C, H, W)`, zeros where the source lies outside the input.

    Example:
        >>> K = torch.tensor([[[50.0, 0, 31.5], [0, 50, 23.5], [0, 0, 1]]])
        >>> img = torch.rand(1, 1, 48, 64)
        >>> bool(torch.allclose(opencv_undistort_image(img, K, torch.zeros(1, 5)), img, atol=1e-5))
        True
    """
    if images.dim() != 4:
        raise ValueError(f"images must be (B, C, H, W), got {tuple(images.shape)}.")
    b, _, h, w = images.shape
    dtype = images.dtype if images.is_floating_point() else torch.float32
    grid = create_meshgrid(h, w, normalized_coordinates=False, device=images.device, dtype=torch.float64)
    pts = grid.reshape(1, h * w, 2).expand(b, -1, -1)
    K, dist = K.to(torch.float64), dist.to(torch.float64)
    if new_K is None:
        src = opencv_distorted_frame(pts, K, dist, zoom)
    else:
        src = distort_points(pts, K, dist, new_K=new_K.to(torch.float64))
    if max_radius is not None:
        out = K.clone() if new_K is None else new_K.to(torch.float64)
        if new_K is None:
            out[:, :2, :2] *= zoom
        y = (pts[..., 1] - out[:, None, 1, 2]) / out[:, None, 1, 1]
        x = (pts[..., 0] - out[:, None, 0, 2] - out[:, None, 0, 1] * y) / out[:, None, 0, 0]
        beyond = torch.hypot(x, y) > max_radius.to(x)[:, None]
        src = torch.where(beyond[..., None], torch.full_like(src, -2.0), src)  # -2: outside, so zero-padded
    src = src.reshape(b, h, w, 2).to(dtype)
    return remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode="zeros", align_corners=True)
