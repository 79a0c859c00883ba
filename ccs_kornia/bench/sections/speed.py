"""Section 5: speed, side by side in one run.

* detection images/s of every method at each batch size (the OpenCV peers work image by image whatever
  the batch; the ccs_kornia OpenCV-based detector spreads a batch over threads; the learned detector runs
  the network on the whole batch);
* whole calibration images/s: detection plus solver on one ``calib_views``-view set (ccs_kornia: its
  detector and batched solver; OpenCV: classic + cornerSubPix and ``calibrateCamera``);
* calibrations/s of the solver alone, ccs_kornia batched over ``C`` cameras against a loop of
  ``cv2.calibrateCamera``, on the same noisy corners (0.1 px);
* peak memory: the process's peak resident set size (CPU) and ``torch.cuda.max_memory_allocated`` (GPU);
* the limit (CPU, :mod:`ccs_kornia.bench.sections.floors`): FLOPs per image of the heatmap UNet (at the detection levels
  scale selection picks for these images, and at full resolution) and of the DistortionNet, the machine's GFLOP/s
  on a plain channels-last convolution stack measured in the same run (float32 and bfloat16), hence each network's
  floor time; the learned detector's per-stage time per image at batch 16 and 1; the per-stage profile of the
  default path (``CalibrationPipeline``, learned detector, correction on) on the calibration views written as PNG
  files; and, where the real set ``speed_real_set`` is present, ``python -m ccs_kornia calibrate`` on it end to end
  in a fresh interpreter.

CUDA timings run only when CUDA is present (learned detector and solver; the OpenCV peers are CPU-only).
Best of ``speed_repeats`` runs after one warm-up.
"""

from __future__ import annotations

import resource
import sys
import time

import numpy as np
import torch

from ccs_kornia.bench.common import ccs_calibrate, cv2_calibrate, distortion_available
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.methods import DetectionMethod
from ccs_kornia.bench.scenes.scenes import render_scenes
from ccs_kornia.geometry.models.factory import OPENCV5

__all__ = ["run_speed", "peak_rss_mb"]


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MiB."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


#: least time over which each solver is timed (its best call kept)
SOLVER_SECONDS = 0.5


def _best(fn, repeats: int, device: str = "cpu", min_seconds: float = 0.0, max_repeats: int = 50) -> float:
    """Best time of ``fn`` after a warm-up: ``repeats`` runs, more (up to ``max_repeats``) until ``min_seconds`` were
    timed (calls of a few ms, such as one camera's solve, vary by a third between runs on a shared machine)."""
    fn()
    if device == "cuda":
        torch.cuda.synchronize()
    best, total, runs = float("inf"), 0.0, 0
    while runs < max(1, repeats) or (total < min_seconds and runs < max_repeats):
        t = time.perf_counter()
        fn()
        if device == "cuda":
            torch.cuda.synchronize()
        elapsed = time.perf_counter() - t
        best, total, runs = min(best, elapsed), total + elapsed, runs + 1
    return best


def run_speed(cfg: BenchConfig, methods: dict[str, DetectionMethod], log=print) -> dict:
    """Run the speed section; returns a dict of timings per device."""
    n_views = max(cfg.speed_images, cfg.calib_views)
    scenes = render_scenes(cfg, "clean", 1, n_views, "speed")
    images = scenes.flat_images
    det_images = images[: cfg.speed_images]
    import os

    out: dict = {"threads": torch.get_num_threads(), "images": int(det_images.shape[0]), "load_average_start": _load(),
                 "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
                 "calibration_views": cfg.calib_views, "devices": {}}
    devices = [d for d in cfg.devices if d == "cpu" or (d == "cuda" and torch.cuda.is_available())]
    out["skipped_devices"] = {d: "CUDA not available" for d in cfg.devices if d not in devices}
    for device in devices:
        res: dict = {"detection": {}, "calibration": {}, "solver": {}}
        # detection
        for key, m in methods.items():
            if not m.available:
                continue
            if device == "cuda" and key != "learned":
                continue
            run_images = det_images.to(device)
            per_batch = {}
            for bs in sorted({min(b, run_images.shape[0]) for b in cfg.speed_batch_sizes}):
                # the learned detector at the timed batch size (its method otherwise splits calls into the bench's
                # batches of cfg.learned_batch, and a "batch 16" column would time two calls of 8)
                options = {"batch": bs} if key.startswith("learned") else {}

                def go(m=m, bs=bs, options=options):
                    for i in range(0, run_images.shape[0], bs):
                        m.detect(run_images[i : i + bs], cfg.board, **options)
                sec = _best(go, cfg.speed_repeats, device)
                per_batch[str(bs)] = run_images.shape[0] / sec
            res["detection"][key] = {"label": m.label, "images_per_s": per_batch}
            log(f"[speed] {device} detect {m.label:30s} " + "  ".join(f"b{b}: {v:.1f} img/s" for b, v in per_batch.items()))
            if device == "cpu" and key == "learned":
                res["detection"][key]["workers"] = _detect_in_workers(m, run_images, cfg, log)
        # whole calibration (detect + solve) on one set of views
        views = images[: cfg.calib_views]
        ccs_key = "learned" if "learned" in methods and methods["learned"].available else "opencv_saddle"
        pairs = [(f"ccs_kornia ({methods[ccs_key].label})", ccs_key, "ccs")] if ccs_key in methods else []
        if device == "cpu" and "opencv_subpix" in methods:
            pairs.append(("OpenCV (classic+cornerSubPix, calibrateCamera)", "opencv_subpix", "opencv"))
        for label, key, solver in pairs:
            m = methods[key]

            def whole(m=m, solver=solver):
                c, f = m.detect(views.to(device), cfg.board)
                if solver == "ccs":
                    ccs_calibrate(c[None], f[None], cfg.board, cfg.square, cfg.image_size, OPENCV5, device)
                else:
                    cv2_calibrate(c, f, cfg.board, cfg.square, cfg.image_size, OPENCV5)
            sec = _best(whole, cfg.speed_repeats, device)
            res["calibration"][label] = {"images_per_s": views.shape[0] / sec, "seconds": sec}
            log(f"[speed] {device} whole calibration {label}: {views.shape[0] / sec:.2f} img/s ({sec:.2f} s)")
        # the whole product path: CalibrationPipeline with the distortion correction (its default)
        net, why = distortion_available(cfg.distortion_weights)
        if net is not None and ccs_key == "learned":
            from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

            pipe = CalibrationPipeline("learned", distortion_correction=net).to(device)
            sec = _best(lambda: pipe(views.to(device), cfg.board, cfg.square), cfg.speed_repeats, device)
            label = "ccs_kornia CalibrationPipeline (learned + distortion correction)"
            res["calibration"][label] = {"images_per_s": views.shape[0] / sec, "seconds": sec}
            log(f"[speed] {device} whole calibration {label}: {views.shape[0] / sec:.2f} img/s ({sec:.2f} s)")
        # solver alone
        g = torch.Generator().manual_seed(1)
        truth = scenes.corners[0, : cfg.calib_views].numpy()
        found1 = np.ones(truth.shape[0], dtype=bool)
        for C in cfg.speed_solver_cameras:
            noisy = truth[None] + 0.1 * torch.randn((C, *truth.shape), generator=g, dtype=torch.float64).numpy()
            found = np.ones(noisy.shape[:2], dtype=bool)
            # both solvers timed for at least SOLVER_SECONDS (one camera: 10-15 ms a call)
            t_ccs = _best(lambda: ccs_calibrate(noisy, found, cfg.board, cfg.square, cfg.image_size, OPENCV5, device),
                          cfg.speed_repeats, device, SOLVER_SECONDS)
            entry = {"ccs_calibrations_per_s": C / t_ccs}
            if device == "cpu":
                t_cv = _best(lambda: [cv2_calibrate(noisy[i], found1, cfg.board, cfg.square, cfg.image_size, OPENCV5)
                                      for i in range(C)], cfg.speed_repeats, "cpu", SOLVER_SECONDS)
                entry["opencv_calibrations_per_s"] = C / t_cv
            res["solver"][str(C)] = entry
            log(f"[speed] {device} solver C={C}: ccs {entry['ccs_calibrations_per_s']:.1f}/s"
                + (f", cv2 {entry['opencv_calibrations_per_s']:.1f}/s" if "opencv_calibrations_per_s" in entry else ""))
        if device == "cpu" and ccs_key == "learned":
            res["limit"] = _limit(cfg, det_images, views, log)
        res["peak_memory_mb"] = peak_rss_mb() if device == "cpu" else torch.cuda.max_memory_allocated() / 2**20
        out["devices"][device] = res
    out["load_average_end"] = _load()
    return out


def _detect_in_workers(m: DetectionMethod, images: torch.Tensor, cfg: BenchConfig, log) -> dict:
    """Images/s of the detector in the worker processes a folder gets (``calibrate --jobs auto``: one per core, batches
    of the command line's size), the processes' start included."""
    from ccs_kornia.bench.sections.floors import CLI_BATCH_SIZE
    from ccs_kornia.pipeline.sources import TensorSource
    from ccs_kornia.pipeline.workers import default_workers, map_batches

    # (fewer when the images make fewer batches)
    workers = min(default_workers("cpu"), -(-images.shape[0] // CLI_BATCH_SIZE))
    source = TensorSource(images)
    def detect(x: torch.Tensor, keys: list) -> tuple:  # each worker's batch in one call, as calibrate's
        return m.detect(x, cfg.board, batch=CLI_BATCH_SIZE)

    sec = _best(lambda: list(map_batches(detect, source, None, CLI_BATCH_SIZE, None, workers)), cfg.speed_repeats,
                "cpu")
    log(f"[speed] cpu detect {m.label}: {images.shape[0] / sec:.1f} img/s in {workers} worker process(es), batches of "
        f"{CLI_BATCH_SIZE}")
    return {"processes": workers, "batch": CLI_BATCH_SIZE, "images_per_s": images.shape[0] / sec}


def _limit(cfg: BenchConfig, det_images: torch.Tensor, views: torch.Tensor, log) -> dict:
    """Floors, the detector's and the default path's per-stage profiles, and the real set end to end."""
    from ccs_kornia.bench.sections.floors import (
        compute_floors,
        conv_rate,
        end_to_end,
        profile_default_path,
        profile_detector,
    )
    from ccs_kornia.modules.detection.learned.heatmap_unet import cpu_has_native_bf16

    rates = {"float32": conv_rate(repeats=cfg.speed_repeats + 1)["gflops"]}
    if cpu_has_native_bf16():
        rates["bfloat16"] = conv_rate(repeats=cfg.speed_repeats + 1, dtype=torch.bfloat16)["gflops"]
    out: dict = {"floors": compute_floors(det_images, rates)}
    log("[speed] conv rate " + ", ".join(f"{k} {v:.1f} GFLOP/s" for k, v in rates.items())
        + f"; UNet {out['floors']['gflop_per_image']['unet_level']:.2f} GFLOP/img at the detection levels")
    out["detector"] = profile_detector(det_images, cfg.board, tuple(sorted(set(cfg.speed_batch_sizes), reverse=True)),
                                       cfg.speed_repeats)
    net, why = distortion_available(cfg.distortion_weights)
    out["pipeline"] = profile_default_path(views, cfg.board, cfg.square, cfg.speed_repeats,
                                           distortion_weights=net if net is not None else False)
    pl = out["pipeline"]
    log(f"[speed] default path on {views.shape[0]} PNG files: {pl['wall_s']:.2f} s with {pl['workers']} process(es), "
        f"{pl['serial_wall_s']:.2f} s in one")
    if cfg.speed_real_set:
        from pathlib import Path

        from ccs_kornia.bench.sections.real import REAL_SETS, default_real_dir

        folder = Path(cfg.real_dir or default_real_dir()) / cfg.speed_real_set
        if folder.is_dir() and cfg.speed_real_set in REAL_SETS:
            out["end_to_end"] = {"set": cfg.speed_real_set, **end_to_end(str(folder), REAL_SETS[cfg.speed_real_set]["board"])}
            log(f"[speed] {cfg.speed_real_set} end to end: {out['end_to_end']['wall_s']:.2f} s")
        else:
            out["end_to_end"] = {"set": cfg.speed_real_set, "skipped": f"{folder} not found"}
    return out


def _load() -> float | None:
    """1-minute load average: timings taken while other processes use the cores are not comparable."""
    try:
        import os

        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return None
