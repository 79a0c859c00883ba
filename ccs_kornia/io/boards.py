"""Board sizes as users write them (``9x6``): parsed and checked once, at the edge of the library."""

from __future__ import annotations

__all__ = ["parse_board"]


def parse_board(text: str) -> tuple[int, int]:
    """Parse a ``COLSxROWS`` inner-corner board size such as ``"9x6"``.

    Args:
        text: ``COLSxROWS`` with positive integers (``x`` or ``X``; spaces allowed around it).

    Returns:
        ``(cols, rows)`` as OpenCV's ``patternSize``.

    Raises:
        ValueError: with a message saying what is expected.

    Example:
        >>> parse_board("9x6")
        (9, 6)
    """
    raw = str(text).strip()
    parts = raw.lower().split("x")
    hint = "expected COLSxROWS inner corners, e.g. 9x6 (a board of 10x7 squares)"
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"invalid board size {text!r}: {hint}")
    cols, rows = (int(p) for p in parts)
    if cols < 2 or rows < 2:
        raise ValueError(
            f"invalid board size {text!r}: a board needs at least 2 inner corners per side "
            f"(count the inner corners where four squares meet, not the squares); {hint}"
        )
    if cols * rows < 6:
        raise ValueError(f"invalid board size {text!r}: {cols * rows} corners is too few to calibrate; {hint}")
    if cols > 200 or rows > 200:
        raise ValueError(f"invalid board size {text!r}: more than 200 corners per side; {hint}")
    return cols, rows
