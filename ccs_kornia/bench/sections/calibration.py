"""Section 2: calibration accuracy on rendered sets with known intrinsics (paper Table I).

Per condition, ``calib_trials`` trials of ``calib_views`` views. Each random camera gets a pool of
``calib_pool_views`` rendered views and ``calib_trials_per_camera`` trials drawn from it (random subsets;
with ``pool == views`` and one trial per camera every trial is independent). Every detection method's
corners go to both solvers: ccs_kornia's batched :class:`CalibrationSolver` (all trials in one call) and
``cv2.calibrateCamera`` (flags 0), both with the 5-coefficient OpenCV model. ``truth`` feeds the exact
corners, the floor set by the solver and the model alone.

Metrics (paper): ``E_FL = |fx - fx*| + |fy - fy*|``, ``E_PP = |cx - cx*| + |cy - cy*|``,
``E_IP = (E_FL + E_PP) / 2`` and its variance over trials, RMS reprojection error (px). Failed trials (fewer
than 3 boards found, or the solver failed) are counted, not averaged.

Note on ``level2``: its ``k0`` in ``[0.8, 1.2]`` scales the image about its centre, which no lens model
can tell from a change of focal length; every method that does not learn ``k0`` from image content carries
about ``|k0 - 1| (fx + fy)`` in ``E_FL``. For such conditions ``e_ip_k0`` also scores the result against the
``k0``-scaled camera (:func:`~ccs_kornia.bench.common.k0_scaled_intrinsics`), which is what the images show. The paper's radial model
is centred on the image centre, not the principal point, and is not exactly an OpenCV model either: the
``exact corners`` row shows that floor.
"""

from __future__ import annotations

import numpy as np
import torch

from ccs_kornia.bench.common import (
    Timer,
    calibration_metrics,
    ccs_calibrate,
    cv2_calibrate,
    distortion_available,
    format_metric,
    k0_scaled_intrinsics,
)
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.methods import DetectionMethod
from ccs_kornia.bench.scenes.scenes import render_scenes
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.pipeline.sources import TensorSource

__all__ = ["run_calibration"]


def _trial_subsets(cfg: BenchConfig, cameras: int, per_camera: int, cond_index: int) -> np.ndarray:
    """``(T, 2 + views)`` rows ``camera, trial, view indices``."""
    rng = np.random.default_rng(BENCH_SEED_BASE + 7 * cond_index + 1)
    rows = []
    for t in range(cfg.calib_trials):
        c = t // per_camera
        if cfg.calib_pool_views == cfg.calib_views:
            views = np.arange(cfg.calib_views)
        else:
            views = np.sort(rng.choice(cfg.calib_pool_views, cfg.calib_views, replace=False))
        rows.append(np.concatenate([[c, t], views]))
    return np.asarray(rows, dtype=np.int64)


def run_calibration(cfg: BenchConfig, methods: dict[str, DetectionMethod], device: str = "cpu", log=print) -> dict:
    """Run the synthetic calibration section; returns ``{"conditions": {cond: {method: {solver: metrics}}}}``."""
    if cfg.calib_pool_views < cfg.calib_views:
        raise ValueError("calib_pool_views must be >= calib_views.")
    per_camera = max(1, int(cfg.calib_trials_per_camera))
    cameras = -(-cfg.calib_trials // per_camera)
    keys = [k for k in (cfg.calib_methods or tuple(methods)) if k in methods and methods[k].available]
    out: dict = {
        "trials": cfg.calib_trials, "views": cfg.calib_views, "pool_views": cfg.calib_pool_views,
        "trials_per_camera": per_camera, "cameras": cameras, "model": str(OPENCV5), "methods": keys, "conditions": {},
        "not_in_section": [methods[k].label for k in methods if methods[k].available and k not in keys],
    }
    for ci, cond in enumerate(cfg.calib_conditions):
        scenes = render_scenes(cfg, cond, cameras, cfg.calib_pool_views, "calibration")
        log(f"[calibration] {cond}: {cameras}x{cfg.calib_pool_views} views rendered in {scenes.render_seconds:.1f}s")
        sub = _trial_subsets(cfg, cameras, per_camera, ci)
        cam, views = sub[:, 0], sub[:, 2:]
        K_true = scenes.K[cam].numpy()
        radial = scenes.radial[cam].double().numpy()
        # only where k0 != 1 (level2) does the scaled camera differ from the true one
        K_scaled = k0_scaled_intrinsics(K_true, radial, cfg.image_size) if bool((radial[:, 0] != 1).any()) else None
        res: dict = {}
        pool_images = scenes.flat_images
        corrector = _corrector(cfg, device) if "learned" in keys else None
        pool_out = None
        if corrector is not None:
            # the product path (CalibrationPipeline: network, detection, second look) once over each camera's pool;
            # every trial then runs the rest of the pipeline on its views (take_views + finish)
            with Timer() as t_net:
                h, w = pool_images.shape[-2:]
                pool_out = corrector.run(TensorSource(pool_images.reshape(cameras, cfg.calib_pool_views, 1, h, w)),
                                         cfg.board, cfg.square, calibrate=False)
            log(f"[calibration] {cond}: pipeline detection on {pool_images.shape[0]} views ({t_net.seconds:.1f}s)")
        detections: dict[str, tuple[np.ndarray, np.ndarray]] = {
            "truth": (scenes.corners.numpy(), np.ones(scenes.corners.shape[:2], dtype=bool)),
        }
        for key in keys:
            with Timer() as t:
                c, f = methods[key].detect(pool_images, cfg.board)
            n = cfg.calib_pool_views
            detections[key] = (c.reshape(cameras, n, *c.shape[1:]), f.reshape(cameras, n))
            log(f"[calibration] {cond}: {methods[key].label} found {int(f.sum())}/{f.size} ({t.seconds:.1f}s)")
        for key, (pool_c, pool_f) in detections.items():
            corners = pool_c[cam[:, None], views]  # (T, V, N, 2)
            found = pool_f[cam[:, None], views]  # (T, V)
            with Timer() as t_ccs:
                r = ccs_calibrate(corners, found, cfg.board, cfg.square, cfg.image_size, OPENCV5, device)
            ccs = calibration_metrics(r["K"], K_true, r["success"], r["rms"], r["views"], K_scaled)
            ccs["seconds"] = t_ccs.seconds
            with Timer() as t_cv:
                cv = [cv2_calibrate(corners[i], found[i], cfg.board, cfg.square, cfg.image_size, OPENCV5)
                      for i in range(len(sub))]
            cvm = calibration_metrics(
                np.stack([d["K"] for d in cv]), K_true, np.array([d["success"] for d in cv]),
                np.array([d["rms"] for d in cv]), np.array([d["views"] for d in cv]), K_scaled,
            )
            cvm["seconds"] = t_cv.seconds
            label = "exact corners" if key == "truth" else methods[key].label
            res[key] = {"label": label, "boards_found": float(found.mean()), "ccs": ccs, "opencv": cvm}
            if key == "learned" and pool_out is not None:
                with Timer() as t_dc:
                    done = corrector.finish(pool_out.take_views(torch.as_tensor(cam), torch.as_tensor(views)),
                                            cfg.board, cfg.square)
                    cal, applied = done.calibration, done.corrected
                dc = calibration_metrics(cal.K.cpu().numpy(), K_true, cal.success.cpu().numpy(), cal.rms.cpu().numpy(),
                                         cal.used.sum(-1).cpu().numpy(), K_scaled)
                dc["seconds"] = t_dc.seconds
                dc["correction_applied"] = int(applied.sum())
                res[key]["ccs_corrected"] = dc
                log(f"[calibration] {cond:12s} {label:30s} E_IP ccs + distortion correction "
                    f"{format_metric(dc['e_ip'])} (applied on {int(applied.sum())}/{len(sub)})")
                # the command line's default: the same path with the model chosen per trial (--model auto)
                auto_pipe = _corrector(cfg, device, model=ModelChoice())
                with Timer() as t_auto:
                    done = auto_pipe.finish(pool_out.take_views(torch.as_tensor(cam), torch.as_tensor(views)),
                                            cfg.board, cfg.square)
                    cal = done.calibration
                auto = calibration_metrics(cal.K.cpu().numpy(), K_true, cal.success.cpu().numpy(),
                                           cal.rms.cpu().numpy(), cal.used.sum(-1).cpu().numpy(), K_scaled)
                auto["seconds"] = t_auto.seconds
                chosen = [s["chosen"] for s in done.model_selection if s and s["chosen"]]
                auto["models"] = {m: chosen.count(m) for m in sorted(set(chosen))}
                res[key]["ccs_auto"] = auto
                log(f"[calibration] {cond:12s} {label:30s} E_IP ccs+dc --model auto {format_metric(auto['e_ip'])} "
                    f"(chosen {auto['models']})")
            log(f"[calibration] {cond:12s} {label:30s} E_IP ccs {format_metric(ccs['e_ip'])} "
                f"/ cv2 {format_metric(cvm['e_ip'])}")
        out["conditions"][cond] = res
    return out


def _corrector(cfg: BenchConfig, device: str, model: CameraModel | ModelChoice = OPENCV5):
    """The pipeline whose corrected solver stage the learned detections go through (None without weights)."""

    net, _ = distortion_available(cfg.distortion_weights)
    if net is None:
        return None
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    return CalibrationPipeline("learned", model=model, distortion_correction=net.to(device)).to(device)
