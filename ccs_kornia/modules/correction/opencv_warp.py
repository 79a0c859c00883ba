"""Removal of OpenCV-model distortion from images, and the point maps to and from the undistorted frame."""

from __future__ import annotations

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap

from ccs_kornia import camera

__all__ = ["opencv_undistort_image", "opencv_undistorted_frame", "opencv_distorted_frame"]


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
    images: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, zoom: float = 1.0, mode: str = "bilinear"
) -> torch.Tensor:
    """Remove OpenCV-model distortion from images (as ``cv2.undistort`` with ``newCameraMatrix = K`` zoomed).

    ``zoom < 1`` keeps more of a barrel-distorted image's periphery in the frame.

    Args:
        images: :math:`(B, C, H, W)`.
        K: :math:`(B, 3, 3)`; dist: :math:`(B, D)`.
        zoom: focal scale of the output camera.
        mode: interpolation.

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
    src = opencv_distorted_frame(pts, K.to(torch.float64), dist.to(torch.float64), zoom).reshape(b, h, w, 2).to(dtype)
    return remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode="zeros", align_corners=True)
