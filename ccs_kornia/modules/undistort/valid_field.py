r"""The valid field of a calibrated lens: how far from the optical axis its model may be trusted.

A lens model is trusted where its radial mapping is monotonic (beyond the first turning point several directions
share one image radius, and undistorting there folds the image back onto itself: each model's own rule,
:meth:`~ccs_kornia.geometry.models.base.CameraModel.monotonic_radius`), where the calibration's corners reached
(beyond them the model is extrapolated) and within :data:`MAX_VIEW_ANGLE_DEG` of the axis. The field is a radius on
the normalized (``z = 1``) plane, ``tan`` of the angle from the axis, for every model alike. The image's own extent
is applied when the view is framed (:func:`~ccs_kornia.modules.undistort.view_camera.view_camera_matrix`).
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["MAX_VIEW_ANGLE_DEG", "check_camera", "valid_radius"]

#: The widest angle from the axis a pinhole view is asked to show: at 90 degrees its image plane is infinite, and
#: near it a few degrees of field take most of the pixels. Models valid beyond it (lenses over 160 degrees) are cut.
MAX_VIEW_ANGLE_DEG = 80.0


def check_camera(camera: Camera) -> None:
    """Raise ``TypeError`` unless ``camera`` is a :class:`~ccs_kornia.geometry.camera.Camera`: the undistortion
    functions take the camera value only (no ``K`` and coefficients apart), and say so at their boundary.

    Example:
        >>> check_camera("K.yaml")
        Traceback (most recent call last):
        ...
        TypeError: camera must be a ccs_kornia.geometry.camera.Camera, got str.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a ccs_kornia.geometry.camera.Camera, got {type(camera).__name__}.")


def valid_radius(camera: Camera, points: torch.Tensor | None = None) -> torch.Tensor:
    r"""The valid field of each camera's lens, as the largest radius on the normalized (``z = 1``) plane.

    The smallest of: the radius up to which the model's radial mapping increases
    (:meth:`~ccs_kornia.geometry.models.base.CameraModel.monotonic_radius`, the model's own rule), the widest radius
    the ``points`` reach (the calibration's corners), and ``tan`` of :data:`MAX_VIEW_ANGLE_DEG`. Computed in float64.

    Args:
        camera: ``B`` cameras (any models).
        points: :math:`(B, N, 2)` optional pixels seen in calibration (NaN rows are ignored; a point a fisheye sees
            at or beyond 90 degrees bounds nothing).

    Returns:
        :math:`(B,)` float64 radius (``tan`` of the angle from the axis).

    Example:
        >>> from ccs_kornia.geometry.models import OPENCV5, FISHEYE
        >>> K = torch.tensor([[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]], dtype=torch.float64)
        >>> barrel = Camera.from_opencv(OPENCV5, K, torch.tensor([-0.3, 0.0, 0.0, 0.0, 0.0]), (640, 480))
        >>> round(valid_radius(barrel).item(), 2)  # r_d' = 1 - 0.9 r^2: just below 1 / sqrt(0.9) = 1.054
        1.05
        >>> fish = Camera.from_opencv(FISHEYE, K, torch.tensor([-0.3, 0.0, 0.0, 0.0]), (640, 480))
        >>> round(math.degrees(valid_radius(fish).atan().item()), 1)  # theta_d' = 1 - 0.9 theta^2
        60.4
        >>> corner = fish.distort(torch.tensor([[[0.5, 0.0]]], dtype=torch.float64))  # a corner seen at tan = 0.5
        >>> round(valid_radius(fish, corner).item(), 12)
        0.5
    """
    check_camera(camera)
    cam = camera.to(dtype=torch.float64)
    max_angle = math.radians(MAX_VIEW_ANGLE_DEG)
    radius = cam.params.new_empty(len(cam))
    for model in dict.fromkeys(cam.models):
        index = [i for i, m in enumerate(cam.models) if m == model]
        idx = torch.tensor(index, device=cam.device)
        radius[idx] = model.monotonic_radius(cam.params[idx, : model.num_params], max_angle)
    if points is not None:
        check_tensor(points, "points", [len(cam), "N", 2])
        rays = cam.unproject(points.to(device=cam.device, dtype=torch.float64))
        z = rays[..., 2]
        # tan of each ray's angle from the axis; a ray at or beyond 90 degrees bounds nothing
        reach = torch.where(z > 0, torch.hypot(rays[..., 0], rays[..., 1]) / z, torch.full_like(z, math.inf))
        reach = torch.where(rays.isfinite().all(-1), reach, torch.zeros_like(reach))  # NaN rows: hidden corners
        seen = reach.amax(-1)
        radius = torch.minimum(radius, torch.where(seen > 0, seen, radius))
    return radius
