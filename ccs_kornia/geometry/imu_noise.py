"""An IMU's noise as Kalibr's ``imu.yaml`` states it: the white noise and bias random walk densities of its gyroscope
and accelerometer (continuous time), and its rate.

A sample's white noise has the standard deviation ``noise_density * sqrt(update_rate)``; a bias moves by
``random_walk * sqrt(dt)`` in ``dt`` seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

__all__ = ["ImuNoise"]


@dataclass(frozen=True)
class ImuNoise:
    """An IMU's noise as Kalibr's ``imu.yaml`` states it (continuous-time densities) and its rate.

    Args:
        accelerometer_noise_density: white noise, m/s^2/sqrt(Hz).
        accelerometer_random_walk: bias random walk, m/s^3/sqrt(Hz).
        gyroscope_noise_density: white noise, rad/s/sqrt(Hz).
        gyroscope_random_walk: bias random walk, rad/s^2/sqrt(Hz).
        update_rate: samples per second (Hz), the rate the densities are discretised at.

    Example:
        >>> noise = ImuNoise.euroc()
        >>> noise.gyroscope_noise_density, noise.update_rate
        (0.000187, 200.0)
        >>> round(noise.discrete_gyroscope_sigma, 7)  # the white noise of one sample, rad/s
        0.0026446
    """

    accelerometer_noise_density: float
    accelerometer_random_walk: float
    gyroscope_noise_density: float
    gyroscope_random_walk: float
    update_rate: float

    @classmethod
    def euroc(cls) -> ImuNoise:
        """The ADIS16448 of the EuRoC recordings, as Kalibr's example ``imu.yaml`` gives it (200 Hz)."""
        return cls(accelerometer_noise_density=1.86e-03, accelerometer_random_walk=4.33e-04,
                   gyroscope_noise_density=1.87e-04, gyroscope_random_walk=2.66e-05, update_rate=200.0)

    @property
    def discrete_gyroscope_sigma(self) -> float:
        """The gyroscope's white noise per sample (rad/s): the density times ``sqrt(update_rate)``, as Kalibr
        discretises it."""
        return self.gyroscope_noise_density * math.sqrt(self.update_rate)

    @property
    def discrete_accelerometer_sigma(self) -> float:
        """The accelerometer's white noise per sample (m/s^2), as :attr:`discrete_gyroscope_sigma`."""
        return self.accelerometer_noise_density * math.sqrt(self.update_rate)

    def scaled(self, factor: float) -> ImuNoise:
        """Every density times ``factor`` (a user's values off by that much).

        Example:
            >>> ImuNoise.euroc().scaled(10.0).gyroscope_noise_density
            0.00187
        """
        return replace(self, accelerometer_noise_density=self.accelerometer_noise_density * factor,
                       accelerometer_random_walk=self.accelerometer_random_walk * factor,
                       gyroscope_noise_density=self.gyroscope_noise_density * factor,
                       gyroscope_random_walk=self.gyroscope_random_walk * factor)
