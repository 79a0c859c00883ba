"""Argument normalisation and random draws shared by the renderer's modules (private)."""

from __future__ import annotations

import torch
from torch import Tensor

__all__: list[str] = []

def _rand(generator: torch.Generator, shape, device, dtype=torch.float64) -> Tensor:
    return torch.rand(shape, generator=generator, device=generator.device, dtype=dtype).to(device)


def _uniform(generator: torch.Generator, shape, lo: float, hi: float, device, dtype=torch.float64) -> Tensor:
    return lo + (hi - lo) * _rand(generator, shape, device, dtype)


def _randint(generator: torch.Generator, lo: int, hi_inclusive: int, shape, device) -> Tensor:
    return torch.randint(int(lo), int(hi_inclusive) + 1, shape, generator=generator, device=generator.device).to(device)


def _check_size(image_size) -> tuple[int, int]:
    if len(image_size) != 2 or int(image_size[0]) < 2 or int(image_size[1]) < 2:
        raise ValueError(f"image_size must be (W, H) with both >= 2, got {image_size}.")
    return int(image_size[0]), int(image_size[1])


def _batched(x, b: int, tail: tuple[int, ...], name: str, device, dtype) -> Tensor | None:
    """``None`` stays ``None``; a tensor of shape ``tail`` or ``(B, *tail)`` becomes ``(B, *tail)``."""
    if x is None:
        return None
    x = torch.as_tensor(x, device=device, dtype=dtype)
    if tuple(x.shape) == tail:
        x = x.expand(b, *tail)
    if tuple(x.shape) != (b, *tail):
        raise ValueError(f"{name} must have shape {tail} or {(b, *tail)}, got {tuple(x.shape)}.")
    return x


def _per_item(x, b: int, name: str, device, dtype) -> Tensor:
    x = torch.as_tensor(x, device=device, dtype=dtype)
    if x.dim() == 0:
        x = x.expand(b)
    if tuple(x.shape) != (b,):
        raise ValueError(f"{name} must be a number or a ({b},) tensor, got {tuple(x.shape)}.")
    return x


def _board_tensors(board_size, b: int, device) -> tuple[Tensor, Tensor]:
    bs = torch.as_tensor(board_size, device=device, dtype=torch.long)
    if bs.shape == (2,):
        bs = bs.expand(b, 2)
    if tuple(bs.shape) != (b, 2):
        raise ValueError(f"board_size must be (cols, rows) or a ({b}, 2) tensor, got {tuple(bs.shape)}.")
    if bool((bs < 2).any()):
        raise ValueError(f"A board needs at least 2x2 inner corners, got {bs.tolist()}.")
    return bs[:, 0].contiguous(), bs[:, 1].contiguous()


def _padded_object_points(cols: Tensor, rows: Tensor, square: Tensor, n_max: int) -> tuple[Tensor, Tensor]:
    """Object points ``(B, n_max, 3)`` in grid order (zero-padded) and the mask of existing corners."""
    n = torch.arange(n_max, device=cols.device).unsqueeze(0)
    c = cols.unsqueeze(1)
    exists = n < c * rows.unsqueeze(1)
    s = square.unsqueeze(1)
    i = torch.remainder(n, c).to(square.dtype) * s
    j = torch.div(n, c, rounding_mode="floor").to(square.dtype) * s
    obj = torch.stack([i, j, torch.zeros_like(i)], -1) * exists.unsqueeze(-1)
    return obj, exists
