r"""Images of a calibrated camera resampled into pinhole views: ``cv2.undistort`` / ``cv2.fisheye.undistortImage``
for every model, through the camera's own :meth:`~ccs_kornia.geometry.camera.Camera.distort`.

Each pixel of the view is a ray of the pinhole camera ``new_K`` (the view's camera, see
:func:`~ccs_kornia.modules.undistort.view_camera.view_camera_matrix`); the camera's model says where the lens images
that ray (:func:`undistortion_map`), and the image is sampled there (kornia's ``remap``). Pixels whose ray lies
beyond the lens's valid field (:func:`~ccs_kornia.modules.undistort.valid_field.valid_radius`) are black, like those
whose source lies outside the image.
"""

from __future__ import annotations

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.undistort.valid_field import check_camera
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["UndistortImage", "undistort_image", "undistortion_map"]

#: where a pixel of the view has no source: outside every image, so sampled as zero
_NO_SOURCE = -2.0


def _check_view(camera: Camera, new_K: torch.Tensor | None, max_radius: torch.Tensor | None) -> None:
    check_camera(camera)
    c = len(camera)
    if new_K is not None:
        check_tensor(new_K, "new_K", [c, 3, 3], what=f"for {c} camera(s)")
    if max_radius is not None:
        check_tensor(max_radius, "max_radius", [c], what=f"for {c} camera(s)")


def undistortion_map(
    camera: Camera,
    image_size: tuple[int, int],
    new_K: torch.Tensor | None = None,
    max_radius: torch.Tensor | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    r"""Where each pixel of the undistorted view comes from in the camera's image (``cv2.initUndistortRectifyMap``).

    Args:
        camera: ``C`` cameras (any models).
        image_size: ``(W, H)`` of the view.
        new_K: :math:`(C, 3, 3)` the view's camera (``None``: each camera's own ``K``).
        max_radius: :math:`(C,)` optional valid radius on the normalized plane: pixels whose ray is farther from the
            axis get no source.
        device: where the map is made (``None``: the camera's device).

    Returns:
        :math:`(C, H, W, 2)` float64 source pixels ``(x, y)``; ``(-2, -2)`` (outside every image) where there is none.

    Example:
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> K = torch.tensor([[50.0, 0, 32.0], [0, 50, 24.0], [0, 0, 1]], dtype=torch.float64)
        >>> src = undistortion_map(Camera.from_opencv(FISHEYE, K, torch.tensor([0.1, 0.0, 0.0, 0.0])), (64, 48))
        >>> src.shape, src[0, 24, 32].tolist()  # the optical axis stays where it is
        (torch.Size([1, 48, 64, 2]), [32.0, 24.0])
        >>> round(src[0, 24, 63, 0].item(), 2)  # the view's border comes from inside: 32 + 50 theta_d(atan(0.62))
        60.6
    """
    _check_view(camera, new_K, max_radius)
    w, h = int(image_size[0]), int(image_size[1])
    device = camera.device if device is None else torch.device(device)
    cam = camera.to(device=device, dtype=torch.float64)
    P = (cam.K if new_K is None else new_K).to(device=device, dtype=torch.float64)
    grid = create_meshgrid(h, w, normalized_coordinates=False, device=device, dtype=torch.float64).reshape(1, h * w, 2)
    # the view's pixels to its normalized plane (K^-1 [u, v, 1]^T)
    y = (grid[..., 1] - P[:, None, 1, 2]) / P[:, None, 1, 1]
    x = (grid[..., 0] - P[:, None, 0, 2] - P[:, None, 0, 1] * y) / P[:, None, 0, 0]
    src = cam.distort(torch.stack([x, y], -1))
    if max_radius is not None:
        beyond = torch.hypot(x, y) > max_radius.to(x)[:, None]
        src = torch.where(beyond[..., None], torch.full_like(src, _NO_SOURCE), src)
    return src.reshape(len(cam), h, w, 2)


def _check_images(images: torch.Tensor, camera: Camera) -> None:
    check_tensor(images, "images", ["B", "C", "H", "W"])
    if len(camera) not in (1, images.shape[0]):
        raise ValueError(f"{images.shape[0]} images need 1 or {images.shape[0]} cameras, got {len(camera)}.")


def _sample(images: torch.Tensor, src: torch.Tensor, mode: str) -> torch.Tensor:
    """``images`` sampled at ``src`` :math:`(1 | B, H, W, 2)`, in the images' dtype (integers: float32)."""
    dtype = images.dtype if images.is_floating_point() else torch.float32
    src = src.to(device=images.device, dtype=dtype)
    return remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode="zeros", align_corners=True)


def undistort_image(
    images: torch.Tensor,
    camera: Camera,
    new_K: torch.Tensor | None = None,
    max_radius: torch.Tensor | None = None,
    mode: str = "bilinear",
) -> torch.Tensor:
    r"""Images of a calibrated camera to pinhole images with camera ``new_K`` (``cv2.undistort``'s
    ``newCameraMatrix``, ``cv2.fisheye.undistortImage``'s ``Knew``), for every model.

    Args:
        images: :math:`(B, C, H, W)`.
        camera: ``B`` cameras, one per image, or one for all.
        new_K: :math:`(B, 3, 3)` (one camera: :math:`(1, 3, 3)`) the view's camera (``None``: the camera's own
            ``K``; see :func:`~ccs_kornia.modules.undistort.view_camera.view_camera_matrix`).
        max_radius: :math:`(B,)` (one camera: :math:`(1,)`) optional valid radius on the normalized plane
            (:func:`~ccs_kornia.modules.undistort.valid_field.valid_radius`): pixels whose ray is farther from the
            axis are zero too (no content folded back or extrapolated into a wide view's corners).
        mode: interpolation (``bilinear`` or ``nearest``).

    Returns:
        :math:`(B, C, H, W)` in the images' dtype (integer images: float32), zeros where the source lies outside the
        image or beyond the valid field. The map is computed in float64.

    Example:
        >>> from ccs_kornia.geometry.models import OPENCV5
        >>> K = torch.tensor([[50.0, 0, 31.5], [0, 50, 23.5], [0, 0, 1]])
        >>> img = torch.rand(2, 1, 48, 64)
        >>> out = undistort_image(img, Camera.from_opencv(OPENCV5, K))  # no distortion: the image again
        >>> out.shape, bool(torch.allclose(out, img, atol=1e-5))
        (torch.Size([2, 1, 48, 64]), True)
    """
    _check_images(images, camera)
    _check_view(camera, new_K, max_radius)
    h, w = images.shape[-2:]
    src = undistortion_map(camera, (w, h), new_K, max_radius, device=images.device)
    return _sample(images, src, mode)


class UndistortImage(torch.nn.Module):
    r"""Module form of :func:`undistort_image`: one camera's (or ``B`` cameras') images into views with camera
    ``new_K``; the map is made once per image size and kept (a video's frames, a folder of images).

    Args:
        camera: ``1`` or ``B`` cameras (any models).
        new_K: :math:`(C, 3, 3)` the view's camera (``None``: the camera's own ``K``).
        max_radius: :math:`(C,)` optional valid radius on the normalized plane.
        mode: interpolation.

    Example:
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> from ccs_kornia.modules.undistort.valid_field import valid_radius
        >>> from ccs_kornia.modules.undistort.view_camera import view_camera_matrix
        >>> K = torch.tensor([[40.0, 0, 31.5], [0, 40, 23.5], [0, 0, 1]], dtype=torch.float64)
        >>> fish = Camera.from_opencv(FISHEYE, K, torch.tensor([0.05, -0.01, 0.0, 0.0]), (64, 48))
        >>> radius = valid_radius(fish)
        >>> undistort = UndistortImage(fish, view_camera_matrix(fish, (64, 48), max_radius=radius), radius)
        >>> undistort(torch.rand(3, 1, 48, 64)).shape  # three frames of the camera, one map
        torch.Size([3, 1, 48, 64])
    """

    def __init__(self, camera: Camera, new_K: torch.Tensor | None = None, max_radius: torch.Tensor | None = None,
                 mode: str = "bilinear") -> None:
        super().__init__()
        _check_view(camera, new_K, max_radius)
        self.camera, self.new_K, self.max_radius, self.mode = camera, new_K, max_radius, mode
        self._maps: dict[tuple, torch.Tensor] = {}

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        _check_images(images, self.camera)
        key = (images.shape[-1], images.shape[-2], images.device)
        if key not in self._maps:
            self._maps = {key: undistortion_map(self.camera, key[:2], self.new_K, self.max_radius, images.device)}
        return _sample(images, self._maps[key], self.mode)
