"""Shape and argument checks shared by every layer (kornia's ``KORNIA_CHECK_SHAPE`` with our error type).

Every stage and value checks its inputs at the boundary and raises ``ValueError`` with a message that names the
argument, the expected shape and the shape it got. The shape patterns are kornia's: ``["B", "N", "2"]``
means three dimensions, the last of size 2; a leading ``"*"`` allows any leading dimensions.

Example:
    >>> import torch
    >>> check_shape(torch.zeros(2, 5, 2), ["B", "N", "2"], "points must be (B, N, 2)")
    >>> check_shape(torch.zeros(2, 5), ["B", "N", "2"], "points must be (B, N, 2)")
    Traceback (most recent call last):
    ...
    ValueError: points must be (B, N, 2), got (2, 5).
    >>> check_board_size((9, 6))
    (9, 6)
"""

from __future__ import annotations

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE

__all__ = [
    "broadcast_shapes", "check_shape", "check_board_size", "check_points", "check_correction", "check_grey_images",
]


def check_shape(x: object, shape: list[str], expected: str) -> None:
    """Raise ``ValueError(f"{expected}, got {shape}.")`` unless ``x`` is a tensor matching ``shape``.

    Args:
        x: the argument to check.
        shape: kornia shape pattern, e.g. ``["B", "1", "H", "W"]``.
        expected: the start of the message, e.g. ``"image must be (B, 1, H, W)"``.
    """
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{expected}, got {type(x).__name__}.")
    if not KORNIA_CHECK_SHAPE(x, shape, raises=False):
        raise ValueError(f"{expected}, got {tuple(x.shape)}.")


def broadcast_shapes(*shapes: tuple[int, ...]) -> torch.Size:
    """``torch.broadcast_shapes`` without its first-call cost: torch's imports ``torch.fx``'s symbolic shapes and sympy,
    a noticeable share of a small calibration from the command line (``docs/measurements.md``).

    Example:
        >>> broadcast_shapes((3, 1, 4), (5, 4))
        torch.Size([3, 5, 4])
    """
    out = [1] * max((len(s) for s in shapes), default=0)
    for s in shapes:
        for i, d in enumerate(s, len(out) - len(s)):
            if d != 1 and out[i] not in (1, d):
                raise ValueError(f"Shapes {[tuple(s) for s in shapes]} cannot be broadcast together.")
            out[i] = d if d != 1 else out[i]
    return torch.Size(out)


def check_board_size(board_size: tuple[int, int], min_side: int = 2) -> tuple[int, int]:
    """``(cols, rows)`` as ints, at least ``min_side`` inner corners a side (a board: 2x2); raises ``ValueError``
    otherwise.

    The one check of a board size, where it enters a stage; code behind that edge unpacks the checked pair.
    """
    if len(board_size) != 2:
        raise ValueError(f"board_size must be (cols, rows), got {board_size}.")
    cols, rows = int(board_size[0]), int(board_size[1])
    if cols < min_side or rows < min_side:
        raise ValueError(f"board_size must be (cols, rows) with at least {min_side}x{min_side} inner corners, got "
                         f"{board_size}.")
    return cols, rows


def check_points(points: torch.Tensor) -> None:
    """Pixel points :math:`(B, N, 2)`."""
    check_shape(points, ["B", "N", "2"], "points must be (B, N, 2)")


def check_correction(correction: torch.Tensor, batch: int | None = None) -> None:
    """Radial correction coefficients :math:`(B, 5)` (``B`` 1 or ``batch`` when given)."""
    check_shape(correction, ["B", "5"], "correction must be (B, 5) coefficients (k0'..k4')")
    if batch is not None and correction.shape[0] not in (1, batch):
        raise ValueError(f"correction batch {correction.shape[0]} does not match {batch}.")


def check_grey_images(images: torch.Tensor) -> None:
    """Grey images :math:`(B, 1, H, W)` of at least 8x8 px (a detection level and its refinement window need them)."""
    if not isinstance(images, torch.Tensor) or images.dim() != 4 or images.shape[1] != 1:
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"Expected grey images (B, 1, H, W), got {shape}.")
    if min(images.shape[-2:]) < 8:
        raise ValueError(f"Images must be at least 8x8 px, got {tuple(images.shape[-2:])}.")
