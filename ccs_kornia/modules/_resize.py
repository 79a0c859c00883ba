"""Separable linear resizes as banded matrix products (CPU-fast area downscaling).

A separable resize is ``out = My @ image @ Mx^T`` with a short run of taps per output row of each matrix. torch's area
interpolation (``F.interpolate(mode="area")``, i.e. ``adaptive_avg_pool2d``) is slower than that on CPU for factors
below 2.5 that are not integers (``docs/measurements.md``); :func:`area_resize` gives its values
(the same footprints and weights, summed in another order) through :func:`banded_product`, which multiplies each
block of output rows only with the input rows its taps reach.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["BANDED_MAX_PIXELS", "area_matrix", "area_resize", "banded_product", "halve", "separable_product"]

#: :func:`area_resize` uses the banded products on images of at most this many pixels (torch's area interpolation
#: beyond, faster there: ``docs/measurements.md``)
BANDED_MAX_PIXELS = 2_000_000


def banded_product(m: torch.Tensor, x: torch.Tensor, block: int = 32) -> torch.Tensor:
    """``m @ x`` for a matrix ``m`` :math:`(S, N)` whose rows are short runs of taps moving along ``N`` and
    ``x`` :math:`(..., N, K)`: each block of ``block`` output rows multiplies only the input rows its taps reach.

    Example:
        >>> m = area_matrix(6, 3)
        >>> x = torch.arange(12.0).reshape(6, 2)
        >>> torch.allclose(banded_product(m, x), m @ x)
        True
    """
    nz = m != 0
    used = nz.any(1)
    first = torch.where(used, nz.to(torch.int8).argmax(1), m.shape[1])
    last = torch.where(used, m.shape[1] - 1 - nz.flip(1).to(torch.int8).argmax(1), -1)
    out = x.new_zeros(x.shape[:-2] + (m.shape[0], x.shape[-1]))
    for s in range(0, m.shape[0], block):
        lo, hi = int(first[s:s + block].min()), int(last[s:s + block].max()) + 1
        if hi > lo:
            out[..., s:s + block, :] = m[s:s + block, lo:hi] @ x[..., lo:hi, :]
    return out


def separable_product(my: torch.Tensor, mx: torch.Tensor, images: torch.Tensor) -> torch.Tensor:
    """``my @ images @ mx^T`` for images :math:`(..., H, W)` and banded matrices ``my`` :math:`(h, H)`, ``mx``
    :math:`(w, W)` (columns first, then rows), :math:`(..., h, w)`.

    Example:
        >>> x = torch.rand(1, 6, 8)
        >>> my, mx = area_matrix(6, 3), area_matrix(8, 4)
        >>> torch.allclose(separable_product(my, mx, x), my @ x @ mx.T)
        True
    """
    return banded_product(my, banded_product(mx, images.transpose(-1, -2)).transpose(-1, -2))


@functools.lru_cache(maxsize=64)
def _area_matrix_cpu(n_in: int, n_out: int, dtype: torch.dtype) -> torch.Tensor:
    i = torch.arange(n_out)
    start = (i * n_in) // n_out  # adaptive pooling's footprint: floor(i n / m) to ceil((i + 1) n / m)
    end = -((-(i + 1) * n_in) // n_out)
    j = torch.arange(n_in)
    inside = (j[None] >= start[:, None]) & (j[None] < end[:, None])
    return inside.to(torch.float64).div((end - start)[:, None].to(torch.float64)).to(dtype)


def area_matrix(n_in: int, n_out: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """One axis of area interpolation from ``n_in`` to ``n_out`` samples as a :math:`(n_out, n_in)` matrix (cached;
    do not modify it in place).

    Example:
        >>> area_matrix(4, 2)
        tensor([[0.5000, 0.5000, 0.0000, 0.0000],
                [0.0000, 0.0000, 0.5000, 0.5000]])
    """
    return _area_matrix_cpu(int(n_in), int(n_out), dtype).to(device)


def area_resize(images: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """``F.interpolate(images, size, mode="area")`` for downscaling :math:`(B, C, H, W)` to ``size = (h, w)``; on CPU
    as two banded products (the same values up to float rounding, 1e-7), elsewhere torch's own.

    Example:
        >>> x = torch.rand(2, 1, 48, 64)
        >>> bool(torch.allclose(area_resize(x, (17, 23)), F.interpolate(x, size=(17, 23), mode="area"), atol=1e-6))
        True
    """
    check_tensor(images, "images", ["B", "C", "H", "W"])
    h, w = int(size[0]), int(size[1])
    height, width = images.shape[-2:]
    if (h, w) == (height, width):
        return images
    # torch's own is as fast or faster for large factors and for integer factors (docs/measurements.md)
    if (2 * h, 2 * w) == (height, width) and images.is_floating_point():
        return halve(images)
    small = max(height / max(h, 1), width / max(w, 1)) >= 2.5
    integer = height % h == 0 and width % w == 0
    # and on large images (the banded blocks multiply ~32x the taps, the dense matrices grow with both sides and
    # each new size builds its own: docs/measurements.md)
    large = height * width > BANDED_MAX_PIXELS
    if (images.device.type != "cpu" or h > height or w > width or not images.is_floating_point() or small or integer
            or large):
        return F.interpolate(images, size=(h, w), mode="area")
    return separable_product(area_matrix(height, h, images.dtype), area_matrix(width, w, images.dtype), images)


def halve(images: torch.Tensor) -> torch.Tensor:
    """``F.avg_pool2d(images, 2)`` of :math:`(..., H, W)` images (the last odd row or column dropped), the same values
    (the four pixels summed in the kernel's order, times 0.25): on CPU faster than the pooling kernel from about
    160x120 px up (``docs/measurements.md``), slower below, where the kernel is kept.

    Example:
        >>> x = torch.rand(2, 1, 480, 640)
        >>> torch.equal(halve(x), F.avg_pool2d(x, 2))
        True
    """
    if images.shape[-1] * images.shape[-2] < 20_000 or images.device.type != "cpu":
        return F.avg_pool2d(images, 2)
    x = images[..., : images.shape[-2] // 2 * 2, : images.shape[-1] // 2 * 2]
    return (x[..., ::2, ::2] + x[..., ::2, 1::2] + x[..., 1::2, ::2] + x[..., 1::2, 1::2]) * 0.25
