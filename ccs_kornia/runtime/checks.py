"""Shape and argument checks shared by every layer (kornia's ``KORNIA_CHECK_SHAPE`` with our error type).

Every stage and value checks its inputs at the boundary and raises ``ValueError`` with a one-line message that names
the argument, the expected shape and the shape it got. The shape patterns are kornia's: ``["B", "N", "2"]`` means
three dimensions, the last of size 2; a leading ``"*"`` allows any leading dimensions. Here a pattern may also hold
ints (``[C, V, 3]``, exact sizes), and a letter may be bound to a size by keyword (``B=images.shape[0]``): the way to
say that several tensors share a dimension.

Example:
    >>> import torch
    >>> check_shape(torch.zeros(2, 5, 2), ["B", "N", "2"], "points must be (B, N, 2)")
    >>> check_shape(torch.zeros(2, 5), ["B", "N", "2"], "points must be (B, N, 2)")
    Traceback (most recent call last):
    ...
    ValueError: points must be (B, N, 2), got (2, 5).
    >>> check_tensor(torch.zeros(3, 5, 2), "corners", ["B", "N", "2"], B=2)
    Traceback (most recent call last):
    ...
    ValueError: corners must be (B, N, 2) with B=2, got (3, 5, 2).
    >>> check_board_size((9, 6))
    (9, 6)
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE

__all__ = [
    "broadcast_shapes", "check_board_size", "check_correction", "check_grey_images", "check_points", "check_same_shape",
    "check_shape", "check_tensor",
]

Shape = Sequence["str | int"]


def _received(x: object) -> str:
    return str(tuple(x.shape)) if isinstance(x, torch.Tensor) else type(x).__name__


def _matches(x: torch.Tensor, shape: Shape, sizes: dict[str, int]) -> bool:
    return KORNIA_CHECK_SHAPE(x, [str(sizes.get(d, d)) if isinstance(d, str) else str(d) for d in shape], raises=False)


def _text(shape: Shape) -> str:
    dims = [str(d) for d in shape]
    return f"({dims[0]},)" if len(dims) == 1 else f"({', '.join(dims)})"


def check_shape(x: object, shape: Shape, expected: str) -> None:
    """Raise ``ValueError(f"{expected}, got {shape}.")`` unless ``x`` is a tensor matching ``shape``.

    Args:
        x: the argument to check.
        shape: kornia shape pattern, e.g. ``["B", "1", "H", "W"]``; ints stand for exact sizes.
        expected: the start of the message, e.g. ``"image must be (B, 1, H, W)"``.
    """
    if not isinstance(x, torch.Tensor) or not _matches(x, shape, {}):
        raise ValueError(f"{expected}, got {_received(x)}.")


def check_tensor(x: object, name: str, *shapes: Shape, what: str = "", **sizes: int) -> None:
    """Raise ``ValueError`` unless ``x`` is a tensor of one of ``shapes``; the message names ``name``, the shapes and
    the shape received: ``"{name} must be {shape} [or {shape}] [{what}] [with B=..], got {x.shape}."``.

    Args:
        x: the argument to check.
        name: the argument's name, the message's subject.
        shapes: kornia shape patterns, at least one; ints and digit strings are exact sizes, other letters any size
            (unless bound in ``sizes``), a leading ``"*"`` any leading dimensions. A ``torch.Size`` is a pattern too.
        what: what the tensor holds, said after the shape (``"coefficients (k0, k1, k2)"``).
        sizes: letters bound to sizes, e.g. ``B=images.shape[0]`` for a batch shared with another argument.

    Example:
        >>> check_tensor(torch.zeros(4, 3, 3), "K", ["*", "3", "3"])
        >>> check_tensor(torch.zeros(6, 10, 2), "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
        >>> check_tensor(torch.zeros(2, 3), "K", ["*", "3", "3"], what="camera matrices")
        Traceback (most recent call last):
        ...
        ValueError: K must be (*, 3, 3) camera matrices, got (2, 3).
        >>> check_tensor(torch.ones(2, 7, dtype=torch.bool), "valid", torch.Size([2, 6]))
        Traceback (most recent call last):
        ...
        ValueError: valid must be (2, 6), got (2, 7).
    """
    if isinstance(x, torch.Tensor):
        for shape in shapes:
            if _matches(x, shape, sizes):
                return
    expected = " or ".join(dict.fromkeys(_text(s) for s in shapes)) + (f" {what}" if what else "")
    if sizes:
        expected += " with " + ", ".join(f"{k}={v}" for k, v in sizes.items())
    raise ValueError(f"{name} must be {expected}, got {_received(x)}.")


def check_same_shape(x: object, name: str, like: torch.Tensor, like_name: str) -> None:
    """Raise ``ValueError`` unless ``x`` is a tensor of ``like``'s shape (kornia's ``KORNIA_CHECK_SAME_SHAPE``, named).

    Example:
        >>> check_same_shape(torch.zeros(2, 5), "sigma", torch.zeros(2, 5), "valid")
        >>> check_same_shape(torch.zeros(2, 4), "sigma", torch.zeros(2, 5), "valid")
        Traceback (most recent call last):
        ...
        ValueError: sigma must be (2, 5) (as valid), got (2, 4).
    """
    if not isinstance(x, torch.Tensor) or x.shape != like.shape:
        raise ValueError(f"{name} must be {_text(like.shape)} (as {like_name}), got {_received(x)}.")


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


def check_points(points: object, name: str = "points", **sizes: int) -> None:
    """Pixel points :math:`(B, N, 2)` (``B`` or ``N`` fixed where given, e.g. ``B=images.shape[0]``).

    Example:
        >>> check_points(torch.zeros(2, 5, 2), "corners", B=2)
        >>> check_points(torch.zeros(2, 5, 3), "corners")
        Traceback (most recent call last):
        ...
        ValueError: corners must be (B, N, 2), got (2, 5, 3).
    """
    check_tensor(points, name, ["B", "N", "2"], **sizes)


def check_correction(correction: object, batch: int | None = None) -> None:
    """Radial correction coefficients :math:`(B, 5)` (``B`` 1 or ``batch`` when given).

    Example:
        >>> check_correction(torch.zeros(1, 5), batch=3)
        >>> check_correction(torch.zeros(2, 5), batch=3)
        Traceback (most recent call last):
        ...
        ValueError: correction must be (1, 5) or (B, 5) coefficients (k0'..k4') with B=3, got (2, 5).
    """
    if batch is None:
        check_tensor(correction, "correction", ["B", "5"], what="coefficients (k0'..k4')")
    else:
        check_tensor(correction, "correction", ["1", "5"], ["B", "5"], what="coefficients (k0'..k4')", B=batch)


def check_grey_images(images: object, name: str = "images", min_side: int = 8) -> None:
    """Grey images :math:`(B, 1, H, W)` of at least ``min_side`` px a side (8: a detection level and its refinement
    window need them; 0: any size).

    Example:
        >>> check_grey_images(torch.zeros(2, 1, 16, 16))
        >>> check_grey_images(torch.zeros(2, 3, 16, 16), "image")
        Traceback (most recent call last):
        ...
        ValueError: image must be (B, 1, H, W) grey images, got (2, 3, 16, 16).
    """
    check_tensor(images, name, ["B", "1", "H", "W"], what="grey images")
    if min(images.shape[-2:]) < min_side:
        raise ValueError(f"Images must be at least {min_side}x{min_side} px, got {tuple(images.shape[-2:])}.")
