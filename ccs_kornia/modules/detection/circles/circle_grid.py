r"""Circle grids on images: OpenCV's grid finder for the dots' order, this package's moments for their centres.

For each image, and each polarity in turn (dark dots on a light print, then the inverse), ``cv2.findCirclesGrid``
finds the grid and its order: with its own blob detector, then with one that keeps steeply foreshortened dots
(inertia ratio down to :data:`MIN_INERTIA`), then that one with OpenCV's ``CALIB_CB_CLUSTERING``; each dot is then measured on the image
(:func:`~ccs_kornia.modules.detection.circles.dot_moments.dot_moments`: the centre of its image, its area). A dot
that cannot be measured is left unseen (NaN).

A grid whose half-turn looks the same is numbered from the end nearer the image's top left.
ROS-Industrial's modified grid (:attr:`~ccs_kornia.modules.detection.boards.CircleGrid.marked_origin`) is then put
in its own order (:func:`order_marked_origin`): the dot whose area is at least :data:`ORIGIN_AREA_RATIO` times the
others' median must sit at a corner of the grid; it becomes dot 0, ``x`` runs along its row and ``y`` along its column
so that ``x`` then ``y`` turn clockwise in the image (``y`` up on a print seen from the front, ``z`` towards the
camera). A grid without such a dot, or with it off the grid's corners, is not found: its origin cannot be told.

The centres are those of the dots' images, not the images of the dots' centres: the calibration corrects them once it
knows the camera and the board's poses (:mod:`~ccs_kornia.modules.detection.circles.centre_bias`).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.boards import CircleGrid
from ccs_kornia.modules.detection.circles.dot_moments import dot_moments

__all__ = ["MIN_INERTIA", "ORIGIN_AREA_RATIO", "CircleGridDetector", "detect_circle_grid", "order_marked_origin"]

#: the smallest ratio of a dot's image's minor to major second moment the blob detector keeps (a dot seen at about 77
#: degrees from its normal)
MIN_INERTIA = 0.05
#: the origin dot's area over the median of the others' (it is twice their diameter: four times their area)
ORIGIN_AREA_RATIO = 2.0


def _blob_detector() -> cv2.SimpleBlobDetector:
    p = cv2.SimpleBlobDetector_Params()
    p.minArea, p.maxArea = 6.0, 1e6
    p.filterByInertia, p.minInertiaRatio = True, MIN_INERTIA
    p.filterByCircularity, p.minCircularity = True, 0.4
    p.filterByConvexity, p.minConvexity = True, 0.8
    p.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(p)


def order_marked_origin(centres: np.ndarray, areas: np.ndarray, board_size: tuple[int, int]
                        ) -> tuple[np.ndarray | None, str]:
    """The permutation :math:`(N,)` that puts a modified circle grid's dots (``centres`` :math:`(N, 2)` and ``areas``
    :math:`(N,)` in a ``(cols, rows)`` grid order of any orientation) in its own order (module docstring), or
    ``None`` and why.

    Example:
        >>> r, c = np.meshgrid(np.arange(3), np.arange(4), indexing="ij")
        >>> pts = np.stack([c.ravel() * 10.0, r.ravel() * 10.0], -1)  # rows down the image
        >>> areas = np.ones(12)
        >>> areas[8] = 4.0  # the big dot at the bottom left of the image
        >>> perm, why = order_marked_origin(pts, areas, (4, 3))
        >>> pts[perm][:2].tolist(), pts[perm][4].tolist()
        ([[0.0, 20.0], [10.0, 20.0]], [0.0, 10.0])
    """
    cols, rows = board_size
    n = cols * rows
    if np.isfinite(areas).sum() < n // 2:
        return None, "too few dots measured to find the origin dot"
    big = int(np.nanargmax(areas))
    rest = np.delete(areas, big)
    ratio = areas[big] / np.nanmedian(rest)
    if not ratio >= ORIGIN_AREA_RATIO:
        return None, (f"no origin dot: the largest dot is {ratio:.1f} times the others' area (at least "
                      f"{ORIGIN_AREA_RATIO:g} expected)")
    idx = np.arange(n).reshape(rows, cols)
    candidates = []
    for grid in (idx, idx.T):
        for flip_r in (False, True):
            for flip_c in (False, True):
                g = grid[::-1] if flip_r else grid
                g = g[:, ::-1] if flip_c else g
                if g.shape != (rows, cols) or g[0, 0] != big:
                    continue
                x = centres[g[0, 1]] - centres[g[0, 0]]
                y = centres[g[1, 0]] - centres[g[0, 0]]
                candidates.append((float(x[0] * y[1] - x[1] * y[0]), g.ravel()))
    if not candidates:
        return None, "the origin dot is not at a corner of the grid"
    turn, perm = min(candidates, key=lambda t: t[0])
    if not turn < 0:
        return None, "the origin dot's grid is mirrored (the print seen from its back?)"
    return perm, ""


def _find(src: np.ndarray, board: CircleGrid, blobs) -> np.ndarray | None:
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if board.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    for extra, detector in ((0, None), (0, blobs), (cv2.CALIB_CB_CLUSTERING, blobs)):
        try:
            ok, pts = (cv2.findCirclesGrid(src, board.board_size, flags=flags | extra) if detector is None else
                       cv2.findCirclesGrid(src, board.board_size, flags=flags | extra, blobDetector=detector))
        except cv2.error:
            ok, pts = False, None
        if ok and pts is not None and len(pts) == board.num_corners:
            return pts.reshape(-1, 2).astype(np.float64)
    return None


def _detect_one(gray: np.ndarray, board: CircleGrid, min_dots: int) -> tuple[np.ndarray | None, str]:
    gray8 = np.clip(np.round(gray * 255.0), 0, 255).astype(np.uint8)
    blobs = _blob_detector()
    why = f"no {board.cols}x{board.rows} {'asymmetric ' if board.asymmetric else ''}grid of dots found"
    for dark in (True, False):
        rough = _find(gray8 if dark else 255 - gray8, board, blobs)
        if rough is None:
            continue
        m = dot_moments(gray, rough, dark=dark)
        centres = np.where(m.ok[:, None], m.centres, np.nan)
        polarity = "dark dots" if dark else "light dots"
        if board.marked_origin:
            perm, why = order_marked_origin(rough, m.areas, board.board_size)
            if perm is None:
                return None, why
            centres = centres[perm]
        elif not board.orientation_known and rough[-1].sum() < rough[0].sum():
            centres = centres[::-1].copy()  # a half-turn-symmetric grid: numbered from the end nearer the top left
        count = int(m.ok.sum())
        if count < min_dots:
            return None, f"only {count} of {board.num_corners} dots measured ({polarity})"
        return centres, f"circles ({polarity}), {count} of {board.num_corners} dots"
    return None, why


def detect_circle_grid(images: torch.Tensor, board: CircleGrid, min_dots: int = 6) -> DetectionResult:
    """The dots' centres :math:`(B, N, 2)` (px, dot order of ``board``; NaN where a dot could not be measured) on
    images :math:`(B, 1, H, W)` in ``[0, 1]`` (module docstring).

    Example:
        >>> g = CircleGrid(4, 3, 1.0)
        >>> art, a = g.texture(24)
        >>> out = detect_circle_grid(torch.from_numpy(art).float()[None, None] / 255, g)
        >>> bool(out.found[0]), np.round(out.corners[0, 5].numpy() - a[:, 2], 2).tolist()
        (True, [24.0, 24.0])
    """
    b = images.shape[0]
    n = board.num_corners
    corners = torch.zeros(b, n, 2, dtype=torch.float64)
    found = torch.zeros(b, dtype=torch.bool)
    reasons = []
    for k in range(b):
        gray = images[k, 0].detach().double().cpu().numpy()
        pts, why = _detect_one(gray, board, min_dots)
        if pts is not None:
            corners[k], found[k] = torch.from_numpy(pts), True
        reasons.append(why)
    # every measured dot counts alike (the corners' saddle precision measures nothing on a dot)
    sigma = torch.where(corners.isfinite().all(-1) & found[:, None], 1.0, float("nan")).to(torch.float64)
    return DetectionResult(corners.to(images.device), found.to(images.device), reasons, sigma.to(images.device))


class CircleGridDetector(ChessboardDetector):
    """Circle-grid detector with the chessboard detectors' interface (:func:`detect_circle_grid`): ``board_size`` is
    the grid's ``(cols, rows)`` dots; a dot not measured is NaN.

    It measures the dots at full resolution (``selects_scale``: the pipeline does not downscale its images); the
    distortion network, trained on boards of squares, does not judge its images (``lens_correction``).

    Args:
        board: the :class:`~ccs_kornia.modules.detection.boards.CircleGrid`.
        min_dots: dots a view needs to count as found.

    Example:
        >>> g = CircleGrid(4, 11, 0.02, asymmetric=True)
        >>> out = CircleGridDetector(g)(torch.zeros(2, 1, 64, 64), g.board_size)
        >>> out.corners.shape, out.found.tolist()
        (torch.Size([2, 44, 2]), [False, False])
    """

    selects_scale = True
    lens_correction = False

    def __init__(self, board: CircleGrid, min_dots: int = 6) -> None:
        super().__init__()
        self.board = board
        self.min_dots = int(min_dots)

    @property
    def refines_on_image(self) -> bool:
        return False

    def forward(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        board_size = self._check_inputs(images, board_size)
        if board_size != self.board.board_size:
            raise ValueError(f"board_size {board_size} is not the circle grid's {self.board.board_size}.")
        return detect_circle_grid(images, self.board, self.min_dots)
