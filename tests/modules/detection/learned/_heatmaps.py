"""Synthetic corner heatmaps shared by the sub-pixel tests."""

from __future__ import annotations

import torch


def render(mu: torch.Tensor, sigma: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Unit-peak Gaussians at ``mu`` (B,N,2) with ``sigma`` (B,N,2), max-combined into a (B,1,H,W) heatmap."""
    dtype = mu.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype), indexing="ij")
    dx = xs - mu[..., 0, None, None]
    dy = ys - mu[..., 1, None, None]
    exponent = dx**2 / (2 * sigma[..., 0, None, None] ** 2) + dy**2 / (2 * sigma[..., 1, None, None] ** 2)
    return torch.exp(-exponent).amax(1, keepdim=True)


def board_like(batch: int, cols: int = 8, rows: int = 6, spacing: float = 14.0, seed: int = 0) -> torch.Tensor:
    """(B, cols*rows, 2) float64 corner positions: a grid with random sub-pixel offsets in [0, 3)."""
    gen = torch.Generator().manual_seed(seed)
    gx, gy = torch.meshgrid(torch.arange(cols), torch.arange(rows), indexing="xy")
    grid = torch.stack([gx, gy], -1).reshape(-1, 2).double() * spacing + 10.0
    return grid[None] + 3.0 * torch.rand(batch, cols * rows, 2, generator=gen, dtype=torch.float64)


def nearest_error(found: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Distance from each found point (B,M,2) to its nearest true point (B,N,2), exact (no cdist matmul trick)."""
    return (found[:, :, None].double() - truth[:, None]).norm(dim=-1).min(-1).values
