"""A quick first look at a frame: does it hold the board, and roughly where (before the full detector is spent on it).

A recording of a minute holds about 1800 frames, most of them of no use (no board, the board half out of view, a near
copy of the frame before); the full detector costs a few frames a second at 720p. :class:`BoardScreen` looks at a
downscaled copy of each frame with OpenCV's cheapest test for the board's kind:

* a chessboard: ``cv2.findChessboardCorners`` with ``CALIB_CB_FAST_CHECK`` (a frame without a board is refused in a
  few milliseconds), on a copy whose longer side is ``max_side``;
* a ChArUco board or an AprilGrid: its markers (``cv2.aruco``, both print polarities in one pass, and the mirrored
  image where the plain one shows too few: a two-sided board's back), checked against the board's lattice, at least
  ``min_markers``;
* a circle grid: ``cv2.findCirclesGrid`` on the copy (dark dots, then light ones).

What it sees is a :class:`Sighting`: whether the board is there and its *outline* ``(4, 2)``, the image positions of
the inner-corner grid's four extreme corners (first, end of the first row, last, start of the last row) in the
full-size frame's pixels; for a marker board, where the markers' homography puts them, so a partial view has an
outline too. The outline is rough (the screen's resolution): enough to tell a still board from a moving one and a
new pose from a near copy (:mod:`~ccs_kornia.pipeline.frame_candidates`), never used as corners.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard, CircleGrid

__all__ = ["DEFAULT_SCREEN_SIDE", "BoardScreen", "Sighting", "grid_outline"]

#: the screen's copy of a frame has this longer side (a 1280x720 frame is looked at as 640x360)
DEFAULT_SCREEN_SIDE = 640


@dataclass
class Sighting:
    """What the screen saw on one frame.

    Attributes:
        found: the board is there.
        outline: :math:`(4, 2)` float64, the inner-corner grid's extreme corners in the full-size frame's pixels
            (``None`` when not found).
        points: corners (chessboard) or markers (marker boards) the screen saw.
    """

    found: bool
    outline: np.ndarray | None = None
    points: int = 0


def grid_outline(corners: np.ndarray, board_size: tuple[int, int]) -> np.ndarray:
    """The four extreme corners :math:`(4, 2)` of a grid's corners :math:`(N, 2)` in grid order (row by row): first,
    end of the first row, last, start of the last row.

    Example:
        >>> c = np.array([[x, y] for y in range(3) for x in range(4)], dtype=float)
        >>> grid_outline(c, (4, 3)).tolist()
        [[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 2.0]]
    """
    cols, rows = int(board_size[0]), int(board_size[1])
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    return pts[[0, cols - 1, cols * rows - 1, cols * (rows - 1)]].copy()


class BoardScreen:
    """The quick first look at frames for one board.

    Args:
        board_size: ``(cols, rows)`` inner corners.
        board: the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard`,
            :class:`~ccs_kornia.modules.detection.boards.AprilGrid` or
            :class:`~ccs_kornia.modules.detection.boards.CircleGrid` (``None``: a chessboard).
        max_side: the longer side of the copy looked at (frames as small or smaller are looked at as they are).
        min_markers: markers a marker board needs on the lattice to count as seen.

    Example:
        >>> board = np.kron((np.indices((5, 6)).sum(0) % 2) * 255, np.ones((20, 20))).astype(np.uint8)
        >>> frame = np.full((200, 240), 128, np.uint8)
        >>> frame[40:140, 60:180] = board
        >>> seen = BoardScreen((5, 4))(frame)
        >>> seen.found, seen.points, np.round(seen.outline).astype(int).tolist()
        (True, 20, [[80, 60], [160, 60], [160, 120], [80, 120]])
    """

    def __init__(self, board_size: tuple[int, int], board: CharucoBoard | AprilGrid | CircleGrid | None = None,
                 max_side: int = DEFAULT_SCREEN_SIDE, min_markers: int = 2) -> None:
        if len(board_size) != 2 or min(int(board_size[0]), int(board_size[1])) < 2:
            raise ValueError(f"board_size must be (cols, rows) with at least 2 inner corners each, got {board_size}.")
        if max_side < 64:
            raise ValueError(f"max_side must be >= 64, got {max_side}.")
        self.board_size = (int(board_size[0]), int(board_size[1]))
        self.board = board
        self.max_side = int(max_side)
        self.min_markers = max(1, int(min_markers))
        self._outline_units: np.ndarray | None = None
        if board is not None and not isinstance(board, CircleGrid):
            cols, rows = self.board_size
            unit = float(board.square if isinstance(board, CharucoBoard) else board.tag_size)
            obj = board.object_points().numpy()[:, :2] / unit
            self._outline_units = grid_outline(obj, (cols, rows))
        self._detector = None  # the marker detector, made in the process that uses it

    @property
    def sees_partial_boards(self) -> bool:
        """Whether a board partly beyond the image's edge is seen (a marker board: its markers' homography gives the
        outline; a chessboard's and a circle grid's test needs the whole board)."""
        return self._outline_units is not None

    def scale(self, size: tuple[int, int]) -> float:
        """The factor from a ``(W, H)`` frame to the copy the screen looks at (1: looked at as it is)."""
        return min(1.0, self.max_side / max(size))

    def shrink(self, gray8: np.ndarray) -> np.ndarray:
        """The copy of a full-size grey ``uint8`` frame that the screen looks at."""
        h, w = gray8.shape[:2]
        s = self.scale((w, h))
        if s >= 1.0:
            return gray8
        return cv2.resize(gray8, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)

    def __call__(self, gray8: np.ndarray, full_size: tuple[int, int] | None = None) -> Sighting:
        """Look at one grey ``uint8`` frame.

        Args:
            gray8: the frame, full size or already shrunk (:meth:`shrink`).
            full_size: ``(W, H)`` of the full-size frame when ``gray8`` is a shrunk copy (default: its own size).

        Returns:
            :class:`Sighting`, the outline in full-size pixels.
        """
        h, w = gray8.shape[:2]
        full = (w, h) if full_size is None else (int(full_size[0]), int(full_size[1]))
        small = gray8 if (w, h) != full else self.shrink(gray8)
        # pixel centres at integers: a copy scaled by s maps x to (x + 0.5) / s - 0.5
        sx, sy = full[0] / small.shape[1], full[1] / small.shape[0]
        if self.board is None:
            seen = self._chessboard(small)
        elif isinstance(self.board, CircleGrid):
            seen = self._circles(small)
        else:
            seen = self._markers(small)
        if seen.outline is not None:
            seen.outline = (seen.outline + 0.5) * np.array([sx, sy]) - 0.5
        return seen

    def _chessboard(self, small: np.ndarray) -> Sighting:
        flags = cv2.CALIB_CB_FAST_CHECK | cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(small, self.board_size, flags=flags)
        if not found or corners is None:
            return Sighting(False)
        return Sighting(True, grid_outline(corners.reshape(-1, 2), self.board_size), len(corners))

    def _circles(self, small: np.ndarray) -> Sighting:
        """A circle grid: ``cv2.findCirclesGrid`` on the copy, dark dots then light ones."""
        flags = cv2.CALIB_CB_ASYMMETRIC_GRID if self.board.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
        for img in (small, 255 - small):
            found, centres = cv2.findCirclesGrid(img, self.board_size, flags=flags)
            if found and centres is not None:
                return Sighting(True, grid_outline(centres.reshape(-1, 2), self.board_size), len(centres))
        return Sighting(False)

    def _marker_table(self) -> tuple[cv2.aruco.ArucoDetector, dict[int, np.ndarray]]:
        """The marker detector (both print polarities in one pass, no corner refinement: the outline is rough) and
        marker id -> its corners ``(4, 2)`` on the board, in squares or tag sides (made in the process that uses
        them)."""
        if self._detector is None:
            from ccs_kornia.modules.detection.boards import aruco_dictionary

            params = cv2.aruco.DetectorParameters()
            params.detectInvertedMarker = True
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
            if isinstance(self.board, CharucoBoard):
                from ccs_kornia.modules.detection.markers.charuco import board_markers

                table = board_markers(self.board, bool(self.board.legacy))
            else:
                from ccs_kornia.modules.detection.boards import APRILGRID_BORDER_BITS
                from ccs_kornia.modules.detection.markers.aprilgrid import board_tags

                params.markerBorderBits = APRILGRID_BORDER_BITS
                table = board_tags(self.board)
            self._detector = (cv2.aruco.ArucoDetector(aruco_dictionary(self.board.dictionary), params), table)
        return self._detector

    def _markers(self, small: np.ndarray) -> Sighting:
        from ccs_kornia.modules.detection.markers.marker_board import consistent_markers

        detector, table = self._marker_table()
        best = (np.zeros((0, 4, 2)), np.zeros((0, 4, 2)))
        for mirrored in (False, True):  # a two-sided board seen from its back: decoded on the mirrored image
            corners, ids, _ = detector.detectMarkers(cv2.flip(small, 1) if mirrored else small)
            if ids is None or not len(ids):
                continue
            pts = np.stack([c.reshape(4, 2) for c in corners]).astype(np.float64)
            if mirrored:
                pts[..., 0] = small.shape[1] - 1 - pts[..., 0]
            ids = ids.reshape(-1)
            _, first = np.unique(ids, return_index=True)
            keep = np.array([k in first and int(i) in table for k, i in enumerate(ids)], dtype=bool)
            if keep.sum() <= len(best[0]):
                continue
            pts, obj = pts[keep], np.stack([table[int(i)] for i in ids[keep]])
            on = consistent_markers(pts, obj)
            if on.sum() > len(best[0]):
                best = (pts[on], obj[on])
            if len(best[0]) >= self.min_markers:
                break
        m = len(best[0])
        if m < self.min_markers:
            return Sighting(False, None, m)
        h, _ = cv2.findHomography(best[1].reshape(-1, 2), best[0].reshape(-1, 2), 0)
        if h is None or not np.isfinite(h).all():
            return Sighting(False, None, m)
        outline = cv2.perspectiveTransform(self._outline_units[None], h)[0].astype(np.float64)
        return Sighting(True, outline, m)
