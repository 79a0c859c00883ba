"""What the commands say about a run's result, in words: why a board was found in no image, a board that looks
larger than the one given, what ``--allow-weak`` let through."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["board_size_hint", "not_found_message", "weak_lines"]


def board_size_hint(board: tuple[int, int], reasons: Sequence[str]) -> str:
    """``the board looks larger than 8x6 in N images: check --board ...`` when boards were refused because their
    checker pattern continues past a side (a sub-board of the board in the images); ``""`` otherwise.

    Example:
        >>> board_size_hint((8, 6), ["board refused: the checker pattern continues past its left side", ""])[:49]
        'the board looks larger than 8x6 in 1 image: check'
    """
    n = sum(1 for r in reasons if "continues past" in r)
    if not n:
        return ""
    return (f"the board looks larger than {board[0]}x{board[1]} in {n} image{'s' if n > 1 else ''}: check --board "
            f"(COLSxROWS counts inner corners, where four squares meet)")


#: what to check when a board of each detector is found in no image
_NOT_FOUND_CHECK = {
    "charuco": "check --charuco SXxSY (the squares, as OpenCV's CharucoBoard counts them), --dictionary and --legacy",
    "aprilgrid": "check the target YAML's tagCols and tagRows; the tags must be 36h11 with a two-bit black border, "
                 "as Kalibr prints them",
}


def not_found_message(board: tuple[int, int], readable: int, total: int, detector: str = "") -> str:
    """Why a board was found in no image, with what to check for the board's kind (``detector``).

    Example:
        >>> not_found_message((4, 6), 3, 3, "charuco")[:65]
        'board 4x6 not found in any of 3 images (check --charuco SXxSY (th'
    """
    if readable == 0:
        return f"none of the {total} input files could be read as an image"
    check = _NOT_FOUND_CHECK.get(detector, "check --board: COLSxROWS counts inner corners, where four squares meet")
    return f"board {board[0]}x{board[1]} not found in any of {readable} images ({check})"


def weak_lines(data: dict[str, Any]) -> list[str]:
    """What ``--allow-weak`` let through in a camera's record: the checks that would have refused it, and the
    1-sigma of its intrinsics that shows why (empty when nothing was let through)."""
    errors = data.get("errors") or []
    if not data.get("success") or not errors:
        return []
    std = data.get("std") or {}
    K = data["K"]
    sigma = ", ".join(f"{k} {v:.1f} ± {std[k]:.1f}" for k, v in (("fx", K[0][0]), ("fy", K[1][1]), ("cx", K[0][2]),
                                                                   ("cy", K[1][2])) if std.get(k) is not None)
    return [f"calibrated with --allow-weak although {e['message']}" for e in errors] + \
        [f"1-sigma of the intrinsics (px): {sigma}"]
