"""Which chessboard an image shows, whatever size was asked for: a wrong ``--board`` is named early, after a few
views, instead of after every view and every second look was tried with the wrong size.

OpenCV's sector-based detector (``cv2.findChessboardCornersSBWithMeta``) grows a board from the smallest grid it
takes (3x3 inner corners) to the whole board (``CALIB_CB_LARGER``) and says which size it grew to.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["MAX_SIDE", "board_size_in", "other_board_size"]

#: images are searched at most this large (longer side, px): a board is found on a downscaled copy as well, and the
#: search stays short (``docs/measurements.md``)
MAX_SIDE = 1280


def board_size_in(image: np.ndarray) -> tuple[int, int] | None:
    """The inner-corner grid ``(cols, rows)`` of the chessboard in a grey image, or ``None`` without one.

    Args:
        image: :math:`(H, W)` grey image, ``uint8`` or float in ``[0, 1]``.

    Returns:
        ``(cols, rows)`` with ``cols >= rows`` (the order of a board's sides depends on how it lies in the image, which
        a board size given as ``COLSxROWS`` does not).

    Example:
        >>> board = np.kron((np.indices((7, 10)).sum(0) % 2).astype(np.uint8) * 255, np.ones((24, 24), np.uint8))
        >>> board_size_in(np.pad(board, 40, constant_values=255))
        (9, 6)
        >>> board_size_in(np.full((240, 320), 128, np.uint8)) is None
        True
    """
    if image.ndim != 2:
        raise ValueError(f"Expected a grey (H, W) image, got shape {image.shape}.")
    grey = image if image.dtype == np.uint8 else (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    while max(grey.shape) > MAX_SIDE:
        grey = cv2.pyrDown(grey)
    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, _, meta = cv2.findChessboardCornersSBWithMeta(grey, (3, 3), flags)
    if not found or meta is None:
        return None
    rows, cols = meta.shape[:2]
    return (max(rows, cols), min(rows, cols))


def other_board_size(sizes: list[tuple[int, int] | None], board: tuple[int, int],
                     least: int = 2) -> tuple[int, int] | None:
    """The board size that views show instead of ``board``: the most frequent size of ``sizes`` (one per view,
    :func:`board_size_in`), when it is not ``board`` (either way round), at least ``least`` views and half of them
    show it, and none shows ``board``; else ``None``.

    Example:
        >>> other_board_size([(9, 6), (9, 6), None, (9, 6)], (7, 5)), other_board_size([(9, 6), (9, 6)], (6, 9))
        ((9, 6), None)
    """
    wanted = (max(board), min(board))
    seen = [s for s in sizes if s is not None]
    if not seen or wanted in seen:
        return None
    best = max(set(seen), key=seen.count)
    return best if seen.count(best) >= max(least, (len(sizes) + 1) // 2) else None
