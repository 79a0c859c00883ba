"""Fisheye (Kannala-Brandt) images to pinhole images: the view's camera matrix and the undistortion.

:func:`fisheye_view_camera_matrix` frames the view from the lens's valid field (:func:`fisheye_valid_angle`: where
``theta_d(theta)`` increases and the calibration's corners reached); :func:`fisheye_new_camera_matrix` is
``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify``, kept for comparison: it undistorts the border
midpoints, which on a lens seeing 90 degrees or more at its borders gives an off-centre, sheared or degenerate view.
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap

from ccs_kornia.geometry import camera
from ccs_kornia.modules.undistort.view_camera import (
    MAX_VIEW_ANGLE_DEG,
    view_camera_matrix,
)

__all__ = ["fisheye_new_camera_matrix", "fisheye_undistort_image", "fisheye_valid_angle", "fisheye_view_camera_matrix"]

_ANGLE_SAMPLES = 4096


def _check(K: torch.Tensor, D: torch.Tensor) -> None:
    if K.dim() != 3 or K.shape[-2:] != (3, 3):
        raise ValueError(f"K must be (B, 3, 3), got {tuple(K.shape)}.")
    if D.shape != (K.shape[0], 4):
        raise ValueError(f"D must be ({K.shape[0]}, 4), got {tuple(D.shape)}.")


def fisheye_valid_angle(K: torch.Tensor, D: torch.Tensor, points: torch.Tensor | None = None) -> torch.Tensor:
    r"""The valid field of a Kannala-Brandt lens: the largest angle from the axis a pinhole view of it may show.

    The smallest of: the angle where ``theta_d(theta) = theta (1 + k1 theta^2 + ... + k4 theta^8)`` stops
    increasing (beyond it several directions share one image radius), the widest angle ``points`` reach (the
    calibration's corners: beyond them the polynomial is extrapolated), and
    :data:`~ccs_kornia.modules.undistort.view_camera.MAX_VIEW_ANGLE_DEG`. The image's own extent is applied
    when the view is framed (:func:`fisheye_view_camera_matrix`), so without ``points`` the bound is the
    monotonic range within the image.

    Args:
        K: :math:`(B, 3, 3)`; D: :math:`(B, 4)` ``k1..k4``.
        points: :math:`(B, N, 2)` optional pixels seen in calibration (NaN rows are ignored).

    Returns:
        :math:`(B,)` angle in radians.

    Example:
        >>> K = torch.tensor([[[300.0, 0, 319.5], [0, 300, 239.5], [0, 0, 1]]], dtype=torch.float64)
        >>> D = torch.tensor([[-0.3, 0.0, 0.0, 0.0]], dtype=torch.float64)  # d theta_d / d theta = 1 - 0.9 theta^2
        >>> round(math.degrees(fisheye_valid_angle(K, D).item()), 1)  # folds at 1 / sqrt(0.9) rad
        60.4
    """
    _check(K, D)
    K, D = K.to(torch.float64), D.to(torch.float64)
    top = math.radians(MAX_VIEW_ANGLE_DEG)
    theta = torch.linspace(0.0, top, _ANGLE_SAMPLES + 1, dtype=K.dtype, device=K.device)[None]
    t2 = theta * theta
    k1, k2, k3, k4 = (D[:, i, None] for i in range(4))
    slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    # the last sample before the slope first stops being positive (the top where it never does)
    index = torch.arange(_ANGLE_SAMPLES + 1, device=K.device)
    first_bad = torch.where(slope <= 0, index, _ANGLE_SAMPLES + 1).amin(-1)
    angle = theta[0, (first_bad - 1).clamp(min=0)]
    if points is not None:
        if points.dim() != 3 or points.shape[0] != K.shape[0] or points.shape[-1] != 2:
            raise ValueError(f"points must be ({K.shape[0]}, N, 2), got {tuple(points.shape)}.")
        rays = camera.kb_unproject_points(points.to(K), K, D)
        seen = torch.acos(rays[..., 2].clamp(-1.0, 1.0))
        seen = torch.where(seen.isfinite(), seen, torch.zeros_like(seen)).amax(-1)
        angle = torch.minimum(angle, torch.where(seen > 0, seen, angle))
    return angle


def fisheye_view_camera_matrix(
    K: torch.Tensor,
    D: torch.Tensor,
    image_size: tuple[int, int],
    balance: float = 0.0,
    fov: float | None = None,
    max_angle: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""The camera of a pinhole view of a fisheye image along its axis, framed within the lens's valid field.

    The view is centred on the optical axis with ``fy' / fx' = fy / fx``; ``balance = 0`` is the largest view
    without black pixels (every pixel inside the image and within ``max_angle`` of the axis), ``balance = 1`` the
    smallest zoom showing all of that region, linear in the focal length between; ``fov`` a horizontal field of
    view in degrees instead, clamped to the region (see
    :func:`~ccs_kornia.modules.undistort.view_camera.view_camera_matrix`).

    Args:
        K: :math:`(B, 3, 3)`; D: :math:`(B, 4)` ``k1..k4``.
        image_size: ``(W, H)`` of the fisheye images and of the view.
        balance: in ``[0, 1]``.
        fov: horizontal field of view in degrees (overrides ``balance``).
        max_angle: :math:`(B,)` valid field in radians (default: :func:`fisheye_valid_angle` without points).

    Returns:
        :math:`(B, 3, 3)` camera matrix for :func:`fisheye_undistort_image`.

    Example:
        >>> K = torch.tensor([[[300.0, 0, 319.5], [0, 300, 239.5], [0, 0, 1]]], dtype=torch.float64)
        >>> D = torch.tensor([[0.05, -0.01, 0.002, 0.0]], dtype=torch.float64)
        >>> P0 = fisheye_view_camera_matrix(K, D, (640, 480))
        >>> P1 = fisheye_view_camera_matrix(K, D, (640, 480), balance=1.0)
        >>> P0[0, 0, 2].item(), P0[0, 1, 2].item(), bool(P1[0, 0, 0] < P0[0, 0, 0])  # centred; 1 shows more
        (319.5, 239.5, True)
    """
    _check(K, D)
    K, D = K.to(torch.float64), D.to(torch.float64)
    if max_angle is None:
        max_angle = fisheye_valid_angle(K, D)

    def to_pixels(plane: torch.Tensor) -> torch.Tensor:
        rays = torch.cat([plane, torch.ones_like(plane[..., :1])], -1)
        return camera.kb_project_points(rays, K, D)

    return view_camera_matrix(to_pixels, K, torch.tan(max_angle.to(K)), image_size, balance, fov)


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
    images: torch.Tensor,
    K: torch.Tensor,
    D: torch.Tensor,
    new_K: torch.Tensor | None = None,
    mode: str = "bilinear",
    max_angle: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""Fisheye images to pinhole images with camera ``new_K`` (as ``cv2.fisheye.undistortImage``).

    Args:
        images: :math:`(B, C, H, W)`.
        K: :math:`(B, 3, 3)`; D: :math:`(B, 4)` ``k1..k4`` (``cv2.fisheye``).
        new_K: :math:`(B, 3, 3)` camera of the output (``None``: ``K``; see :func:`fisheye_view_camera_matrix`).
        mode: interpolation.
        max_angle: :math:`(B,)` optional valid field in radians (:func:`fisheye_valid_angle`): pixels whose ray is
            farther from the axis are zero too (no folded or extrapolated content in a wide view's corners).

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
    if max_angle is not None:
        beyond = torch.atan(torch.hypot(x, y)) > max_angle.to(x)[:, None]
        src = torch.where(beyond[..., None], torch.full_like(src, -2.0), src)  # -2: outside, so zero-padded
    src = src.reshape(b, h, w, 2).to(dtype)
    return remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode="zeros", align_corners=True)
