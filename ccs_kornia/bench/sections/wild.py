"""Section ``wild``: detection in the wild, on renders with exact ground truth, board-free
images and rescaled real photos.

*Synthetic conditions* (:data:`WILD_CONDITIONS`, rendered by :class:`ccs_kornia.data.scenes.wild.WildChessboards` from
seeds at ``BENCH_SEED_BASE + 400000``, disjoint from training, validation and the other sections): square sizes
from 8 to 300 px, images from 320x240 to 6000x4000, box / Gaussian / motion blur of 10-30 % of the square,
tilts of 60-75 degrees, glare, shadows, strong noise, JPEG, boards whose outer squares leave the image,
ArUco-like and dot marks in the light squares, Kannala-Brandt fisheyes of 120-200 degrees. Every condition also
gets a realistic optical point spread (0.3-1 px Gaussian), gamma 1.8-2.4 and mild sensor noise. Images are
rendered one at a time (memory-bounded) and quantised to 8 bits.

Per condition and method: *detected* (whole board found with a mean corner error of at most
``max(error_threshold, 5 % of the square)`` under the best lattice ordering), *wrong* (found, but off by more),
mean corner error on the boards each method detected and on the *common* subset every available method
detected, wall time per image and *peak memory per image*: the growth of the process' peak resident set
during the call (``VmHWM`` after resetting it through ``/proc/self/clear_refs``, minus ``VmRSS`` before; a
sampling thread where that file cannot be written), which counts torch, numpy and OpenCV allocations alike.

*Board-free*: ``wild_free_images`` images without a board (:func:`ccs_kornia.data.scenes.distractors.board_free_images`:
clutter, stripes, line grids, tiled floors, bricks, noise, small checker patches); every board reported is false.

*Real photos*: the sets of ``../shared/data/real`` rescaled by ``wild_real_scales`` (area averaging down, bilinear
up); no ground truth, so boards found (and time, memory) are reported.
"""

from __future__ import annotations

import math
import os
import pickle
import select
import signal
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.bench.common import summary
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.methods import DetectionMethod
from ccs_kornia.bench.scenes.scenes import corner_errors, quantize
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE

__all__ = ["WILD_CONDITIONS", "WILD_REAL_SETS", "wild_spec", "PeakMemory", "run_wild"]

_SEED = BENCH_SEED_BASE + 400_000
_BASE = dict(psf_sigma=(0.3, 1.0), gamma=(1.8, 2.4), noise_sigma=(0.0, 0.01), max_tilt_deg=50.0)
#: condition -> (board (cols, rows), WildSpec fields, short description)
WILD_CONDITIONS: dict[str, tuple[tuple[int, int], dict, str]] = {
    "sq8": ((9, 6), dict(image_sizes=((640, 480),), square_px=(8.0, 10.0)), "squares 8-10 px, 640x480"),
    "sq25": ((9, 6), dict(image_sizes=((1280, 960),), square_px=(20.0, 30.0)), "squares 20-30 px, 1280x960"),
    "sq80": ((9, 6), dict(image_sizes=((2592, 1944),), square_px=(60.0, 100.0)), "squares 60-100 px, 2592x1944"),
    "sq300": ((9, 6), dict(image_sizes=((6000, 4000),), square_px=(250.0, 300.0)), "squares 250-300 px, 6000x4000"),
    "img320": ((9, 6), dict(image_sizes=((320, 240),), square_px=(12.0, 20.0)), "320x240, squares 12-20 px"),
    "img6000": ((9, 6), dict(image_sizes=((6000, 4000),), square_px=(40.0, 150.0)), "6000x4000, squares 40-150 px"),
    "box_blur": ((9, 6), dict(image_sizes=((1280, 960),), square_px=(30.0, 80.0), blur=("box",),
                              blur_fraction=(0.1, 0.3)), "box blur 10-30 % of the square"),
    "gauss_blur": ((9, 6), dict(image_sizes=((1280, 960),), square_px=(30.0, 80.0), blur=("gaussian",),
                                blur_fraction=(0.1, 0.3)), "Gaussian blur of the same spread (sigma 3-9 % of the square)"),
    "motion_blur": ((9, 6), dict(image_sizes=((1280, 960),), square_px=(30.0, 80.0), blur=("motion",),
                                 blur_fraction=(0.1, 0.3)), "motion blur 10-30 % of the square"),
    "tilt75": ((9, 6), dict(image_sizes=((1280, 960),), square_px=(25.0, 60.0), min_tilt_deg=60.0, max_tilt_deg=75.0),
               "board tilted 60-75 degrees"),
    "glare": ((9, 6), dict(image_sizes=((640, 480),), square_px=(20.0, 40.0), glare_prob=1.0), "saturating glare"),
    "shadow": ((9, 6), dict(image_sizes=((640, 480),), square_px=(20.0, 40.0), shadow_prob=1.0), "soft shadows"),
    "noise": ((9, 6), dict(image_sizes=((640, 480),), square_px=(20.0, 40.0), noise_sigma=(0.03, 0.06)),
              "sensor noise sigma 0.03-0.06"),
    "jpeg": ((9, 6), dict(image_sizes=((640, 480),), square_px=(15.0, 35.0), jpeg_prob=1.0, jpeg_quality=(10, 35)),
             "JPEG quality 10-35"),
    "cut": ((9, 6), dict(image_sizes=((640, 480),), square_px=(20.0, 40.0), cut_prob=1.0),
            "outer squares cut by the image border"),
    "aruco": ((8, 5), dict(image_sizes=((1280, 960),), square_px=(30.0, 80.0), marks=("aruco",)),
              "ArUco-like marks (ChArUco)"),
    "dots": ((8, 5), dict(image_sizes=((1280, 960),), square_px=(30.0, 80.0), marks=("dots", "tiles")),
             "dot / tile codes (ECoCheck-like)"),
    "fisheye": ((8, 6), dict(image_sizes=((1280, 960),), lenses=("fisheye",), fov_deg=(120.0, 200.0)),
                "Kannala-Brandt fisheye, 120-200 degrees"),
}
#: real sets of ``../shared/data/real`` and their boards (inner corners, cols x rows)
WILD_REAL_SETS: dict[str, tuple[int, int]] = {
    "opencv_left": (9, 6), "boofcv_sony_hx5v": (4, 6), "boofcv_bumblebee2_left": (4, 6),
    "boofcv_bumblebee2_right": (4, 6), "udacity_camera_cal": (9, 6), "udacity_gopro_wide": (8, 6),
    "ros_fisheye_mono": (8, 6), "boofcv_fisheye_chessboard": (6, 4),
}
_BIG = 4_000_000  # pixels from which a condition counts as big (``wild_big_images`` images)


def wild_spec(name: str, supersample: int = 2):
    """The :class:`~ccs_kornia.data.scenes.wild.WildSpec` and board of a condition of :data:`WILD_CONDITIONS`."""
    from ccs_kornia.data.scenes.wild import WildSpec

    if name not in WILD_CONDITIONS:
        raise ValueError(f"Unknown wild condition {name!r}; expected one of {tuple(WILD_CONDITIONS)}.")
    board, fields, _ = WILD_CONDITIONS[name]
    spec = WildSpec(**{**_BASE, "board_cols": (board[0], board[0]), "board_rows": (board[1], board[1]),
                       "supersample": supersample, **fields})
    return spec, board


def _status(key: str) -> int | None:
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _trim() -> None:
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class PeakMemory:
    """Peak growth of the resident set during a ``with`` block, in MiB (``mb``; NaN where unmeasurable).

    First hands the allocator's free memory back to the system (glibc ``malloc_trim``), so memory freed by an
    earlier call is not silently reused and missed; then resets the kernel's high-water mark
    (``/proc/self/clear_refs``), so the peak of this block alone is read from ``VmHWM``; without that file, a
    thread samples ``VmRSS`` every 5 ms.
    """

    method = "malloc_trim, then VmHWM after clear_refs"

    def __enter__(self) -> PeakMemory:
        self.mb = math.nan
        _trim()
        self._rss0 = _status("VmRSS:")
        self._thread = None
        try:
            with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
                fh.write("5")
            self._reset = True
        except OSError:
            self._reset = False
            self._peak, self._stop = self._rss0 or 0, threading.Event()
            self._thread = threading.Thread(target=self._poll, daemon=True)
            self._thread.start()
        return self

    def _poll(self) -> None:
        while not self._stop.is_set():
            self._peak = max(self._peak, _status("VmRSS:") or 0)
            time.sleep(0.005)

    def __exit__(self, *exc) -> None:
        if self._rss0 is None:
            return
        if self._reset:
            peak = _status("VmHWM:")
        else:
            self._stop.set()
            self._thread.join()
            peak = self._peak
        if peak is not None:
            self.mb = max(0.0, (peak - self._rss0) / 2**20)


#: peers run in a forked child with a time limit: libcbdetect dies of SIGFPE on some striped images (its own bug)
#: and OpenCV's classic detector can search for many minutes on a 24 Mpx render; either would stall or end the
#: whole benchmark. A crash or a timeout counts as "no board" and is reported.
_ISOLATE = ("opencv_subpix", "opencv_sb", "libcbdetect")


def _measure(m: DetectionMethod, image: torch.Tensor, board: tuple[int, int]):
    with PeakMemory() as mem:
        t0 = time.perf_counter()
        corners, found = m.detect(image, board)
        secs = time.perf_counter() - t0
    return corners[0], bool(found[0]), secs, mem.mb


def _detect_one(m: DetectionMethod, image: torch.Tensor, board: tuple[int, int], limit: float | None = None):
    """``(corners (N, 2), found, seconds, peak MB, failure)`` of one image; ``failure`` is ``""``, ``"crashed"``
    or ``"timed out"`` (then ``seconds`` is the limit)."""
    if m.key not in _ISOLATE or not hasattr(os, "fork"):
        return (*_measure(m, image, board), "")
    rd, wr = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: measure, send the result, leave without running the parent's exit handlers
        try:
            os.close(rd)
            with os.fdopen(wr, "wb") as fh:
                fh.write(pickle.dumps(_measure(m, image, board)))
        finally:
            os._exit(0)
    os.close(wr)
    chunks, t0, failure = [], time.perf_counter(), ""
    with os.fdopen(rd, "rb") as fh:
        while True:
            wait = None if limit is None else max(0.0, limit - (time.perf_counter() - t0))
            ready, _, _ = select.select([fh], [], [], wait)
            if not ready:
                os.kill(pid, signal.SIGKILL)
                failure = "timed out"
                break
            chunk = os.read(fh.fileno(), 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
    os.waitpid(pid, 0)
    data = b"".join(chunks)
    if failure or not data:
        n = board[0] * board[1]
        return np.zeros((n, 2)), False, (float(limit) if failure else math.nan), math.nan, failure or "crashed"
    return (*pickle.loads(data), "")


def _methods_ok(methods: dict[str, DetectionMethod]) -> dict[str, DetectionMethod]:
    return {k: m for k, m in methods.items() if m.available}


#: a corner counts as visible where the 8-bit image varies by at least this much (of full scale) within a quarter
#: square of it; a saturating glare can flatten both the black and the white squares around a corner to 1
VISIBLE_CONTRAST = 0.05


def corners_visible(image: np.ndarray, corners: np.ndarray, square_px: float) -> np.ndarray:
    """Per corner, whether the image shows it: intensity range at least :data:`VISIBLE_CONTRAST` within
    ``max(2, square_px / 4)`` px of it (a square window; corners outside the image are not visible).

    Args:
        image: :math:`(H, W)` grey image in ``[0, 1]``.
        corners: :math:`(N, 2)` true corners, px.
        square_px: the board's square size in px.

    Returns:
        :math:`(N,)` bool.

    Example:
        >>> img = np.zeros((40, 40)); img[:20, :20] = img[20:, 20:] = 1.0
        >>> corners_visible(img, np.array([[19.5, 19.5], [5.0, 5.0]]), 16.0).tolist()
        [True, False]
    """
    h, w = image.shape
    r = max(2, int(round(square_px / 4)))
    out = np.zeros(len(corners), dtype=bool)
    for k, (x, y) in enumerate(np.asarray(corners, dtype=np.float64)):
        if not (np.isfinite(x) and np.isfinite(y) and 0 <= x < w and 0 <= y < h):
            continue
        xi, yi = int(round(x)), int(round(y))
        patch = image[max(0, yi - r):yi + r + 1, max(0, xi - r):xi + r + 1]
        out[k] = patch.size > 0 and float(patch.max() - patch.min()) >= VISIBLE_CONTRAST
    return out


def _condition(cfg: BenchConfig, name: str, index: int, methods, log) -> dict:
    spec, board = wild_spec(name, cfg.supersample)
    from ccs_kornia.data.scenes.wild import WildChessboards

    scenes = WildChessboards(spec)
    w, h = spec.image_sizes[0]
    n_img = cfg.wild_big_images if w * h >= _BIG else cfg.wild_images
    n = board[0] * board[1]
    per = {k: {"err": np.full(n_img, np.nan), "found": np.zeros(n_img, bool), "ok": np.zeros(n_img, bool),
               "partial": np.zeros(n_img, bool), "sec": np.zeros(n_img), "mb": np.zeros(n_img), "crashes": 0,
               "timeouts": 0} for k in methods}
    squares, render_s = np.zeros(n_img), 0.0
    visible = np.zeros(n_img, bool)
    for i in range(n_img):
        t0 = time.perf_counter()
        batch = scenes.sample(1, torch.Generator().manual_seed(_SEED + 1000 * index + i))
        render_s += time.perf_counter() - t0
        image, truth = quantize(batch.images), batch.corners[0, :n].double().numpy()
        from ccs_kornia.data.render.optics import square_size_px

        squares[i] = float(square_size_px(batch.corners[:, :n].double(), batch.corner_valid[:, :n], batch.board_size)[0])
        limit = max(cfg.error_threshold, 0.05 * squares[i])
        visible[i] = bool(corners_visible(image[0, 0].double().numpy(), truth, squares[i]).all())
        del batch
        for key, m in methods.items():
            corners, found, secs, mb, failure = _detect_one(m, image, board, cfg.wild_time_limit)
            r = per[key]
            r["found"][i], r["sec"][i], r["mb"][i] = found, secs, mb
            r["crashes"] += int(failure == "crashed")
            r["timeouts"] += int(failure == "timed out")
            if found:
                r["partial"][i] = not np.isfinite(corners).all()  # hidden corners (glare, cut) left out
                r["err"][i] = float(np.nanmean(corner_errors(corners, truth, board)))
                r["ok"][i] = r["err"][i] <= limit
    common = np.logical_and.reduce([r["ok"] for r in per.values()]) if per else np.zeros(n_img, bool)
    res: dict = {}
    for key, r in per.items():
        good = r["err"][r["ok"]]
        res[key] = {
            "label": methods[key].label, "images": n_img, "found": int(r["found"].sum()), "detected": int(r["ok"].sum()),
            "detection_rate": float(r["ok"].mean()) if n_img else None,
            "detected_visible": int((r["ok"] & visible).sum()),
            "partial_boards": int((r["ok"] & r["partial"]).sum()),
            "wrong_boards": int((r["found"] & ~r["ok"]).sum()),
            "mean_px": summary(good)["mean"], "median_px": summary(good)["median"],
            "mean_common_px": summary(r["err"][common])["mean"], "common_images": int(common.sum()),
            "seconds_per_image": float(np.nanmean(r["sec"])) if np.isfinite(r["sec"]).any() else None,
            "peak_mb_per_image": float(np.nanmean(r["mb"])) if n_img and np.isfinite(r["mb"]).any() else None,
            "crashes": r["crashes"], "timeouts": r["timeouts"],
            "peak_mb_max": float(np.nanmax(r["mb"])) if n_img and np.isfinite(r["mb"]).any() else None,
        }
        log(f"[wild] {name:12s} {methods[key].label:30s} detected {int(r['ok'].sum())}/{n_img} wrong "
            f"{res[key]['wrong_boards']} mean {_fmt(res[key]['mean_px'])} px  {res[key]['seconds_per_image']:.2f} s/img "
            f"{_fmt(res[key]['peak_mb_per_image'], 0)} MB")
    return {"description": WILD_CONDITIONS[name][2], "board": list(board), "image_size": [w, h],
            "square_px": {"min": float(squares.min()), "max": float(squares.max())} if n_img else None,
            "render_seconds": render_s, "visible_images": int(visible.sum()), "methods": res}


def _board_free(cfg: BenchConfig, methods, log) -> dict:
    from ccs_kornia.data.scenes.distractors import DISTRACTOR_KINDS, board_free_images

    n = int(cfg.wild_free_images)
    boards = ((9, 6), (7, 5))  # patches hold at most 3 x 2 inner corners: no sub-board of either
    out: dict = {"images": n, "boards_searched": [list(b) for b in boards], "kinds": {}, "methods": {}}
    if n < 1:
        return out
    counts = {k: {"false_boards": 0, "seconds": 0.0, "by_kind": {}, "crashes": 0, "timeouts": 0} for k in methods}
    g = torch.Generator().manual_seed(_SEED + 900_000)
    per_call = len(DISTRACTOR_KINDS)
    done = 0
    while done < n:
        m_img = min(per_call, n - done)
        size = (640, 480) if (done // per_call) % 2 == 0 else (1280, 960)
        images, kinds = board_free_images(m_img, size, g)
        images = quantize(images)
        for j in range(m_img):
            board = boards[(done + j) % len(boards)]
            out["kinds"][kinds[j]] = out["kinds"].get(kinds[j], 0) + 1
            for key, m in methods.items():
                _, found, secs, _, failure = _detect_one(m, images[j:j + 1], board, cfg.wild_time_limit)
                c = counts[key]
                c["seconds"] += 0.0 if math.isnan(secs) else secs
                c["crashes"] += int(failure == "crashed")
                c["timeouts"] += int(failure == "timed out")
                if found:
                    c["false_boards"] += 1
                    c["by_kind"][kinds[j]] = c["by_kind"].get(kinds[j], 0) + 1
        done += m_img
    for key, c in counts.items():
        out["methods"][key] = {"label": methods[key].label, "false_boards": c["false_boards"], "by_kind": c["by_kind"],
                               "seconds_per_image": c["seconds"] / n, "crashes": c["crashes"], "timeouts": c["timeouts"]}
        log(f"[wild] board-free   {methods[key].label:30s} false boards {c['false_boards']}/{n}")
    return out


def _real(cfg: BenchConfig, methods, log) -> dict:
    from ccs_kornia.bench.sections.real import default_real_dir, load_real_set

    root = Path(cfg.real_dir) if cfg.real_dir else default_real_dir()
    out: dict = {"root": str(root), "scales": list(cfg.wild_real_scales), "sets": {}, "skipped": {}}
    if not root.is_dir():
        out["skipped"]["*"] = f"real data folder not found: {root}"
        log(f"[wild] real photos skipped: {root} not found")
        return out
    names = cfg.wild_real_sets if cfg.wild_real_sets is not None else tuple(WILD_REAL_SETS)
    for name in names:
        if name not in WILD_REAL_SETS:
            out["skipped"][name] = "unknown set (board size not recorded)"
            continue
        if not (root / name).is_dir():
            out["skipped"][name] = f"not found in {root}"
            continue
        board = WILD_REAL_SETS[name]
        images, files, size = load_real_set(root / name)
        images = images / 255.0 if float(images.max()) > 1.5 else images
        k = len(files) if cfg.wild_real_images is None else min(len(files), int(cfg.wild_real_images))
        pick = np.unique(((np.arange(k) + 0.5) * len(files) / k).astype(int))  # evenly spread, centred
        entry: dict = {"board": list(board), "image_size": list(size), "images": int(len(pick)), "scales": {}}
        for s in cfg.wild_real_scales:
            res = {key: {"label": m.label, "found": 0, "sec": [], "mb": [], "crashes": 0, "timeouts": 0}
                   for key, m in methods.items()}
            for i in pick:
                a = images[i, 0].numpy()
                interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
                x = cv2.resize(a, None, fx=float(s), fy=float(s), interpolation=interp)
                x = quantize(torch.from_numpy(np.ascontiguousarray(x))[None, None].float())
                for key, m in methods.items():
                    _, found, secs, mb, failure = _detect_one(m, x, board, cfg.wild_time_limit)
                    r = res[key]
                    r["found"] += int(found)
                    r["crashes"] += int(failure == "crashed")
                    r["timeouts"] += int(failure == "timed out")
                    r["sec"].append(secs)
                    r["mb"].append(mb)
            entry["scales"][f"{s:g}"] = {
                key: {"label": r["label"], "found": r["found"], "crashes": r["crashes"], "timeouts": r["timeouts"],
                      "seconds_per_image": float(np.nanmean(r["sec"])) if np.isfinite(r["sec"]).any() else None,
                      "peak_mb_per_image": float(np.nanmean(r["mb"])) if np.isfinite(r["mb"]).any() else None}
                for key, r in res.items()
            }
            log(f"[wild] real {name:26s} x{s:g}: " + ", ".join(
                f"{methods[k].label} {r['found']}/{len(pick)}" for k, r in res.items()))
        out["sets"][name] = entry
    return out


def _fmt(x, digits: int = 3) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def run_wild(cfg: BenchConfig, methods: dict[str, DetectionMethod], log=print) -> dict:
    """Run the ``wild`` section; returns ``{"conditions": ..., "board_free": ..., "real": ...}``."""
    ms = _methods_ok(methods)
    if cfg.wild_methods is not None:
        ms = {k: m for k, m in ms.items() if k in cfg.wild_methods}
    names = cfg.wild_conditions if cfg.wild_conditions is not None else tuple(WILD_CONDITIONS)
    out: dict = {"memory": PeakMemory.method, "threshold_px": cfg.error_threshold, "time_limit_s": cfg.wild_time_limit,
                 "isolated": list(_ISOLATE), "conditions": {}}
    for name in names:
        index = tuple(WILD_CONDITIONS).index(name) if name in WILD_CONDITIONS else -1
        out["conditions"][name] = _condition(cfg, name, index, ms, log)
    out["board_free"] = _board_free(cfg, ms, log)
    out["real"] = _real(cfg, ms, log) if cfg.wild_real_scales else {"skipped": {"*": "no scales configured"}}
    return out
