"""The renderer's arguments as batches of ``B`` views, checked where they enter.

A camera, a lens or a number is given once for every view or once per view; :func:`batched_argument` and
:func:`per_view_argument` give it the view axis. Boards of different sizes share one batch as zero-padded point
sets (:func:`board_size_tensors`, :func:`padded_object_points`).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["batched_argument", "board_size_tensors", "check_image_size", "padded_object_points", "per_view_argument"]


def check_image_size(image_size) -> tuple[int, int]:
    """An image size ``(W, H)`` as two ints, each at least 2, checked where a size enters the renderer or a sampler.

    Raises:
        ValueError: it is not two sizes of at least 2.

    Example:
        >>> check_image_size((640.0, 480))
        (640, 480)
    """
    if len(image_size) != 2 or int(image_size[0]) < 2 or int(image_size[1]) < 2:
        raise ValueError(f"image_size must be (W, H) with both >= 2, got {image_size}.")
    return int(image_size[0]), int(image_size[1])


def batched_argument(x, b: int, tail: tuple[int, ...], name: str, device, dtype) -> Tensor | None:
    """An argument given once or per view as a ``(B, *tail)`` tensor; ``None`` stays ``None`` (no such lens part).

    Args:
        x: ``None``, or a tensor (or nested sequence) of shape ``tail`` (shared by every view) or ``(B, *tail)``.
        b: the number of views ``B``.
        tail: the shape of one view's value, e.g. ``(3, 3)`` for a camera matrix, ``(5,)`` for OpenCV coefficients.
        name: the argument's name, for the error.
        device, dtype: where and how the result is held.

    Returns:
        :math:`(B, *tail)` (a shared value is expanded, not copied), or ``None``.

    Raises:
        ValueError: ``x`` has neither shape.

    Example:
        >>> batched_argument(torch.eye(3), 4, (3, 3), "K", "cpu", torch.float64).shape
        torch.Size([4, 3, 3])
        >>> batched_argument(None, 4, (5,), "dist", "cpu", torch.float64) is None
        True
    """
    if x is None:
        return None
    x = torch.as_tensor(x, device=device, dtype=dtype)
    if tuple(x.shape) == tail:
        x = x.expand(b, *tail)
    if tuple(x.shape) != (b, *tail):
        raise ValueError(f"{name} must have shape {tail} or {(b, *tail)}, got {tuple(x.shape)}.")
    return x


def per_view_argument(x, b: int, name: str, device, dtype) -> Tensor:
    """A number shared by every view, or one per view, as a ``(B,)`` tensor (a square side, a grey level).

    Args:
        x: a number, a 0-d tensor or a :math:`(B,)` tensor.
        b: the number of views ``B``.
        name: the argument's name, for the error.
        device, dtype: where and how the result is held.

    Returns:
        :math:`(B,)`.

    Raises:
        ValueError: ``x`` is neither a number nor ``(B,)``.

    Example:
        >>> per_view_argument(0.025, 3, "square", "cpu", torch.float64)
        tensor([0.0250, 0.0250, 0.0250], dtype=torch.float64)
    """
    x = torch.as_tensor(x, device=device, dtype=dtype)
    if x.dim() == 0:
        x = x.expand(b)
    if tuple(x.shape) != (b,):
        raise ValueError(f"{name} must be a number or a ({b},) tensor, got {tuple(x.shape)}.")
    return x


def board_size_tensors(board_size, b: int, device) -> tuple[Tensor, Tensor]:
    """The boards' inner corners per view: ``cols`` and ``rows`` as two ``(B,)`` long tensors.

    Args:
        board_size: ``(cols, rows)`` shared by every view, or a :math:`(B, 2)` tensor (one board per view).
        b: the number of views ``B``.
        device: where the result is held.

    Returns:
        ``cols`` :math:`(B,)` and ``rows`` :math:`(B,)`, long.

    Raises:
        ValueError: the shape is neither, or a board has fewer than 2x2 inner corners.

    Example:
        >>> board_size_tensors((9, 6), 2, "cpu")
        (tensor([9, 9]), tensor([6, 6]))
    """
    bs = torch.as_tensor(board_size, device=device, dtype=torch.long)
    if bs.shape == (2,):
        bs = bs.expand(b, 2)
    if tuple(bs.shape) != (b, 2):
        raise ValueError(f"board_size must be (cols, rows) or a ({b}, 2) tensor, got {tuple(bs.shape)}.")
    if bool((bs < 2).any()):
        raise ValueError(f"A board needs at least 2x2 inner corners, got {bs.tolist()}.")
    return bs[:, 0].contiguous(), bs[:, 1].contiguous()


def padded_object_points(cols: Tensor, rows: Tensor, square: Tensor, n_max: int) -> tuple[Tensor, Tensor]:
    """The inner corners of boards of different sizes in one batch: object points in grid order (corner ``n`` at
    ``(n mod cols, n div cols) * square``, ``z = 0``), zero-padded to ``n_max``, and which of them exist.

    Args:
        cols, rows: :math:`(B,)` long, inner corners per row and per column.
        square: :math:`(B,)` square sides; its dtype is the points'.
        n_max: the padded length, at least the largest ``cols * rows``.

    Returns:
        object points :math:`(B, n_{max}, 3)` (zeros past a board's last corner) and ``exists``
        :math:`(B, n_{max})` bool.

    Example:
        >>> obj, exists = padded_object_points(torch.tensor([2, 3]), torch.tensor([2, 2]), torch.tensor([1.0, 0.5]), 6)
        >>> obj[0, :5, :2].tolist()
        [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [0.0, 0.0]]
        >>> exists.sum(-1).tolist()
        [4, 6]
    """
    n = torch.arange(n_max, device=cols.device).unsqueeze(0)
    c = cols.unsqueeze(1)
    exists = n < c * rows.unsqueeze(1)
    s = square.unsqueeze(1)
    i = torch.remainder(n, c).to(square.dtype) * s
    j = torch.div(n, c, rounding_mode="floor").to(square.dtype) * s
    obj = torch.stack([i, j, torch.zeros_like(i)], -1) * exists.unsqueeze(-1)
    return obj, exists
