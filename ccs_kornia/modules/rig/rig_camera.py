"""One camera of a rig: :class:`RigCamera` (model name, ``K``, coefficients) and its conversions.

A :class:`RigCamera` is what the rig solver takes as a start or a fixed camera and what it returns per camera. Its
coefficients follow the single-camera solver's :class:`~ccs_kornia.modules.calibration.result.CalibrationResult`:
OpenCV order with :data:`~ccs_kornia.geometry.camera.DISTORTION_MODELS` entries (``none``: 0, ``k1k2``: 5 with
``p1 = p2 = k3 = 0``, ``opencv5``: 5, ``rational``: 8) and ``k1..k4`` for ``fisheye``, so ``K`` and ``dist`` drop into
``cv2`` unchanged. Shorter inputs are accepted (missing coefficients are zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.geometry.camera import (
    DISTORTION_MODELS,
    intrinsics_matrix,
    kb_undistort_points,
    undistort_pixels,
)
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import camera_model
from ccs_kornia.geometry.models.fisheye import KannalaBrandtModel

__all__ = ["RIG_MODELS", "RigCamera", "camera_params", "camera_from_params", "normalized_points"]

#: camera model names a rig accepts (the single-camera solver's names)
RIG_MODELS: tuple[str, ...] = (*DISTORTION_MODELS, KannalaBrandtModel.name)


@dataclass
class RigCamera:
    """A camera's intrinsics: model name, camera matrix and distortion coefficients.

    Args:
        model: ``"none" | "k1k2" | "opencv5" | "rational" | "fisheye"``.
        K: :math:`(3, 3)` camera matrix.
        dist: :math:`(D,)` coefficients in OpenCV order (``fisheye``: ``k1..k4``).

    Example:
        >>> cam = RigCamera("k1k2", torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]]), torch.tensor([-0.1, 0.01]))
        >>> camera_params(cam).tolist()
        [500.0, 500.0, 320.0, 240.0, -0.10000000149011612, 0.009999999776482582]
    """

    model: str
    K: torch.Tensor
    dist: torch.Tensor

    @property
    def camera(self) -> CameraModel:
        """The camera model named :attr:`model`."""
        return camera_model(self.model)

    def __post_init__(self) -> None:
        if self.model not in RIG_MODELS:
            raise ValueError(f"Unknown camera model {self.model!r}; expected one of {sorted(RIG_MODELS)}.")
        if not isinstance(self.K, torch.Tensor) or self.K.shape != (3, 3):
            raise ValueError(f"RigCamera.K must be a (3, 3) tensor, got {tuple(getattr(self.K, 'shape', ()))}.")
        if self.dist is None:
            self.dist = self.K.new_zeros(0)
        limit = self.camera.max_coeffs
        if not isinstance(self.dist, torch.Tensor) or self.dist.dim() != 1 or self.dist.shape[0] > limit:
            raise ValueError(f"RigCamera.dist must be (D,) with D <= {limit} for {self.model!r}, got "
                             f"{tuple(getattr(self.dist, 'shape', ()))}.")


def camera_params(cam: RigCamera, dtype: torch.dtype | None = None) -> torch.Tensor:
    """The LM model's parameter vector :math:`(P,)` (``fx, fy, cx, cy`` and the model's coefficients)."""
    dtype = dtype or cam.K.dtype
    return cam.camera.params_from(cam.K.to(dtype)[None], cam.dist.to(dtype)[None])[0]


def camera_from_params(model_name: str, params: torch.Tensor) -> RigCamera:
    """A :class:`RigCamera` from the LM parameter vector :math:`(P,)` of ``model_name``."""
    K = intrinsics_matrix(params[:4])
    return RigCamera(model_name, K, camera_model(model_name).coeffs_from(params[None])[0])


def normalized_points(cam: RigCamera, pixels: torch.Tensor) -> torch.Tensor:
    """Observed (distorted) pixels :math:`(*, N, 2)` to undistorted normalized coordinates ``(X / Z, Y / Z)``.

    ``cv2.undistortPoints`` for the pinhole models, ``cv2.fisheye.undistortPoints`` for ``fisheye`` (meaningful below
    90 degrees from the axis).
    """
    shape = pixels.shape
    pixels = pixels.reshape(1, -1, 2)
    K = cam.K.to(device=pixels.device, dtype=pixels.dtype)
    lens = cam.camera
    if lens.is_fisheye:
        D = lens.opencv_coeffs(cam.dist.to(device=pixels.device, dtype=pixels.dtype))
        return kb_undistort_points(pixels, K[None], D[None]).reshape(shape)
    if lens.num_coeffs == 0 or cam.dist.numel() == 0:
        ideal = pixels
    else:
        d = lens.opencv_coeffs(cam.dist.to(pixels.dtype))
        ideal = undistort_pixels(pixels, K[None], d[None])
    x = (ideal[..., 0] - K[0, 2]) / K[0, 0]
    y = (ideal[..., 1] - K[1, 2]) / K[1, 1]
    return torch.stack([x, y], -1).reshape(shape)
