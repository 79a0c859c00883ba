"""Object points of a chessboard-like target: where each inner corner lies on the board, in grid order.

Every board kind (chessboard, ChArUco, AprilGrid, circle grid) numbers its points the same way, so the solvers,
the renderer and the exports share one convention: ``cols x rows`` inner corners, point ``n = j * cols + i`` at
``(i * s, j * s, 0)``.
"""

from __future__ import annotations

import torch

__all__ = ["board_object_points"]


def board_object_points(
    cols: int, rows: int, square: float = 1.0, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Object points of a ``cols x rows`` inner-corner board in grid order.

    Args:
        cols: inner corners per row.
        rows: number of rows of inner corners.
        square: side of a square in world units.

    Returns:
        Tensor of shape :math:`(cols*rows, 3)`, point ``n = j*cols + i`` is ``(i*s, j*s, 0)``.

    Example:
        >>> board_object_points(3, 2, 0.5)[:4]
        tensor([[0.0000, 0.0000, 0.0000],
                [0.5000, 0.0000, 0.0000],
                [1.0000, 0.0000, 0.0000],
                [0.0000, 0.5000, 0.0000]])
    """
    if cols < 2 or rows < 2:
        raise ValueError(f"A board needs at least 2x2 inner corners, got {cols}x{rows}.")
    j, i = torch.meshgrid(
        torch.arange(rows, device=device, dtype=dtype), torch.arange(cols, device=device, dtype=dtype), indexing="ij"
    )
    return torch.stack([i.reshape(-1) * square, j.reshape(-1) * square, torch.zeros_like(i).reshape(-1)], -1)
