"""The OpenCV baseline detector (:class:`OpenCVChessboardDetector`), the classical baseline and fallback:

1. ``cv2.findChessboardCorners`` (adaptive threshold + normalisation) followed by
   ``cv2.cornerSubPix`` with a window adapted to the board (half-size about 0.45 times the smallest
   distance between neighbouring corners, clamped to ``[2, 11]``), which on rendered boards
   with exact ground truth calibrates better than the sector-based detector (``docs/measurements.md``);
2. if that fails (or its grid is rejected), ``cv2.findChessboardCornersSB`` with
   ``NORMALIZE_IMAGE | EXHAUSTIVE | ACCURACY``;
3. every grid is checked before it is accepted: a lattice that folds, turns sharply or jumps in
   spacing is a false positive, and a lattice whose pattern continues past one of its sides is a
   sub-board of a larger board (the classic detector happily returns 8x6 on a 9x6 board, and a
   view shifted by one square ruins a calibration);
4. the corner order is made deterministic (:func:`~ccs_kornia.modules.detection.checks.board_checks.canonical_corner_order`):
   of the orderings that describe the same physical grid (reversed for 180-degree-symmetric boards, also the
   90-degree rotations for square ones) the one whose first corner is nearest the image's top-left corner is
   returned, so every view of a set uses the same convention.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.checks.board_checks import (
    board_extends,
    canonical_corner_order,
    check_grid,
    check_saddles,
)

__all__ = ["CLASSIC_FLAGS", "OpenCVChessboardDetector"]

#: the flags of OpenCV's classic ``findChessboardCorners``, wherever this package runs it (the baseline detector and
#: the learned detector's candidates)
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)

def _subpix_half_window(corners: np.ndarray, board_size: tuple[int, int], fraction: float, limits: tuple[int, int]) -> int:
    cols, rows = board_size
    grid = corners.reshape(rows, cols, 2)
    d_row = np.linalg.norm(grid[:, 1:] - grid[:, :-1], axis=-1)
    d_col = np.linalg.norm(grid[1:] - grid[:-1], axis=-1)
    spacing = float(min(d_row.min(), d_col.min()))
    return int(np.clip(round(fraction * spacing), limits[0], limits[1]))


class OpenCVChessboardDetector(ChessboardDetector):
    """OpenCV baseline: classic detector + adapted ``cornerSubPix``, falling back to the SB detector.

    Args:
        use_sb_fallback: try ``findChessboardCornersSB`` when the classic detector fails.
        window_fraction: ``cornerSubPix`` half-window as a fraction of the smallest corner spacing.
        window_limits: clamp of the half-window in pixels.
        reject_subboards: reject grids whose checker pattern continues past a side.
        verify_grid: run the lattice and X-junction checks (:func:`check_grid`, :func:`check_saddles`);
            off, every grid OpenCV returns is accepted (as plain OpenCV does).
        num_workers: threads over the images of a batch (OpenCV releases the GIL); ``None`` picks
            ``min(8, cpu count)``, 0 or 1 runs in the calling thread.

    Example:
        >>> det = OpenCVChessboardDetector()
        >>> out = det(torch.zeros(2, 1, 64, 64), (4, 3))
        >>> out.corners.shape, out.found.tolist()
        (torch.Size([2, 12, 2]), [False, False])
    """

    def __init__(
        self,
        use_sb_fallback: bool = True,
        window_fraction: float = 0.45,
        window_limits: tuple[int, int] = (2, 11),
        reject_subboards: bool = True,
        verify_grid: bool = True,
        num_workers: int | None = None,
    ) -> None:
        super().__init__()
        self.use_sb_fallback = use_sb_fallback
        self.window_fraction = window_fraction
        self.window_limits = window_limits
        self.reject_subboards = reject_subboards
        self.verify_grid = verify_grid
        self.num_workers = min(8, os.cpu_count() or 1) if num_workers is None else num_workers

    def detect_one(self, image: np.ndarray, board_size: tuple[int, int]) -> tuple[np.ndarray | None, str]:
        """Detect one board on a grey ``float32`` image in ``[0, 1]``; ``(corners (N,2) | None, reason)``."""
        gray8 = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        h, w = gray8.shape
        problems: list[str] = []

        def accept(corners: np.ndarray, method: str) -> np.ndarray | None:
            pts = corners.reshape(-1, 2).astype(np.float64)
            reason = ""
            if self.verify_grid:
                reason = check_grid(pts, board_size, (w, h)) or check_saddles(image, pts, board_size)
            if not reason and self.reject_subboards:
                side = board_extends(image, pts, board_size)
                if side:
                    reason = f"the checker pattern continues past the {side} side (board larger than {board_size[0]}x{board_size[1]}?)"
            if reason:
                problems.append(f"{method}: {reason}")
                return None
            return pts

        # a board needs a few pixels per square; OpenCV's adaptive threshold fails outright on tiny images
        if min(h, w) < 3 * (min(board_size) + 1) or max(h, w) < 3 * (max(board_size) + 1):
            return None, f"image {w}x{h} too small for a {board_size[0]}x{board_size[1]} board"
        try:
            ok, corners = cv2.findChessboardCorners(gray8, board_size, flags=CLASSIC_FLAGS)
        except cv2.error as err:  # never an exception for one odd image: it is reported as not found
            return None, f"OpenCV failed on this image ({str(err).strip().splitlines()[-1][:120]})"
        if ok and corners is not None:
            half = _subpix_half_window(corners.reshape(-1, 2), board_size, self.window_fraction, self.window_limits)
            refined = cv2.cornerSubPix(
                np.ascontiguousarray(image, dtype=np.float32), corners.astype(np.float32), (half, half), (-1, -1), _SUBPIX_CRITERIA
            )
            pts = accept(refined, "classic")
            if pts is not None:
                return canonical_corner_order(pts, board_size), "classic"
        if self.use_sb_fallback:
            ok, corners = cv2.findChessboardCornersSB(gray8, board_size, flags=_SB_FLAGS)
            if ok and corners is not None:
                pts = accept(corners, "sb")
                if pts is not None:
                    return canonical_corner_order(pts, board_size), "sb"
        if problems:
            return None, "grid rejected: " + "; ".join(problems)
        return None, "board not found"

    def forward(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Detect the board on every image.

        Args:
            images: :math:`(B, 1, H, W)` float in ``[0, 1]``.
            board_size: ``(cols, rows)`` inner corners.

        Returns:
            :class:`DetectionResult` with corners :math:`(B, cols*rows, 2)` (float32, on the images'
            device) and found :math:`(B,)`.
        """
        board_size = self._check_inputs(images, board_size)
        n = board_size[0] * board_size[1]
        arrays = images.detach()[:, 0].float().clamp(0, 1).cpu().numpy()
        if self.num_workers > 1 and len(arrays) > 1:
            with ThreadPoolExecutor(max_workers=min(self.num_workers, len(arrays))) as pool:
                outputs = list(pool.map(lambda a: self.detect_one(a, board_size), arrays))
        else:
            outputs = [self.detect_one(a, board_size) for a in arrays]
        corners = np.zeros((len(arrays), n, 2), dtype=np.float32)
        found = np.zeros(len(arrays), dtype=bool)
        for b, (pts, _) in enumerate(outputs):
            if pts is not None:
                corners[b], found[b] = pts, True
        return DetectionResult(
            corners=torch.from_numpy(corners).to(images.device),
            found=torch.from_numpy(found).to(images.device),
            reasons=[reason for _, reason in outputs],
        )
