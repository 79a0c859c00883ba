"""Shared pieces of the benchmark: configuration, seeded scenes, detection methods, corner bookkeeping, solvers.

Everything here is deterministic for a given :class:`BenchConfig`: scenes are rendered from seeds at
:data:`ccs_kornia.data.datamodule.BENCH_SEED_BASE` and above, which training and validation never use.

Every method sees the same images, quantised to 8 bits as a camera would deliver them (the OpenCV peers get
the ``uint8`` array, the torch methods the same values divided by 255).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import cv2
import numpy as np
import torch

from ccs_kornia.camera import board_object_points
from ccs_kornia.data.datamodule import BENCH_SEED_BASE
from ccs_kornia.data.scenes import make_calibration_set
from ccs_kornia.data.sampling import sample_radial_distortion

__all__ = [
    "SECTIONS",
    "CORNER_CONDITIONS",
    "CALIB_CONDITIONS",
    "METHODS",
    "BenchConfig",
    "Scenes",
    "render_scenes",
    "random_cameras",
    "quantize",
    "DetectionMethod",
    "make_methods",
    "orient_grid",
    "lattice_orderings",
    "corner_errors",
    "cv2_calibrate",
    "ccs_calibrate",
    "summary",
    "Timer",
]

#: benchmark sections, in report order
SECTIONS: tuple[str, ...] = ("corners", "calibration", "real", "distortion", "speed", "wild")
#: conditions of the corner-accuracy section (paper Table III plus the design's extra ones)
CORNER_CONDITIONS: tuple[str, ...] = ("clean", "blur_noise", "bad_lighting", "mild", "severe", "combined")
#: conditions of the synthetic calibration section (paper Table I)
CALIB_CONDITIONS: tuple[str, ...] = ("blur_noise", "bad_lighting", "level1", "level2")
#: detection methods: key -> label used in the reports
METHODS: dict[str, str] = {
    "learned": "ccs_kornia learned",
    "opencv_saddle": "opencv+saddle",
    "opencv_subpix": "cv2 classic+cornerSubPix",
    "opencv_sb": "cv2 findChessboardCornersSB",
    "libcbdetect": "libcbdetect",
}
#: condition name -> (photometric condition of ``augment.CONDITIONS``, radial level or None)
_CONDITION_PARTS: dict[str, tuple[str, str | None]] = {
    "clean": ("clean", None),
    "blur_noise": ("blur_noise", None),
    "noise": ("blur_noise", None),
    "bad_lighting": ("bad_lighting", None),
    "combined": ("combined", None),
    "mild": ("clean", "level1"),
    "level1": ("clean", "level1"),
    "level2": ("clean", "level2"),
    "severe": ("clean", "severe"),
}
#: seed offsets of the sections, so no two sections render the same scene
_SECTION_SEED = {"corners": 0, "calibration": 100_000, "distortion": 200_000, "speed": 300_000, "wild": 400_000}


@dataclass
class BenchConfig:
    """What the benchmark runs and at which size (see :meth:`full`, :meth:`quick`, :meth:`tiny`).

    Attributes:
        sections: sections to run, a subset of :data:`SECTIONS`.
        methods: detection methods, a subset of :data:`METHODS` (unavailable ones are reported and skipped).
        image_size: ``(W, H)`` of the synthetic images.
        board: ``(cols, rows)`` inner corners of the synthetic board.
        square: square side (m) of the synthetic board.
        supersample: renderer sub-cells per pixel side.
        corner_conditions: conditions of the corner section.
        corner_images: images per condition (corner section).
        corner_views_per_camera: views per random camera in the corner section.
        error_threshold: a corner further than this (px) from the truth is wrong.
        calib_conditions: conditions of the calibration section.
        calib_trials: calibration trials per condition.
        calib_views: views per trial.
        calib_pool_views: views rendered per camera; trials of one camera draw ``calib_views`` of them
            (``calib_pool_views == calib_views`` gives fully independent trials).
        calib_trials_per_camera: trials drawn from one camera's pool.
        calib_methods: detection methods of the calibration section (``None``: all of ``methods``).
        real_dir: folder of the real photograph sets (``None``: ``../shared/data/real`` beside the repo).
        real_sets: set names to run (``None``: every known set found).
        real_subsets: random view subsets per set.
        real_subset_fraction: fraction of a set's images in one subset.
        real_max_images: at most this many images per set (``None``: all).
        dc_trials, dc_views: trials (cameras) and views of the severe-distortion part of the distortion section.
        wide_trials, wide_views, wide_size, wide_fx: the paper's wide camera (level-2 distortion) part.
        distortion_weights: DistortionNet export (``None``: the shipped weights).
        speed_batch_sizes: detection batch sizes timed.
        speed_images: images timed per batch size.
        speed_solver_cameras: camera counts of the batched solver timing.
        speed_repeats: repeats of each timing (best is kept).
        devices: ``cpu`` and/or ``cuda`` (``cuda`` skipped when not present).
        learned_batch: images per learned-detector call.
        wild_conditions: conditions of the ``wild`` section (``None``: all of ``bench.wild.WILD_CONDITIONS``).
        wild_images: images per wild condition; wild_big_images: per condition of 4 Mpx and more.
        wild_free_images: board-free images of the wild section.
        wild_real_sets: real sets rescaled in the wild section (``None``: all eight).
        wild_real_scales: rescaling factors of the real photos; wild_real_images: images per set (``None``: all).
    """

    sections: tuple[str, ...] = SECTIONS
    methods: tuple[str, ...] = tuple(METHODS)
    image_size: tuple[int, int] = (640, 480)
    board: tuple[int, int] = (9, 6)
    square: float = 0.025
    supersample: int = 3
    corner_conditions: tuple[str, ...] = CORNER_CONDITIONS
    corner_images: int = 60
    corner_views_per_camera: int = 15
    error_threshold: float = 3.0
    calib_conditions: tuple[str, ...] = CALIB_CONDITIONS
    calib_trials: int = 50
    calib_views: int = 15
    calib_pool_views: int = 30
    calib_trials_per_camera: int = 5
    calib_methods: tuple[str, ...] | None = None
    real_dir: str | None = None
    real_sets: tuple[str, ...] | None = None
    real_subsets: int = 20
    real_subset_fraction: float = 0.7
    real_max_images: int | None = None
    dc_trials: int = 20
    dc_views: int = 15
    wide_trials: int = 20
    wide_views: int = 15
    wide_size: tuple[int, int] = (480, 480)
    wide_fx: tuple[float, float] = (100.0, 300.0)
    distortion_weights: str | None = None
    speed_batch_sizes: tuple[int, ...] = (1, 16)
    speed_images: int = 16
    speed_solver_cameras: tuple[int, ...] = (1, 16, 64)
    speed_repeats: int = 2
    devices: tuple[str, ...] = ("cpu", "cuda")
    learned_batch: int = 8
    wild_conditions: tuple[str, ...] | None = None
    wild_images: int = 20
    wild_big_images: int = 5
    wild_free_images: int = 200
    wild_real_sets: tuple[str, ...] | None = None
    wild_real_scales: tuple[float, ...] = (0.5, 1.5, 2.0, 4.0)
    wild_real_images: int | None = 6
    preset: str = "full"
    extra: dict = field(default_factory=dict)

    @classmethod
    def full(cls, **overrides) -> BenchConfig:
        """The full run (target: under 45 minutes on 2 CPU cores)."""
        return replace(cls(), **overrides)

    @classmethod
    def quick(cls, **overrides) -> BenchConfig:
        """A few images and trials per condition (target: under 5 minutes on 2 idle CPU cores)."""
        base = cls(
            corner_images=8, corner_views_per_camera=4, calib_trials=3, calib_views=10, calib_pool_views=10, calib_trials_per_camera=1,
            real_subsets=4, real_max_images=12, dc_trials=2, dc_views=10, wide_trials=1, wide_views=10, speed_images=4,
            speed_solver_cameras=(1, 16), speed_repeats=1, supersample=2, preset="quick",
            real_sets=("opencv_left", "boofcv_bumblebee2_left"),
            calib_methods=("learned", "opencv_saddle", "opencv_subpix", "opencv_sb"),
            wild_images=2, wild_big_images=1, wild_free_images=28, wild_real_images=1,
        )
        return replace(base, **overrides)

    @classmethod
    def tiny(cls, **overrides) -> BenchConfig:
        """The smallest configuration that still exercises every section (used by the tests)."""
        base = cls(
            image_size=(320, 240), board=(6, 4), supersample=1, corner_conditions=("clean", "severe"),
            corner_images=2, corner_views_per_camera=2, calib_conditions=("blur_noise",), calib_trials=2,
            calib_views=5, calib_pool_views=5, calib_trials_per_camera=1, real_subsets=2, real_max_images=6, dc_trials=1, dc_views=5, wide_trials=1, wide_views=5, wide_size=(240, 240),
            wide_fx=(60.0, 150.0),
            speed_batch_sizes=(1, 2), speed_images=2, speed_solver_cameras=(1, 2), speed_repeats=1,
            real_sets=("boofcv_bumblebee2_left",), calib_methods=("opencv_saddle", "opencv_subpix"),
            wild_conditions=("img320", "cut"), wild_images=1, wild_big_images=1, wild_free_images=2,
            wild_real_sets=("boofcv_bumblebee2_left",), wild_real_scales=(0.5,), wild_real_images=1,
            preset="tiny",
        )
        return replace(base, **overrides)

    def to_dict(self) -> dict:
        return asdict(self)


# ----------------------------------------------------------------------------------------------
# scenes
# ----------------------------------------------------------------------------------------------


def quantize(images: torch.Tensor) -> torch.Tensor:
    """8-bit quantisation, as a camera delivers images: ``round(255 x) / 255``."""
    return torch.round(images.clamp(0, 1) * 255.0) / 255.0


def random_cameras(num: int, image_size: tuple[int, int], generator: torch.Generator) -> torch.Tensor:
    """Random pinhole cameras ``(num, 3, 3)``: fx in ``[0.7, 1.2] W``, fy/fx in ``[0.97, 1.03]``, principal
    point within 3 % of the image centre (independent fx, fy, cx, cy, as the design asks)."""
    w, h = image_size
    u = torch.rand(num, 4, generator=generator, dtype=torch.float64)
    fx = w * (0.7 + 0.5 * u[:, 0])
    fy = fx * (0.97 + 0.06 * u[:, 1])
    cx = (w - 1) / 2 + 0.03 * w * (2 * u[:, 2] - 1)
    cy = (h - 1) / 2 + 0.03 * h * (2 * u[:, 3] - 1)
    K = torch.zeros(num, 3, 3, dtype=torch.float64)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, cx, cy, 1.0
    return K


@dataclass
class Scenes:
    """Rendered views of ``C`` cameras with ``V`` views each, with exact ground truth.

    Attributes:
        images: :math:`(C, V, 1, H, W)` float in ``[0, 1]``, 8-bit quantised.
        corners: :math:`(C, V, N, 2)` true (distorted) corner pixels, float64.
        K: :math:`(C, 3, 3)` float64.
        radial: :math:`(C, 3)` the paper's radial coefficients of each camera (``(1, 0, 0)`` if none).
        condition: the condition name.
        render_seconds: wall time of the rendering.
    """

    images: torch.Tensor
    corners: torch.Tensor
    K: torch.Tensor
    radial: torch.Tensor
    condition: str
    render_seconds: float

    @property
    def flat_images(self) -> torch.Tensor:
        return self.images.reshape(-1, *self.images.shape[2:])

    @property
    def flat_corners(self) -> torch.Tensor:
        return self.corners.reshape(-1, *self.corners.shape[2:])


def render_scenes(
    cfg: BenchConfig, condition: str, cameras: int, views: int, section: str, radial: tuple[float, float, float] | None = None
) -> Scenes:
    """Render ``cameras x views`` images of ``cfg.board`` under a named condition.

    Args:
        cfg: benchmark configuration (image size, board, supersampling).
        condition: a key of the corner / calibration conditions (``clean``, ``blur_noise``, ``bad_lighting``,
            ``combined``, ``mild``/``level1``, ``level2``, ``severe``).
        cameras: number of random cameras.
        views: views per camera.
        section: section name (selects a disjoint seed range).
        radial: fixed radial coefficients for every camera (overrides the condition's level).

    Returns:
        :class:`Scenes`.
    """
    if condition not in _CONDITION_PARTS:
        raise ValueError(f"Unknown condition {condition!r}; expected one of {sorted(_CONDITION_PARTS)}.")
    photometric, level = _CONDITION_PARTS[condition]
    cond_index = sorted(_CONDITION_PARTS).index(condition)
    base = BENCH_SEED_BASE + _SECTION_SEED[section] + 1000 * cond_index
    gen = torch.Generator().manual_seed(base)
    Ks = random_cameras(cameras, cfg.image_size, gen)
    if radial is not None:
        rad = torch.tensor(radial, dtype=torch.float32).expand(cameras, 3).clone()
    elif level is not None:
        rad = sample_radial_distortion(cameras, level, cfg.image_size, gen)
    else:
        rad = torch.tensor([1.0, 0.0, 0.0]).expand(cameras, 3).clone()
    t0 = time.perf_counter()
    imgs, pts = [], []
    for c in range(cameras):
        batch = make_calibration_set(
            Ks[c].float(), cfg.board, cfg.square, cfg.image_size, views,
            radial=rad[c] if (level is not None or radial is not None) else None,
            condition=photometric, seed=base + 1 + c, supersample=cfg.supersample,
        )
        imgs.append(quantize(batch.images))
        pts.append(batch.corners.double())
    return Scenes(
        images=torch.stack(imgs), corners=torch.stack(pts), K=Ks, radial=rad, condition=condition,
        render_seconds=time.perf_counter() - t0,
    )


# ----------------------------------------------------------------------------------------------
# grid orderings and errors
# ----------------------------------------------------------------------------------------------


def lattice_orderings(grid: np.ndarray, square_board: bool) -> list[np.ndarray]:
    """All index orderings of a ``(rows, cols, 2)`` lattice describing the same set of corners.

    The 180-degree rotation and both mirrors (a mirrored board gives the same intrinsics), plus the
    transposes for square boards.
    """
    out = [grid, grid[::-1, ::-1], grid[::-1, :], grid[:, ::-1]]
    if square_board:
        out += [g.transpose(1, 0, 2) for g in list(out)]
    return out


def orient_grid(corners: np.ndarray, board: tuple[int, int]) -> np.ndarray:
    """Give a detected lattice the board's handedness and the canonical 180-degree orientation.

    A board seen from its front keeps ``(step along i) x (step along j) > 0`` in image coordinates
    (y down); a detector that returns the mirrored order gets its columns flipped. Then
    :func:`ccs_kornia.modules.detection.board_checks.canonical_corner_order` picks the orientation whose first
    corner is nearest the image's top-left, so every method and view follows one convention.
    """
    from ccs_kornia.modules.detection.board_checks import canonical_corner_order

    cols, rows = board
    g = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    u = (g[:, -1] - g[:, 0]).mean(0) if cols > 1 else np.array([1.0, 0.0])
    v = (g[-1] - g[0]).mean(0) if rows > 1 else np.array([0.0, 1.0])
    if u[0] * v[1] - u[1] * v[0] < 0:
        g = g[:, ::-1]
    return canonical_corner_order(g.reshape(-1, 2), board)


def corner_errors(pred: np.ndarray, truth: np.ndarray, board: tuple[int, int]) -> np.ndarray:
    """Per-corner distance ``(N,)`` to the truth under the best of :func:`lattice_orderings`."""
    cols, rows = board
    g = np.asarray(pred, dtype=np.float64).reshape(rows, cols, 2)
    t = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    best, best_mean = None, np.inf
    for cand in lattice_orderings(g, cols == rows):
        cand = cand.reshape(-1, 2)
        if cand.shape != t.shape:
            continue
        err = np.linalg.norm(cand - t, axis=-1)
        if err.mean() < best_mean:
            best, best_mean = err, err.mean()
    return best


# ----------------------------------------------------------------------------------------------
# detection methods
# ----------------------------------------------------------------------------------------------

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

    def __init__(self, key: str, fn: Callable | None, reason: str = "") -> None:
        self.key, self.label = key, METHODS.get(key, key)
        self._fn = fn
        self.available = fn is not None
        self.reason = reason

    def detect(self, images: torch.Tensor, board: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        if not self.available:
            raise RuntimeError(f"{self.label} is not available: {self.reason}")
        corners, found = self._fn(images, board)
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


def _learned_method(batch: int) -> tuple[Callable | None, str]:
    from ccs_kornia.modules.detection.factory import make_detector

    try:
        from ccs_kornia.modules.detection.learned_detector import DEFAULT_DETECTOR_WEIGHTS
    except ImportError as err:
        return None, f"learned detector module not available ({err})"
    if not DEFAULT_DETECTOR_WEIGHTS.is_file():
        return None, f"learned detector: weights not available ({DEFAULT_DETECTOR_WEIGHTS} not found)"
    try:
        det = make_detector("learned")
    except Exception as err:  # unreadable or incompatible weights must not stop the other methods
        return None, f"learned detector: weights could not be loaded ({type(err).__name__}: {err})"

    def run(images: torch.Tensor, board: tuple[int, int]):
        cs, fs = [], []
        det.to(images.device)
        with torch.inference_mode():
            for i in range(0, images.shape[0], batch):
                out = det(images[i : i + batch], board)
                cs.append(out.corners.double().cpu().numpy())
                fs.append(out.found.cpu().numpy())
        corners, found = np.concatenate(cs), np.concatenate(fs)
        for b in np.nonzero(found)[0]:
            corners[b] = orient_grid(corners[b], board)
        return corners, found

    run.detector = det  # type: ignore[attr-defined]
    return run, ""


def _opencv_saddle_method() -> Callable:
    from ccs_kornia.modules.detection.saddle_refine import CornerRefiner
    from ccs_kornia.modules.detection.opencv_detector import OpenCVChessboardDetector

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


# ----------------------------------------------------------------------------------------------
# solvers
# ----------------------------------------------------------------------------------------------

_CV2_FLAGS = {
    "opencv5": 0,
    "k1k2": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    "none": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
}


def cv2_calibrate(
    corners: np.ndarray, found: np.ndarray, board: tuple[int, int], square: float, image_size: tuple[int, int],
    model: str = "opencv5",
) -> dict:
    """``cv2.calibrateCamera`` on the found views of one camera.

    Args:
        corners: :math:`(V, N, 2)` pixels.
        found: :math:`(V,)` bool.
        model: ``opencv5`` (flags 0), ``k1k2`` (ZERO_TANGENT_DIST + FIX_K3) or ``none``.

    Returns:
        ``{"success", "K" (3,3), "dist", "rms", "views"}`` (K NaN on failure).
    """
    obj = board_object_points(board[0], board[1], square, dtype=torch.float64).numpy().astype(np.float32)
    idx = np.nonzero(found)[0]
    fail = {"success": False, "K": np.full((3, 3), np.nan), "dist": None, "rms": float("nan"), "views": int(len(idx))}
    if len(idx) < 3:
        return fail
    img_pts = [corners[i].reshape(-1, 1, 2).astype(np.float32) for i in idx]
    try:
        rms, K, dist, _, _ = cv2.calibrateCamera([obj] * len(idx), img_pts, tuple(int(s) for s in image_size), None, None,
                                                 flags=_CV2_FLAGS[model])
    except cv2.error:
        return fail
    ok = bool(np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0)
    return {"success": ok, "K": K if ok else fail["K"], "dist": dist.ravel().tolist(), "rms": float(rms), "views": int(len(idx))}


def ccs_calibrate(
    corners: np.ndarray, found: np.ndarray, board: tuple[int, int], square: float, image_size: tuple[int, int],
    model: str = "opencv5", device: str = "cpu",
) -> dict:
    """:class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`, batched over cameras (trials).

    Args:
        corners: :math:`(C, V, N, 2)` pixels.
        found: :math:`(C, V)` bool.

    Returns:
        ``{"success" (C,), "K" (C,3,3), "rms" (C,), "views" (C,) used views}`` as numpy arrays.
    """
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    c = torch.as_tensor(corners, dtype=torch.float64, device=device)
    f = torch.as_tensor(found, dtype=torch.bool, device=device)
    valid = f[..., None].expand(c.shape[:-1])
    obj = board_object_points(board[0], board[1], square, dtype=torch.float64, device=device)
    with torch.inference_mode():
        res = CalibrationSolver(model=model)(c, valid, obj, image_size)
    return {
        "success": res.success.cpu().numpy(),
        "K": res.K.cpu().numpy(),
        "rms": res.rms.cpu().numpy(),
        "views": res.used.sum(-1).cpu().numpy(),
    }


# ----------------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------------


def summary(values, prefix: str = "") -> dict:
    """``mean, median, p95, std, var, min, max, n`` of the finite values (None when there are none)."""
    a = np.asarray([v for v in np.ravel(values) if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    keys = ("mean", "median", "p95", "std", "var", "min", "max")
    if a.size == 0:
        return {**{prefix + k: None for k in keys}, prefix + "n": 0}
    vals = (a.mean(), np.median(a), np.percentile(a, 95), a.std(), a.var(), a.min(), a.max())
    return {**{prefix + k: float(v) for k, v in zip(keys, vals)}, prefix + "n": int(a.size)}


class Timer:
    """Context manager measuring wall seconds: ``with Timer() as t: ...; t.seconds``."""

    def __enter__(self) -> Timer:
        self._t = time.perf_counter()
        self.seconds = math.nan
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self._t
