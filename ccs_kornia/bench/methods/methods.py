"""The corner detectors under test, behind one interface (:class:`DetectionMethod`), built by :func:`make_methods`."""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np
import torch

from ccs_kornia.bench.config import METHODS
from ccs_kornia.bench.scenes.scenes import orient_grid

__all__ = ["ABLATIONS", "DetectionMethod", "make_methods", "make_ablations"]

#: ablation rows of the corner section: key -> (the method it varies, its label, detector options)
ABLATIONS: dict[str, tuple[str, str, dict]] = {
    # as the detector applies it: after the grid, before the saddle refinement on the image
    "learned_collinearity": ("learned", "ccs_kornia learned + collinearity", {"collinearity": True}),
    # as the paper's last step: on the final (saddle-refined) corners
    "learned_collinearity_last": ("learned", "ccs_kornia learned + collinearity last", {"collinearity_last": True}),
}

_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)


def _to_uint8(images: torch.Tensor) -> np.ndarray:
    return np.clip(np.rint(images.detach()[:, 0].float().cpu().numpy() * 255.0), 0, 255).astype(np.uint8)


def _opencv_subpix_one(gray8: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    ok, c = cv2.findChessboardCorners(gray8, board, flags=_CLASSIC_FLAGS)
    if not ok or c is None:
        return None
    pts = c.reshape(-1, 2).astype(np.float64)
    cols, rows = board
    g = pts.reshape(rows, cols, 2)
    spacing = min(np.linalg.norm(np.diff(g, axis=1), axis=-1).min(), np.linalg.norm(np.diff(g, axis=0), axis=-1).min())
    # half-window about 0.45 x the corner spacing: the classic path the design measures as OpenCV's strongest
    half = int(np.clip(round(0.45 * spacing), 2, 11))
    c = cv2.cornerSubPix(gray8, c.astype(np.float32), (half, half), (-1, -1), _SUBPIX_CRITERIA)
    return c.reshape(-1, 2).astype(np.float64)


def _opencv_sb_one(gray8: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    ok, c = cv2.findChessboardCornersSB(gray8, board, flags=_SB_FLAGS)
    return c.reshape(-1, 2).astype(np.float64) if ok and c is not None else None


class DetectionMethod:
    """One corner detector under test: ``detect(images (B,1,H,W)) -> corners (B,N,2) float64, found (B,)``.

    Attributes:
        key: short name (a key of :data:`METHODS`).
        label: name in the reports.
        available: whether it can run here.
        reason: why not, when not available.
    """

    def __init__(self, key: str, fn: Callable | None, reason: str = "", label: str | None = None) -> None:
        self.key, self.label = key, label or METHODS.get(key, key)
        self._fn = fn
        self.available = fn is not None
        self.reason = reason

    def detect(self, images: torch.Tensor, board: tuple[int, int], **options) -> tuple[np.ndarray, np.ndarray]:
        """``options``: of the method (the learned detector's ``batch``: images per call, default the bench's)."""
        if not self.available:
            raise RuntimeError(f"{self.label} is not available: {self.reason}")
        corners, found = self._fn(images, board, **options)
        return np.asarray(corners, dtype=np.float64), np.asarray(found, dtype=bool)

    def __repr__(self) -> str:
        return f"DetectionMethod({self.key!r}, available={self.available})"


def _per_image(one: Callable[[np.ndarray, tuple[int, int]], np.ndarray | None]) -> Callable:
    def run(images: torch.Tensor, board: tuple[int, int]):
        n = board[0] * board[1]
        gray = _to_uint8(images)
        corners = np.zeros((len(gray), n, 2))
        found = np.zeros(len(gray), dtype=bool)
        for b, g in enumerate(gray):
            pts = one(g, board)
            if pts is not None and pts.shape == (n, 2):
                corners[b], found[b] = orient_grid(pts, board), True
        return corners, found

    return run


def _libcbdetect_method() -> tuple[Callable | None, str]:
    try:
        from libCBDetect import Checkerboard  # type: ignore[import-not-found]
    except ImportError:
        return None, "not installed (pip install libcbdetect)"
    except OSError as err:  # installed, but its bundled shared libraries do not load here
        return None, f"installed but cannot be loaded ({err})"

    def one(gray8: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
        cols, rows = board
        det = Checkerboard()
        det.norm, det.score_thr, det.strict_grow = True, 0.01, False
        det.show_processing = det.show_debug_image = det.show_grow_processing = det.overlay = False
        img = gray8.astype(np.float64)
        span = float(np.ptp(img))
        if span <= 0:
            return None
        img = (img - img.min()) / span
        det.cols = det.rows = 0
        det.array_norm_to_image(img.reshape(-1), img.shape[0], img.shape[1])
        det.find_corners()
        det.find_board_from_corners()
        r, c = int(det.rows), int(det.cols)
        if r * c != rows * cols or {r, c} != {rows, cols}:
            return None  # no board, or a board of another size (sub-board)
        u, v = np.zeros(r * c), np.zeros(r * c)
        det.get_board_corners(u, v)
        g = np.stack([u, v], -1).reshape(r, c, 2)
        if (r, c) != (rows, cols):
            g = g.transpose(1, 0, 2)
        pts = g.reshape(-1, 2)
        return pts if np.isfinite(pts).all() else None

    return _per_image(one), ""


def _learned_method(batch: int, collinearity_last: bool = False, **options) -> tuple[Callable | None, str]:
    from ccs_kornia.modules.detection.factory import make_detector
    from ccs_kornia.modules.detection.grid.collinearity import collinearity_refine

    try:
        from ccs_kornia.modules.detection.learned.learned_detector import (
            DEFAULT_DETECTOR_WEIGHTS,
        )
    except ImportError as err:
        return None, f"learned detector module not available ({err})"
    if not DEFAULT_DETECTOR_WEIGHTS.is_file():
        return None, f"learned detector: weights not available ({DEFAULT_DETECTOR_WEIGHTS} not found)"
    try:
        det = make_detector("learned", **options)
    except Exception as err:  # unreadable or incompatible weights must not stop the other methods
        return None, f"learned detector: weights could not be loaded ({type(err).__name__}: {err})"

    def run(images: torch.Tensor, board: tuple[int, int], batch: int = batch):
        cs, fs = [], []
        det.to(images.device)
        with torch.inference_mode():
            for i in range(0, images.shape[0], batch):
                out = det(images[i : i + batch], board)
                if collinearity_last:
                    refined, _ = collinearity_refine(out.corners.double(), out.valid, board)
                    out.corners = torch.where(out.found[:, None, None], refined, out.corners.double())
                cs.append(out.corners.double().cpu().numpy())
                fs.append(out.found.cpu().numpy())
        corners, found = np.concatenate(cs), np.concatenate(fs)
        for b in np.nonzero(found)[0]:
            corners[b] = orient_grid(corners[b], board)
        return corners, found

    run.detector = det  # type: ignore[attr-defined]
    return run, ""


def _opencv_saddle_method() -> Callable:
    from ccs_kornia.modules.detection.opencv_detector import OpenCVChessboardDetector
    from ccs_kornia.modules.detection.refine.saddle_refine import CornerRefiner

    det, refiner = OpenCVChessboardDetector(), CornerRefiner()

    def run(images: torch.Tensor, board: tuple[int, int]):
        with torch.inference_mode():
            out = det(images, board)
            corners = out.corners
            if bool(out.found.any()):
                corners = refiner(images.float(), corners.float(), out.valid, board)
        corners, found = corners.double().cpu().numpy(), out.found.cpu().numpy()
        for b in np.nonzero(found)[0]:
            corners[b] = orient_grid(corners[b], board)
        return corners, found

    return run


def make_methods(keys: tuple[str, ...] | list[str], learned_batch: int = 8) -> dict[str, DetectionMethod]:
    """Build the detection methods; unavailable ones carry the reason instead of raising."""
    out: dict[str, DetectionMethod] = {}
    for key in keys:
        if key not in METHODS:
            raise ValueError(f"Unknown method {key!r}; expected some of {list(METHODS)}.")
        if key == "learned":
            fn, reason = _learned_method(learned_batch)
            out[key] = DetectionMethod(key, fn, reason)
        elif key == "opencv_saddle":
            out[key] = DetectionMethod(key, _opencv_saddle_method())
        elif key == "opencv_subpix":
            out[key] = DetectionMethod(key, _per_image(_opencv_subpix_one))
        elif key == "opencv_sb":
            out[key] = DetectionMethod(key, _per_image(_opencv_sb_one))
        else:
            fn, reason = _libcbdetect_method()
            out[key] = DetectionMethod(key, fn, reason)
    return out


def make_ablations(keys: tuple[str, ...] | list[str], learned_batch: int = 8) -> dict[str, DetectionMethod]:
    """Build the ablation methods of :data:`ABLATIONS` (e.g. the learned detector with the paper's collinearity
    refinement on); unavailable ones carry the reason instead of raising."""
    out: dict[str, DetectionMethod] = {}
    for key in keys:
        if key not in ABLATIONS:
            raise ValueError(f"Unknown ablation {key!r}; expected some of {list(ABLATIONS)}.")
        base, label, options = ABLATIONS[key]
        fn, reason = _learned_method(learned_batch, **options)
        out[key] = DetectionMethod(key, fn, reason, label=label)
    return out
