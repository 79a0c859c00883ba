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
from typing import NamedTuple

import torch

__all__ = ["ImuIntrinsics", "ImuModel", "KalibrImuMatrices"]


class ImuModel(enum.Enum):
    """What the camera-IMU fit assumes of the IMU (Kalibr's ``--imu-models`` names)."""

    #: an ideal IMU: its readings are the true rate and specific force plus biases and noise
    CALIBRATED = "calibrated"
    #: :class:`ImuIntrinsics` estimated: scale factors, misalignment, the gyroscope's rotation and g-sensitivity
    SCALE_MISALIGNMENT = "scale-misalignment"


class KalibrImuMatrices(NamedTuple):
    r"""The intrinsics in Kalibr's ``scale-misalignment`` convention (its ``imu-*.yaml`` result file).

    Kalibr's accelerometer matrix is lower triangular, so its IMU frame is not the one :class:`ImuIntrinsics` uses
    (upper triangular): the two differ by the rotation ``R_kalibr_imu`` (``f_kalibr = R f``), and a pose on Kalibr's
    IMU is ``T_cam_imu`` times that rotation's inverse. Kalibr's readings are
    :math:`a_m = M_a f_k + b_a` and :math:`\omega_m = M_g C\,\omega_k + A\,C f_k + b_g`.
    """

    accel_M: torch.Tensor  #: (3, 3) lower triangular, Kalibr's ``accelerometers: M``
    gyro_M: torch.Tensor  #: (3, 3) lower triangular, ``gyroscopes: M``
    gyro_C: torch.Tensor  #: (3, 3) a rotation, ``gyroscopes: C_gyro_i``
    gyro_A: torch.Tensor  #: (3, 3) rad/s per m/s^2, ``gyroscopes: A``
    R_kalibr_imu: torch.Tensor  #: (3, 3) the rotation from this frame to Kalibr's IMU frame


def _lower_times_rotation(X: torch.Tensor, what: str) -> tuple[torch.Tensor, torch.Tensor]:
    """``X = L Q``: ``L`` lower triangular with a positive diagonal, ``Q`` a rotation (from the QR of ``X^T``)."""
    if float(torch.linalg.det(X)) <= 0:
        raise ValueError(f"{what} mirrors an axis (determinant <= 0): it is no scale-misalignment of a rotation")
    Q1, R1 = torch.linalg.qr(X.T)
    D = torch.diag(torch.sign(torch.diagonal(R1)))
    return (D @ R1).T, D @ Q1.T


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

    def to_kalibr(self) -> KalibrImuMatrices:
        """The same IMU in Kalibr's convention (:class:`KalibrImuMatrices`): the same readings of the same motion.

        Returns:
            Kalibr's four matrices and the rotation between the two IMU frames.

        Raises:
            ValueError: a sensor matrix that mirrors an axis (no rotation relates the frames).

        Example:
            >>> imu = ImuIntrinsics.identity()
            >>> imu.accel_matrix[0, 1] = 0.004  # the accelerometer's x axis leans towards y
            >>> k = imu.to_kalibr()
            >>> bool(k.accel_M[0, 1] == 0), round(float(torch.linalg.det(k.R_kalibr_imu)), 6)
            (True, 1.0)
            >>> f = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
            >>> bool(torch.allclose((k.R_kalibr_imu @ f.T).T @ k.accel_M.T, imu.apply(f, f)[1]))
            True
        """
        accel_M, R = _lower_times_rotation(self.accel_matrix, "the accelerometer's matrix")
        gyro_M, C = _lower_times_rotation(self.gyro_matrix @ R.T, "the gyroscope's matrix")
        return KalibrImuMatrices(accel_M, gyro_M, C, self.g_sensitivity @ R.T @ C.T, R)
