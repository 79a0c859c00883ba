"""The Allan deviation and the noise values read off it (``modules/imu/allan.py``): known white noise and random
walk recovered, the refusals of a log too short and of one without white noise."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.modules.imu import (
    AllanNoise,
    allan_deviation,
    allan_taus,
    noise_from_allan,
)
from ccs_kornia.runtime.errors import UserError


def _signal(seconds: float, rate: float, white: float, walk: float, channels: int = 3, seed: int = 0,
            offset: float = 0.0) -> torch.Tensor:
    """White noise of density ``white`` plus a random walk of ``walk`` (per sqrt(Hz)), sampled at ``rate``."""
    g = torch.Generator().manual_seed(seed)
    n = int(seconds * rate)
    noise = white * math.sqrt(rate) * torch.randn(n, channels, dtype=torch.float64, generator=g)
    steps = walk / math.sqrt(rate) * torch.randn(n, channels, dtype=torch.float64, generator=g)
    return noise + torch.cumsum(steps, 0) + offset


def _overlapping_adev(x: torch.Tensor, m: int, rate: float) -> torch.Tensor:
    """The textbook overlapping Allan deviation: differences of averages of m samples, one start per sample."""
    means = x.unfold(0, m, 1).mean(-1)  # (N - m + 1, C) averages of m samples from every start
    d = means[m:] - means[:-m]
    return (0.5 * d.square().mean(0)).sqrt()


def test_matches_the_definition():
    x = _signal(60.0, 50.0, 1e-2, 1e-3, channels=2, offset=9.81)
    taus, adev = allan_deviation(x, 50.0, torch.tensor([0.02, 0.1, 1.0, 5.0]))
    assert taus.tolist() == [0.02, 0.1, 1.0, 5.0] and adev.shape == (4, 2) and adev.dtype == torch.float64
    for k, tau in enumerate(taus.tolist()):
        assert torch.allclose(adev[k], _overlapping_adev(x, round(tau * 50.0), 50.0), rtol=1e-9)


def test_white_noise_alone_follows_the_minus_half_slope():
    x = _signal(2000.0, 100.0, 2e-3, 0.0, channels=1)
    taus, adev = allan_deviation(x, 100.0)
    assert float(taus[0]) == 0.01 and float(taus[-1]) == pytest.approx(200.0)  # one sample to a tenth of the log
    ratio = adev[:, 0] * taus.sqrt() / 2e-3  # N / sqrt(tau)
    assert float((ratio - 1).abs()[taus < 20].max()) < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_known_noise_is_recovered(seed):
    # the ADIS16448 (gyroscope) and a consumer accelerometer's values, one hour at 200 Hz
    rate, seconds = 200.0, 3600.0
    for white, walk in ((1.87e-4, 2.66e-5), (1.86e-3, 4.33e-4)):
        x = _signal(seconds, rate, white, walk, seed=seed, offset=0.05)
        fit = noise_from_allan(*allan_deviation(x, rate), duration=seconds)
        assert isinstance(fit, AllanNoise) and fit.noise_density.shape == (3,)
        white_error = (fit.noise_density / white - 1).abs().max()
        walk_error = (fit.random_walk / walk - 1).abs().max()
        assert float(white_error) < 0.02, fit.noise_density
        assert float(walk_error) < 0.2, fit.random_walk
        assert float((fit.random_walk.mean() / walk - 1).abs()) < 0.12
        # the fitted curve runs through the measured one
        taus, adev = allan_deviation(x, rate)
        assert float((fit.deviation(taus) / adev - 1).abs()[taus < 20].max()) < 0.1


def test_a_log_too_short_for_the_random_walk_says_how_long_is_needed():
    rate, seconds = 200.0, 120.0  # two minutes of the ADIS16448: the random walk shows only after some 10 s
    x = _signal(seconds, rate, 1.87e-4, 2.66e-5, channels=1)
    with pytest.raises(UserError, match=r"gyroscope x: the log is 2 min long and its Allan deviation does not rise "
                                        r"along the \+1/2 slope up to 12 s: the random walk cannot be read; record a "
                                        r"still log of at least (\d+) min") as err:
        noise_from_allan(*allan_deviation(x, rate), duration=seconds, names=["gyroscope x"])
    needed = float(str(err.value).rsplit("at least ", 1)[1].split()[0])
    # where the +1/2 line rules (K^2 tau / 3 = N^2 / tau: tau = sqrt(3) N / K, about 12 s), thirty times over
    assert 4 <= needed <= 20
    # a log without any random walk: ten times this one at least
    with pytest.raises(UserError, match=r"record a still log of at least 20 min"):
        noise_from_allan(*allan_deviation(_signal(seconds, rate, 1e-3, 0.0, channels=1), rate), duration=seconds)


def test_a_curve_without_white_noise_is_refused():
    # a random walk alone (a log integrated, or resampled far below its rate): no -1/2 slope to read
    x = _signal(600.0, 100.0, 0.0, 1e-3, channels=1)
    with pytest.raises(UserError, match=r"channel 0: the Allan deviation does not fall along the -1/2 slope"):
        noise_from_allan(*allan_deviation(x, 100.0), duration=600.0)


def test_shapes_and_arguments():
    with pytest.raises(ValueError, match=r"x must be \(N, C\)"):
        allan_deviation(torch.zeros(100), 10.0)
    with pytest.raises(ValueError, match="rate must be a positive number"):
        allan_deviation(torch.zeros(100, 1), 0.0)
    taus, adev = allan_deviation(torch.randn(100, 1, dtype=torch.float64), 10.0, torch.tensor([0.1, 0.1, 0.14, 9.0]))
    assert taus.tolist() == [0.1] and adev.shape == (1, 1)  # rounded to whole samples, once each, within half the log
    assert allan_taus(10_000, 100.0, longest=5.0)[-1].item() == 5.0
    with pytest.raises(ValueError, match=r"taus must be \(T,\) with T=3"):
        noise_from_allan(torch.ones(2), torch.ones(3, 1), 10.0)
