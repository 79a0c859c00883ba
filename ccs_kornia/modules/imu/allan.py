r"""The Allan deviation of a still IMU log, and Kalibr's noise values read off it.

:func:`allan_deviation` is the overlapping Allan deviation of each channel, computed from the channel's running sum
in :math:`O(N)` per averaging time and one channel at a time (memory: two copies of one channel, whatever the log's
length). :func:`noise_from_allan` reads the white noise density and the bias random walk off it as Kalibr's users and
``allan_variance_ros`` do: the :math:`-1/2` slope line read at :math:`\tau = 1` s is the noise density :math:`N`, the
:math:`+1/2` slope line read at :math:`\tau = 3` s is the random walk :math:`K`. The two lines and the flat floor
between them (the bias instability's) are fitted together to the Allan variance,

.. math::

    \sigma^2(\tau) = \frac{N^2}{\tau} + B^2 + \frac{K^2 \tau}{3},

so each line is read where it, not its neighbour, explains the curve; averaging times are weighted by the clusters
the log holds at each.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch

from ccs_kornia.runtime.checks import check_tensor
from ccs_kornia.runtime.errors import UserError

__all__ = ["AllanNoise", "allan_deviation", "allan_taus", "noise_from_allan"]

#: the longest default averaging time, as a fraction of the log: at least ten clusters at every one
LONGEST_TAU_FRACTION = 0.1
#: averaging times per decade of the default grid
TAUS_PER_DECADE = 12
#: the white noise is seen where its term is at least this share of the Allan variance at the shortest time
SEEN_SHARE = 0.5


@dataclass(frozen=True)
class AllanNoise:
    """The noise values of C channels read off their Allan deviation.

    Args:
        noise_density: :math:`(C,)` white noise density :math:`N` (the channel's unit times sqrt(s), i.e. per
            sqrt(Hz)): the :math:`-1/2` line at :math:`\\tau = 1` s.
        random_walk: :math:`(C,)` bias random walk :math:`K` (the unit per s times sqrt(s)): the :math:`+1/2` line at
            :math:`\\tau = 3` s.
        floor: :math:`(C,)` the flat term :math:`B` between them (the unit).
        taus: :math:`(T,)` the averaging times fitted (s).
    """

    noise_density: torch.Tensor
    random_walk: torch.Tensor
    floor: torch.Tensor
    taus: torch.Tensor

    def deviation(self, taus: torch.Tensor) -> torch.Tensor:
        """The fitted Allan deviation :math:`(T, C)` at ``taus`` :math:`(T,)` (s)."""
        tau = taus.to(self.noise_density.dtype)[:, None]
        return (self.noise_density**2 / tau + self.floor**2 + self.random_walk**2 * tau / 3).sqrt()


def allan_taus(samples: int, rate: float, longest: float | None = None) -> torch.Tensor:
    """The default averaging times (s): whole sample counts from one sample to ``longest`` seconds (default a tenth
    of the log), :data:`TAUS_PER_DECADE` per decade.

    Example:
        >>> allan_taus(1000, 100.0).tolist()[:5], float(allan_taus(1000, 100.0)[-1])
        ([0.01, 0.02, 0.03, 0.04, 0.05], 1.0)
    """
    last = max(1, int((longest if longest is not None else LONGEST_TAU_FRACTION * samples / rate) * rate))
    last = min(last, max(1, (samples - 1) // 2))
    grid = np.unique(np.round(np.logspace(0, math.log10(last), max(2, int(TAUS_PER_DECADE * math.log10(last)) + 1))))
    return torch.from_numpy(grid.astype(np.float64) / rate)


def allan_deviation(x: torch.Tensor, rate: float, taus: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The overlapping Allan deviation of each channel of a regularly sampled signal.

    .. math::

        \sigma^2(\tau) = \frac{1}{2 \tau^2 (N - 2m + 1)} \sum_{k=0}^{N-2m} (\theta_{k+2m} - 2\theta_{k+m} + \theta_k)^2,

    :math:`\tau = m / \mathrm{rate}`, :math:`\theta` the signal's running integral. Computed in float64, one channel at
    a time.

    Args:
        x: :math:`(N, C)` samples (e.g. a gyroscope's rad/s).
        rate: samples per second (Hz).
        taus: :math:`(T,)` averaging times (s), rounded to whole samples (default :func:`allan_taus`).

    Returns:
        ``(taus, adev)``: :math:`(T',)` the averaging times used (s; those of at most half the log, once each) and
        :math:`(T', C)` the Allan deviation (the unit of ``x``).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> x = 0.01 * torch.randn(100_000, 1, dtype=torch.float64, generator=g)  # white noise at 100 Hz
        >>> taus, adev = allan_deviation(x, 100.0, torch.tensor([1.0, 10.0]))
        >>> taus.tolist(), (adev[:, 0] * taus.sqrt()).round(decimals=3).tolist()  # 0.01 / sqrt(100) = 0.001
        ([1.0, 10.0], [0.001, 0.001])
    """
    check_tensor(x, "x", ["N", "C"], what="samples")
    if not rate > 0:
        raise ValueError(f"rate must be a positive number of samples per second, got {rate}")
    n = x.shape[0]
    if n < 3:
        raise ValueError(f"an Allan deviation needs at least 3 samples, got {n}")
    if taus is None:
        taus = allan_taus(n, rate)
    m = torch.unique(torch.round(torch.as_tensor(taus, dtype=torch.float64) * rate).long())
    m = m[(m >= 1) & (m <= (n - 1) // 2)]
    out = torch.empty(len(m), x.shape[1], dtype=torch.float64)
    for c in range(x.shape[1]):
        channel = x[:, c].detach().to("cpu", torch.float64)
        theta = torch.zeros(n + 1, dtype=torch.float64)
        # the mean is taken out first: the deviation does not see it, and the running sum keeps its precision
        torch.cumsum(channel - channel.mean(), 0, out=theta[1:])
        del channel
        for k, step in enumerate(m.tolist()):
            d = theta[2 * step :] - 2 * theta[step : n + 1 - step] + theta[: n + 1 - 2 * step]
            out[k, c] = d.square().mean() / (2.0 * step * step)
    return m.double() / rate, out.sqrt()


def _nnls(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The non-negative least-squares solution of ``A z = b`` for a few unknowns: every active set tried."""
    best, best_cost = np.zeros(A.shape[1]), float(b @ b)
    for size in range(1, A.shape[1] + 1):
        for cols in itertools.combinations(range(A.shape[1]), size):
            z, *_ = np.linalg.lstsq(A[:, cols], b, rcond=None)
            if (z >= 0).all():
                full = np.zeros(A.shape[1])
                full[list(cols)] = z
                cost = float(np.square(A @ full - b).sum())
                if cost < best_cost:
                    best, best_cost = full, cost
    return best


def _duration_text(seconds: float) -> str:
    if seconds >= 3600:
        return f"{seconds / 3600:.1f} h"
    if seconds >= 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds:.0f} s"


def noise_from_allan(taus: torch.Tensor, adev: torch.Tensor, duration: float,
                     names: list[str] | None = None) -> AllanNoise:
    r"""The white noise density and bias random walk of each channel, read off its Allan deviation.

    The model :math:`\sigma^2(\tau) = N^2 / \tau + B^2 + K^2 \tau / 3` is fitted to the Allan variance by non-negative
    least squares on relative residuals, each averaging time weighted by the clusters the log holds there
    (``duration / tau``): :math:`N` is the :math:`-1/2` slope line read at 1 s, :math:`K` the :math:`+1/2` slope line
    read at 3 s.

    Args:
        taus: :math:`(T,)` averaging times (s), increasing.
        adev: :math:`(T, C)` the Allan deviation (:func:`allan_deviation`).
        duration: the log's length (s): the weights, and how long a log it would take where a line is not seen.
        names: the channels' names for the messages (default ``channel 0``, ...).

    Returns:
        the fitted values per channel.

    Raises:
        UserError: a channel whose curve does not fall along the :math:`-1/2` slope at its shortest averaging times
            (not white noise there), or where the :math:`+1/2` line does not rule the curve over the last factor of
            three of its averaging times (the log is too short for the random walk: the message says how long a log is
            needed).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> rate, n = 100.0, 200_000
        >>> walk = torch.cumsum(1e-4 / rate**0.5 * torch.randn(n, 1, dtype=torch.float64, generator=g), 0)
        >>> x = 1e-3 * rate**0.5 * torch.randn(n, 1, dtype=torch.float64, generator=g) + walk  # N = 1e-3, K = 1e-4
        >>> noise = noise_from_allan(*allan_deviation(x, rate), duration=n / rate)
        >>> round(float(noise.noise_density[0]), 4), round(float(noise.random_walk[0]), 4)
        (0.001, 0.0001)
    """
    check_tensor(adev, "adev", ["T", "C"], what="Allan deviations")
    check_tensor(taus, "taus", ["T"], T=adev.shape[0])
    tau = taus.detach().cpu().double().numpy()
    dev = adev.detach().cpu().double().numpy()
    clusters = duration / tau
    keep = (clusters >= 3) & np.isfinite(dev).all(1) & (dev > 0).all(1)
    if keep.sum() < 4:
        raise UserError(f"the log ({_duration_text(duration)}) gives too few averaging times for an Allan deviation")
    tau, dev, clusters = tau[keep], dev[keep], clusters[keep]
    basis = np.stack([1.0 / tau, np.ones_like(tau), tau / 3.0], 1)  # N^2, B^2, K^2
    out = np.zeros((dev.shape[1], 3))
    for c in range(dev.shape[1]):
        avar = dev[:, c] ** 2
        w = np.sqrt(clusters)
        out[c] = _nnls(basis * (w / avar)[:, None], w)
        name = names[c] if names else f"channel {c}"
        n2, b2, k2 = out[c]
        if n2 / tau[0] < SEEN_SHARE * avar[0]:
            raise UserError(f"{name}: the Allan deviation does not fall along the -1/2 slope at the shortest averaging "
                            f"time ({tau[0]:.3g} s): no white noise to read (is the log still, at its raw rate?)")
        # where the +1/2 line takes over (K^2 tau / 3 = N^2 / tau + B^2): it is read where it rules, from three times
        # that on, so the log must reach there with ten clusters (thirty times the crossing); without a random walk
        # term at all, ten times this log at least
        crossing = (b2 + math.sqrt(b2 * b2 + 4.0 * k2 / 3.0 * n2)) / (2.0 * k2 / 3.0) if k2 > 0 else math.inf
        if not 3.0 * crossing <= tau[-1]:
            needed = max(2.0 * duration, 3.0 * crossing / LONGEST_TAU_FRACTION if k2 > 0 else 10.0 * duration)
            raise UserError(f"{name}: the log is {_duration_text(duration)} long and its Allan deviation does not "
                            f"rise along the +1/2 slope up to {tau[-1]:.3g} s: the random walk cannot be read; "
                            f"record a still log of at least {_duration_text(needed)}")
    values = torch.from_numpy(np.sqrt(out))
    return AllanNoise(noise_density=values[:, 0], random_walk=values[:, 2], floor=values[:, 1],
                      taus=torch.from_numpy(tau))
