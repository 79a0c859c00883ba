r"""Corner candidates from OpenCV's classic detector: the learned detector's last source.

Where the heatmap network's peaks give no board at any level, OpenCV's quad-based ``cv2.findChessboardCorners``
often still does: it segments the dark squares and links their corners, so marks inside
the white squares (ChArUco, ECoCheck) do not disturb it, and it needs no square-size estimate (a scene with strong
saddles at ten times the board's scale misleads ours). Its corners are only candidates here: the learned detector puts
them in its own grid order, refines them on the image with its own refiner and applies its own lattice and sub-board
checks, so the precision is the learned path's and the board convention stays one (OpenCV's classic order, the
organiser's).

The classic detector's cost grows with clutter and pixels (seconds on a large photo without a board:
``docs/measurements.md``), so it runs on a level of at most :data:`OPENCV_MAX_PIXELS`.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.opencv_detector import CLASSIC_FLAGS
from ccs_kornia.runtime.checks import check_board_size, check_grey_images

__all__ = ["OPENCV_MAX_PIXELS", "opencv_level_factor", "opencv_candidates"]

#: most pixels of the level OpenCV's classic detector searches (a 1280x960 photo at full resolution)
OPENCV_MAX_PIXELS = 1.3e6


def opencv_level_factor(image_size: tuple[int, int], max_pixels: float = OPENCV_MAX_PIXELS) -> float:
    """Full-resolution px per level px of the level OpenCV searches in an image of size ``(W, H)`` (never below 1).

    Example:
        >>> opencv_level_factor((640, 480)), round(opencv_level_factor((6000, 4000)), 2)
        (1.0, 4.3)
    """
    w, h = int(image_size[0]), int(image_size[1])
    return max(1.0, math.sqrt(w * h / max_pixels))


def opencv_candidates(
    images: torch.Tensor, board_size: tuple[int, int], num_workers: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The corners ``cv2.findChessboardCorners`` (adaptive threshold, normalised image) finds on each image.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        board_size: ``(cols, rows)`` inner corners.
        num_workers: threads over the images (OpenCV releases the GIL); ``None``: ``min(8, cpu count)``.

    Returns:
        points :math:`(B, N, 2)` ``(x, y)`` px, ``N = cols * rows``, in OpenCV's order (unrefined: the corners of its
        quads, often a px off), and mask :math:`(B, N)` (all true on an image where a board was found, else false).

    Example:
        >>> img = torch.ones(1, 1, 120, 160)
        >>> for j in range(5):
        ...     for i in range(7):
        ...         if (i + j) % 2 == 0:
        ...             img[..., 20 + 16 * j:36 + 16 * j, 24 + 16 * i:40 + 16 * i] = 0
        >>> pts, ok = opencv_candidates(img, (6, 4))
        >>> pts.shape, bool(ok.all())
        (torch.Size([1, 24, 2]), True)
    """
    check_grey_images(images, min_side=0)
    cols, rows = check_board_size(board_size)
    n = cols * rows
    arrays = (images.detach()[:, 0].float().clamp(0, 1) * 255.0).round().to(torch.uint8).cpu().numpy()

    def one(gray: np.ndarray) -> np.ndarray | None:
        try:
            ok, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=CLASSIC_FLAGS)
        except cv2.error:  # an odd image is a miss, never an exception
            return None
        return corners.reshape(n, 2) if ok and corners is not None else None

    workers = min(8, os.cpu_count() or 1) if num_workers is None else num_workers
    if workers > 1 and len(arrays) > 1:
        with ThreadPoolExecutor(max_workers=min(workers, len(arrays))) as pool:
            found = list(pool.map(one, arrays))
    else:
        found = [one(a) for a in arrays]
    points = torch.zeros(len(arrays), n, 2, dtype=torch.float32)
    mask = torch.zeros(len(arrays), n, dtype=torch.bool)
    for b, pts in enumerate(found):
        if pts is not None:
            points[b], mask[b] = torch.from_numpy(pts.astype(np.float32)), True
    return points.to(images.device), mask.to(images.device)
