"""``--pair I,J``: the two cameras of a rig that make a stereo pair (``calibrate-rig``'s stereo files, ``rectify``)."""

from __future__ import annotations

from ccs_kornia.runtime.errors import UserError

__all__ = ["parse_pair"]


def parse_pair(text: str, cameras: int) -> tuple[int, int]:
    """``--pair I,J``: two different cameras of a rig of ``cameras``.

    Example:
        >>> parse_pair("2,0", 4)
        (2, 0)
    """
    parts = text.split(",")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise UserError(f"--pair {text}: expected two camera indices, e.g. 0,1")
    i, j = int(parts[0]), int(parts[1])
    if i == j or max(i, j) >= cameras:
        raise UserError(f"--pair {text}: two different cameras of the {cameras} in the calibration (0..{cameras - 1})")
    return i, j
