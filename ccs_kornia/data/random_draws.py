"""Seeded random draws of the renderer's scenes: the same generator state gives the same numbers on every device.

Each draw is made on the generator's own device (a CPU generator is the rule here) and only then moved to
``device``, so a scene drawn for the GPU is the scene drawn for the CPU.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["seeded_rand", "seeded_randint", "seeded_uniform"]


def seeded_rand(generator: torch.Generator, shape, device, dtype=torch.float64) -> Tensor:
    """Uniform draws in ``[0, 1)`` of ``shape``, made on the generator's device and moved to ``device``.

    Args:
        generator: the random source; its device is where the numbers are drawn.
        shape: shape of the draws.
        device: where the result goes.
        dtype: floating dtype of the draws (float64 by default: poses and lenses are sampled in float64).

    Returns:
        a tensor of ``shape`` on ``device``.

    Example:
        >>> seeded_rand(torch.Generator().manual_seed(0), (2, 3), "cpu").shape
        torch.Size([2, 3])
    """
    return torch.rand(shape, generator=generator, device=generator.device, dtype=dtype).to(device)


def seeded_uniform(generator: torch.Generator, shape, lo: float, hi: float, device, dtype=torch.float64) -> Tensor:
    """Uniform draws in ``[lo, hi)`` of ``shape`` (:func:`seeded_rand` scaled), on ``device``.

    Args:
        generator: the random source.
        shape: shape of the draws.
        lo, hi: the range.
        device: where the result goes.
        dtype: floating dtype of the draws.

    Returns:
        a tensor of ``shape`` on ``device``.

    Example:
        >>> x = seeded_uniform(torch.Generator().manual_seed(0), (100,), -2.0, 3.0, "cpu")
        >>> bool((x >= -2).all() and (x < 3).all())
        True
    """
    return lo + (hi - lo) * seeded_rand(generator, shape, device, dtype)


def seeded_randint(generator: torch.Generator, lo: int, hi_inclusive: int, shape, device) -> Tensor:
    """Integer draws in ``[lo, hi_inclusive]`` (both ends included: the ranges of board sizes are inclusive), on
    ``device``.

    Args:
        generator: the random source; its device is where the numbers are drawn.
        lo, hi_inclusive: the smallest and the largest value.
        shape: shape of the draws.
        device: where the result goes.

    Returns:
        a long tensor of ``shape`` on ``device``.

    Example:
        >>> x = seeded_randint(torch.Generator().manual_seed(0), 4, 6, (200,), "cpu")
        >>> sorted(set(x.tolist()))
        [4, 5, 6]
    """
    return torch.randint(int(lo), int(hi_inclusive) + 1, shape, generator=generator, device=generator.device).to(device)
