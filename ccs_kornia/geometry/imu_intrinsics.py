r"""An IMU's intrinsics: how its gyroscope and accelerometer read the true angular rate and specific force.

The model is Kalibr's ``scale-misalignment`` (Rehder et al., "Extending kalibr: Calibrating the extrinsics of
multiple IMUs and of individual axes", ICRA 2016), written as three matrices acting on the IMU frame's true angular
rate :math:`\omega` and specific force :math:`f` (the accelerometer's axes define the IMU frame):

.. math::

    \omega_m = T_g\,\omega + A_g\,f + b_g, \qquad a_m = T_a\,f + b_a

* :math:`T_g` (3x3, 9 values): the gyroscope's scale factors, its axes' misalignment and their rotation from the
  accelerometer's (any invertible matrix: a triangular scale-misalignment times a rotation);
* :math:`T_a` (3x3 upper triangular, 6 values): the accelerometer's scale factors and misalignment (a rotation of its
  axes is the IMU frame's and moves ``T_cam_imu`` instead);
* :math:`A_g` (3x3, 9 values): the gyroscope's sensitivity to acceleration (g-sensitivity), rad/s per m/s^2.

An ideal IMU (:meth:`ImuIntrinsics.identity`) has ``T_g = T_a = I``, ``A_g = 0``; :class:`ImuModel` says which of the
two the camera-IMU fit assumes.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import torch

__all__ = ["ImuIntrinsics", "ImuModel"]


class ImuModel(enum.Enum):
    """What the camera-IMU fit assumes of the IMU (Kalibr's ``--imu-models`` names)."""

    #: an ideal IMU: its readings are the true rate and specific force plus biases and noise
    CALIBRATED = "calibrated"
    #: :class:`ImuIntrinsics` estimated: scale factors, misalignment, the gyroscope's rotation and g-sensitivity
    SCALE_MISALIGNMENT = "scale-misalignment"


#: the upper triangle of a 3x3 matrix, row by row: the accelerometer's 6 values
UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


@dataclass
class ImuIntrinsics:
    """The three matrices of the module doc (float64, shape ``(3, 3)`` each).

    Example:
        >>> imu = ImuIntrinsics.identity()
        >>> imu.accel_matrix[0, 0] = 1.01  # the accelerometer's x axis reads 1 % high
        >>> w = torch.tensor([[0.1, 0.0, 0.0]], dtype=torch.float64)
        >>> f = torch.tensor([[9.81, 0.0, 0.0]], dtype=torch.float64)
        >>> [x.round(decimals=4).tolist() for x in imu.apply(w, f)]
        [[[0.1, 0.0, 0.0]], [[9.9081, 0.0, 0.0]]]
    """

    gyro_matrix: torch.Tensor
    accel_matrix: torch.Tensor
    g_sensitivity: torch.Tensor

    @classmethod
    def identity(cls, dtype: torch.dtype = torch.float64) -> ImuIntrinsics:
        eye = torch.eye(3, dtype=dtype)
        return cls(eye.clone(), eye.clone(), torch.zeros(3, 3, dtype=dtype))

    def apply(self, rate: torch.Tensor, force: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The readings (before biases and noise) of true rates and specific forces :math:`(N, 3)`."""
        return rate @ self.gyro_matrix.T + force @ self.g_sensitivity.T, force @ self.accel_matrix.T
