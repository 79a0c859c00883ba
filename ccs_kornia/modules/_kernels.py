"""Cached 1-D Gaussian kernels.

kornia's ``get_gaussian_kernel1d`` builds its kernel anew on every call. The learned detector's square-size search and
saddle refinement ask for the same few kernels hundreds of times per batch (a visible share of a small image's
detection: ``docs/measurements.md``), so they are built once per ``(size, sigma, dtype)`` here.
"""

from __future__ import annotations

import functools

import torch
from kornia.filters import get_gaussian_kernel1d

__all__ = ["gaussian_kernel1d"]


@functools.lru_cache(maxsize=512)
def _cpu_kernel(size: int, sigma: float, dtype: torch.dtype) -> torch.Tensor:
    return get_gaussian_kernel1d(size, sigma, dtype=dtype)[0]


def gaussian_kernel1d(size: int, sigma: float, device: torch.device | str | None = None,
                      dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """kornia's normalised 1-D Gaussian kernel :math:`(size,)`, the same values, cached (do not modify it in place).

    Example:
        >>> from kornia.filters import get_gaussian_kernel1d
        >>> torch.equal(gaussian_kernel1d(7, 1.5), get_gaussian_kernel1d(7, 1.5)[0])
        True
    """
    return _cpu_kernel(int(size), float(sigma), dtype).to(device)
