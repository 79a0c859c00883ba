"""Which chessboard an image shows, whatever size was asked for: a wrong ``--board`` is named early, after a few
views, instead of after every view and every second look was tried with the wrong size.

OpenCV's sector-based detector (``cv2.findChessboardCornersSBWithMeta``) grows a board from the smallest grid it
takes (3x3 inner corners) to the whole board (``CALIB_CB_LARGER``) and says which size it grew to.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["CUT_SQUARES", "MAX_SIDE", "board_grid_in", "board_size_in", "other_board_size"]

#: images are searched at most this large (longer side, px): a board is found on a downscaled copy as well, and the
#: search stays short (``docs/measurements.md``)
MAX_SIDE = 1280
#: a grid with a corner nearer the image's border than this many squares may go on past the frame: the next corner
#: out would lie within half a square of the border (or past it), too near for the detector to find it
CUT_SQUARES = 1.5


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
    grid = board_grid_in(image)
    return None if grid is None else grid[0]


def board_grid_in(image: np.ndarray) -> tuple[tuple[int, int], bool] | None:
    """:func:`board_size_in`'s grid ``(cols, rows)`` and whether the frame may cut it: some corner lies within
    :data:`CUT_SQUARES` squares of the image's border, so the board may go on past it (the grid is then the visible
    part of a board at least that large, not evidence of its size); ``None`` without a board.

    Example:
        >>> board = np.kron((np.indices((7, 10)).sum(0) % 2).astype(np.uint8) * 255, np.ones((24, 24), np.uint8))
        >>> image = np.pad(board, 40, constant_values=255)
        >>> board_grid_in(image), board_grid_in(image[:, :250])  # the last column of squares cut by the frame
        (((9, 6), False), ((8, 6), True))
    """
    if image.ndim != 2:
        raise ValueError(f"Expected a grey (H, W) image, got shape {image.shape}.")
    grey = image if image.dtype == np.uint8 else (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    while max(grey.shape) > MAX_SIDE:
        grey = cv2.pyrDown(grey)
    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(grey, (3, 3), flags)
    if not found or meta is None:
        return None
    rows, cols = meta.shape[:2]
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    np.fill_diagonal(gaps, np.inf)
    square = float(np.median(gaps.min(1)))  # a square's side in the image, about each corner
    h, w = grey.shape
    border = np.minimum(np.minimum(pts[:, 0], w - 1 - pts[:, 0]), np.minimum(pts[:, 1], h - 1 - pts[:, 1]))
    return (max(rows, cols), min(rows, cols)), bool(border.min() < CUT_SQUARES * square)


def other_board_size(sizes: list[tuple[int, int] | None], board: tuple[int, int],
                     least: int = 2, cut: list[bool] | None = None) -> tuple[int, int] | None:
    """The board size that views show instead of ``board``: the most frequent size of ``sizes`` (one per view,
    :func:`board_size_in`), when it is not ``board`` (either way round), at least ``least`` views and half of them
    show it, and none shows ``board``; else ``None``.

    ``cut``: per view, whether the frame may cut its grid (:func:`board_grid_in`): a cut grid that fits within
    ``board`` may be a partial view of it, so it is no evidence of another size (it counts as no board seen).

    Example:
        >>> other_board_size([(9, 6), (9, 6), None, (9, 6)], (7, 5)), other_board_size([(9, 6), (9, 6)], (6, 9))
        ((9, 6), None)
        >>> other_board_size([(8, 6)] * 4, (9, 6)), other_board_size([(8, 6)] * 4, (9, 6), cut=[True] * 4)
        ((8, 6), None)
    """
    wanted = (max(board), min(board))
    if cut is not None:  # a partial view of the board given is not a whole view of another one
        sizes = [None if s is not None and c and s[0] <= wanted[0] and s[1] <= wanted[1] else s
                 for s, c in zip(sizes, cut)]
    seen = [s for s in sizes if s is not None]
    if not seen or wanted in seen:
        return None
    best = max(set(seen), key=seen.count)
    return best if seen.count(best) >= max(least, (len(sizes) + 1) // 2) else None
