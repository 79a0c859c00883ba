r"""Whether an ideal IMU's residuals show the intrinsics it was not fitted with: a scale or axis error makes a
sensor's residual follow its own reading.

With the IMU taken as calibrated, a gyroscope whose true response is ``(I + E) w`` leaves the residual ``r ~ E w``
(the biases' slow walk cannot follow a term that changes with the motion). :func:`residual_scale` regresses each
sensor's residuals on its readings, ``r = E m`` in least squares over the recording, and gives ``E``'s largest entry
with its significance (the entry over its standard error, the residuals' own spread setting the noise). A large,
significant ``E`` is what ``--imu-model scale-misalignment`` estimates.
"""

from __future__ import annotations

import torch

__all__ = ["residual_scale"]


def residual_scale(readings: torch.Tensor, residuals: torch.Tensor) -> tuple[float, float]:
    """The largest entry of ``E`` in ``residuals ~ readings E^T`` (both :math:`(N, 3)`, the residuals' means removed)
    and its ratio to its standard error.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> w = torch.randn(2000, 3, generator=g, dtype=torch.float64)
        >>> r = 0.01 * w[:, [0]] * torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)  # x reads 1 % high
        >>> r = r + 1e-3 * torch.randn(2000, 3, generator=g, dtype=torch.float64)
        >>> e, z = residual_scale(w, r)
        >>> round(e, 3), z > 50
        (0.01, True)
    """
    m = readings - readings.mean(0)
    r = residuals - residuals.mean(0)
    G = m.T @ m
    Gi = torch.linalg.inv(G)
    E = (r.T @ m) @ Gi  # (3, 3): row i the response of axis i's residual to the readings
    fitted = m @ E.T
    dof = max(m.shape[0] - 3, 1)
    sigma2 = ((r - fitted) ** 2).sum(0) / dof  # (3,) per residual axis
    se = (sigma2[:, None] * Gi.diagonal()[None, :]).sqrt()
    k = int(E.abs().argmax())
    return float(E.flatten()[k].abs()), float((E.abs() / se.clamp_min(1e-300)).flatten()[k])
