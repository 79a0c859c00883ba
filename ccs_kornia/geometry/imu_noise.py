"""An IMU's noise as Kalibr's ``imu.yaml`` states it: the white noise and bias random walk densities of its gyroscope
and accelerometer (continuous time), and its rate.

A sample's white noise has the standard deviation ``noise_density * sqrt(update_rate)``; a bias moves by
``random_walk * sqrt(dt)`` in ``dt`` seconds.

Example:
    >>> n = ImuNoise.euroc()
    >>> round(n.gyroscope_sample_sigma, 6)
    0.0024
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

__all__ = ["ImuNoise"]


@dataclass(frozen=True)
class ImuNoise:
    """An IMU's noise densities (Kalibr's names and units) and sample rate."""

    accelerometer_noise_density: float  #: m/s^2/sqrt(Hz)
    accelerometer_random_walk: float  #: m/s^3/sqrt(Hz)
    gyroscope_noise_density: float  #: rad/s/sqrt(Hz)
    gyroscope_random_walk: float  #: rad/s^2/sqrt(Hz)
    update_rate: float = 200.0  #: Hz

    @classmethod
    def euroc(cls, update_rate: float = 200.0) -> ImuNoise:
        """EuRoC's ADIS16448, as Kalibr's example ``imu.yaml`` states it."""
        return cls(accelerometer_noise_density=2.0e-3, accelerometer_random_walk=3.0e-3,
                   gyroscope_noise_density=1.6968e-4, gyroscope_random_walk=1.9393e-5, update_rate=update_rate)

    @property
    def gyroscope_sample_sigma(self) -> float:
        """One gyroscope sample's white noise (rad/s)."""
        return self.gyroscope_noise_density * math.sqrt(self.update_rate)

    @property
    def accelerometer_sample_sigma(self) -> float:
        """One accelerometer sample's white noise (m/s^2)."""
        return self.accelerometer_noise_density * math.sqrt(self.update_rate)

    def scaled(self, factor: float) -> ImuNoise:
        """Every density times ``factor`` (a user's values off by that much)."""
        return replace(self, accelerometer_noise_density=self.accelerometer_noise_density * factor,
                       accelerometer_random_walk=self.accelerometer_random_walk * factor,
                       gyroscope_noise_density=self.gyroscope_noise_density * factor,
                       gyroscope_random_walk=self.gyroscope_random_walk * factor)
