"""Fisheye (Kannala-Brandt) images to pinhole images: ``cv2.fisheye``'s new camera matrix and undistortion."""

from __future__ import annotations

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap

from ccs_kornia import camera

__all__ = ["fisheye_new_camera_matrix", "fisheye_undistort_image"]


def _check(K: torch.Tensor, D: torch.Tensor) -> None:
    if K.dim() != 3 or K.shape[-2:] != (3, 3):
        raise ValueError(f"K must be (B, 3, 3), got {tuple(K.shape)}.")
    if D.shape != (K.shape[0], 4):
        raise ValueError(f"D must be ({K.shape[0]}, 4), got {tuple(D.shape)}.")


def fisheye_new_camera_matrix(
    K: torch.Tensor, D: torch.Tensor, image_size: tuple[int, int], balance: float = 0.0, fov_scale: float = 1.0
) -> torch.Tensor:
    r"""The pinhole camera of the undistorted image, as ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify``.

    The midpoints of the image borders are undistorted; ``balance = 0`` keeps only the part of the field every
    border midpoint sees (no black areas along the edges' middles), ``balance = 1`` the whole span between them,
    values between interpolate the focal length; ``fov_scale > 1`` zooms out.

    Args:
        K: :math:`(B, 3, 3)`; D: :math:`(B, 4)` ``k1..k4``.
        image_size: ``(W, H)`` of the fisheye images (and of the output).
        balance: in ``[0, 1]``.
        fov_scale: divides the new focal length.

    Returns:
        :math:`(B, 3, 3)` new camera matrix.

    Example:
        >>> K = torch.tensor([[[300.0, 0, 319.5], [0, 300, 239.5], [0, 0, 1]]], dtype=torch.float64)
        >>> P = fisheye_new_camera_matrix(K, torch.zeros(1, 4, dtype=torch.float64), (640, 480))
        >>> [round(P[0, i, j].item(), 2) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2))]  # as cv2 (D = 0 is no pinhole)
        [233.16, 233.16, 318.92, 239.27]
    """
    _check(K, D)
    if not 0.0 <= balance <= 1.0:
        raise ValueError(f"balance must be in [0, 1], got {balance}.")
    if not fov_scale > 0:
        raise ValueError(f"fov_scale must be positive, got {fov_scale}.")
    w, h = float(image_size[0]), float(image_size[1])
    K, D = K.to(torch.float64), D.to(torch.float64)
    mids = torch.tensor([[w / 2, 0], [w, h / 2], [w / 2, h], [0, h / 2]], dtype=torch.float64, device=K.device)
    # undistorted normalised coordinates of the border midpoints (cv2 uses an identity new matrix here)
    eye = torch.eye(3, dtype=torch.float64, device=K.device).expand_as(K)
    pts = camera.kb_undistort_points(mids.expand(K.shape[0], 4, 2), K, D, eye)
    aspect = K[:, 0, 0] / K[:, 1, 1]
    pts = torch.stack([pts[..., 0], pts[..., 1] * aspect[:, None]], -1)
    centre = pts.mean(-2)
    lo, hi = pts.amin(-2), pts.amax(-2)
    # cv2's four focal lengths that put each border midpoint on its border; balance 0 takes the largest
    fs = torch.stack([w / 2 / (centre[:, 0] - lo[:, 0]), w / 2 / (hi[:, 0] - centre[:, 0]),
                      h / 2 * aspect / (centre[:, 1] - lo[:, 1]), h / 2 * aspect / (hi[:, 1] - centre[:, 1])], -1)
    f = (balance * fs.amin(-1) + (1 - balance) * fs.amax(-1)) / fov_scale
    new = torch.zeros_like(K)
    new[:, 0, 0], new[:, 1, 1] = f, f / aspect
    new[:, 0, 2] = -centre[:, 0] * f + w / 2
    new[:, 1, 2] = (-centre[:, 1] * f + h / 2 * aspect) / aspect
    new[:, 2, 2] = 1.0
    return new


def fisheye_undistort_image(
    images: torch.Tensor, K: torch.Tensor, D: torch.Tensor, new_K: torch.Tensor | None = None, mode: str = "bilinear"
) -> torch.Tensor:
    r"""Fisheye images to pinhole images with camera ``new_K`` (as ``cv2.fisheye.undistortImage``).

    Args:
        images: :math:`(B, C, H, W)`.
        K: :math:`(B, 3, 3)`; D: :math:`(B, 4)` ``k1..k4`` (``cv2.fisheye``).
        new_K: :math:`(B, 3, 3)` camera of the output (``None``: ``K``; see :func:`fisheye_new_camera_matrix`).
        mode: interpolation.

    Returns:
        :math:`(B, C, H, W)`, zeros where the source lies outside the input or behind the lens.

    Example:
        >>> K = torch.tensor([[[50.0, 0, 31.5], [0, 50, 23.5], [0, 0, 1]]])
        >>> img = torch.rand(1, 1, 48, 64)
        >>> fisheye_undistort_image(img, K, torch.zeros(1, 4)).shape
        torch.Size([1, 1, 48, 64])
    """
    if images.dim() != 4:
        raise ValueError(f"images must be (B, C, H, W), got {tuple(images.shape)}.")
    _check(K, D)
    b, _, h, w = images.shape
    new_K = K if new_K is None else new_K
    dtype = images.dtype if images.is_floating_point() else torch.float32
    grid = create_meshgrid(h, w, normalized_coordinates=False, device=images.device, dtype=torch.float64)
    pix = grid.reshape(1, h * w, 2).expand(b, -1, -1)
    new_K = new_K.to(torch.float64)
    x = (pix[..., 0] - new_K[:, None, 0, 2]) / new_K[:, None, 0, 0]
    y = (pix[..., 1] - new_K[:, None, 1, 2]) / new_K[:, None, 1, 1]
    rays = torch.stack([x, y, torch.ones_like(x)], -1)
    src = camera.kb_project_points(rays, K.to(torch.float64), D.to(torch.float64))
    src = src.reshape(b, h, w, 2).to(dtype)
    return remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode="zeros", align_corners=True)
