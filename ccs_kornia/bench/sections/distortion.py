"""Section 4: calibration with and without the learned distortion correction (paper Table IV).

Three parts, all on scenes rendered with benchmark seeds (never used in training):

* **network**: on held-out severely distorted views (farthest image corner moved inwards by 15-25 %), the
  DistortionNet's per-view correction, scored by the grid loss (paper Eq. 1, px, against the scale-normalised
  true distortion; identity and least-squares oracle beside it) and by the straightness of the board's rows and
  columns (RMS distance of the true corners, corrected, from fitted lines; before vs after).
* **severe**: ``dc_trials`` cameras x ``dc_views`` views with severe distortion. ccs_kornia's pipeline with the
  correction on and off (ablation), OpenCV (classic detector + ``cornerSubPix`` + ``calibrateCamera``), and
  OpenCV's detections calibrated by ccs_kornia's corrected solver. E_IP is measured against the camera with
  the distortion's ``k0`` folded in (:func:`~ccs_kornia.bench.common.k0_scaled_intrinsics`): a zoom about
  the centre that no calibration can tell from the focal length.
* **wide**: the paper's wide camera, 480x480, ``fx, fy`` in 100-300 px, distortion level 2: success rate (a
  calibration returned with E_IP under 5 px) and E_IP, same methods.

The rendered distortion is the paper's model, centred on the image centre, which is also where the correction
model centres it; OpenCV's model centres it on the principal point (within 3 % of the image centre here).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from ccs_kornia.bench.common import (
    calibration_metrics,
    cv2_calibrate,
    distortion_available,
    format_metric,
    k0_scaled_intrinsics,
)
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.methods import DetectionMethod
from ccs_kornia.bench.scenes.scenes import Scenes, quantize, render_scenes
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.correction.distortion_net import DEFAULT_DISTORTION_WEIGHTS

__all__ = ["run_distortion", "render_wide_scenes"]


#: success of a wide-camera calibration: a camera returned, and E_IP below this (px)
WIDE_SUCCESS_EIP = 5.0


def render_wide_scenes(cfg: BenchConfig, cameras: int, views: int) -> Scenes:
    """The paper's wide camera: ``cfg.wide_size`` images, ``fx, fy`` in ``cfg.wide_fx``, distortion level 2."""
    from ccs_kornia.data.scenes.sampling import sample_radial_distortion
    from ccs_kornia.data.scenes.scenes import make_calibration_set

    w, h = cfg.wide_size
    base = BENCH_SEED_BASE + 250_000
    gen = torch.Generator().manual_seed(base)
    u = torch.rand(cameras, 4, generator=gen, dtype=torch.float64)
    lo, hi = cfg.wide_fx
    K = torch.zeros(cameras, 3, 3, dtype=torch.float64)
    K[:, 0, 0] = lo + (hi - lo) * u[:, 0]
    K[:, 1, 1] = lo + (hi - lo) * u[:, 1]
    K[:, 0, 2] = (w - 1) / 2 + 0.03 * w * (2 * u[:, 2] - 1)
    K[:, 1, 2] = (h - 1) / 2 + 0.03 * h * (2 * u[:, 3] - 1)
    K[:, 2, 2] = 1.0
    rad = sample_radial_distortion(cameras, "level2", (w, h), gen)
    t0 = time.perf_counter()
    imgs, pts = [], []
    for c in range(cameras):
        batch = make_calibration_set(K[c].float(), cfg.board, cfg.square, (w, h), views, radial=rad[c],
                                     condition="clean", seed=base + 1 + c, supersample=cfg.supersample)
        imgs.append(quantize(batch.images))
        pts.append(batch.corners.double())
    return Scenes(images=torch.stack(imgs), corners=torch.stack(pts), K=K, radial=rad, condition="wide_level2",
                  render_seconds=time.perf_counter() - t0)


def _network_part(pipeline, scenes: Scenes, image_size: tuple[int, int], board: tuple[int, int]) -> dict:
    from ccs_kornia.geometry.radial import fit_radial_correction
    from ccs_kornia.losses.grid_loss import grid_loss, normalize_distortion_scale
    from ccs_kornia.modules.correction.pooling import pool_corrections
    from ccs_kornia.modules.correction.radial_warp import correct_points
    from ccs_kornia.modules.correction.straightness import straightness_rms

    c, v = scenes.images.shape[:2]
    per_view = pipeline.view_corrections(scenes.flat_images)  # (C*V, 5) float64
    truth = normalize_distortion_scale(scenes.radial.double()).repeat_interleave(v, 0)
    ident = torch.zeros_like(per_view)
    ident[:, 0] = 1.0
    oracle = fit_radial_correction(truth, image_size)
    pooled, _ = pool_corrections(per_view.reshape(c, v, 5), image_size, pipeline.settings.min_correction)

    def gl(pred: torch.Tensor) -> float:
        return float(grid_loss(pred.double(), truth, image_size, 16))

    corners = scenes.flat_corners
    valid = torch.ones(corners.shape[:2], dtype=torch.bool)
    before, _ = straightness_rms(corners, valid, board)
    after, _ = straightness_rms(correct_points(corners, per_view, image_size), valid, board)
    after_pooled, _ = straightness_rms(correct_points(corners, pooled.repeat_interleave(v, 0), image_size), valid, board)
    after_oracle, _ = straightness_rms(correct_points(corners, oracle, image_size), valid, board)
    mb, ma = float(before.mean()), float(after.mean())
    return {
        "views": int(c * v),
        "grid_loss": {"network": gl(per_view), "network_pooled": gl(pooled.repeat_interleave(v, 0)),
                      "identity": gl(ident), "oracle": gl(oracle)},
        "straightness_before": mb,
        "straightness_after": ma,
        "straightness_after_pooled": float(after_pooled.mean()),
        "straightness_after_oracle": float(after_oracle.mean()),
        "straightness_reduction": 1.0 - ma / mb if mb > 0 else None,
        "straightness_reduction_pooled": 1.0 - float(after_pooled.mean()) / mb if mb > 0 else None,
    }


def _score(K: np.ndarray, K_ref: np.ndarray, success: np.ndarray, rms: np.ndarray, views: np.ndarray) -> dict:
    m = calibration_metrics(K, K_ref, success, rms, views)
    ip = np.array([np.nan if x is None else x for x in m["e_ip_per_trial"]], dtype=np.float64)
    m["within_5px"] = float(np.mean(np.nan_to_num(ip, nan=np.inf) < WIDE_SUCCESS_EIP))
    return m


def _calibrate_scenes(scenes: Scenes, cfg: BenchConfig, size: tuple[int, int], on, off, cv_method, device, log, tag) -> dict:
    """Run every method on every camera of ``scenes``; metrics against the k0-scaled true cameras."""
    T, V = scenes.images.shape[:2]
    K_ref = k0_scaled_intrinsics(scenes.K.numpy(), scenes.radial.double().numpy(), size)
    rows: dict[str, dict] = {}
    acc: dict[str, dict[str, list]] = {}

    def add(key: str, K, ok, rms, views) -> None:
        d = acc.setdefault(key, {"K": [], "ok": [], "rms": [], "views": []})
        d["K"].append(np.asarray(K, dtype=np.float64))
        d["ok"].append(bool(ok))
        d["rms"].append(float(rms))
        d["views"].append(int(views))

    seconds: dict[str, float] = {"ccs_on": 0.0, "ccs_off": 0.0, "opencv": 0.0, "opencv_ccs_corrected": 0.0}
    applied = 0
    found_on = found_off = found_cv = 0
    for t in range(T):
        imgs = scenes.images[t].to(device)
        t0 = time.perf_counter()
        r_on = on(imgs, cfg.board, cfg.square)
        seconds["ccs_on"] += time.perf_counter() - t0
        applied += int(bool(r_on.corrected))
        found_on += int(r_on.found.sum())
        add("ccs_on", r_on.K.cpu(), r_on.calibration.success, r_on.rms, r_on.used.sum())
        t0 = time.perf_counter()
        r_off = off(imgs, cfg.board, cfg.square)
        seconds["ccs_off"] += time.perf_counter() - t0
        found_off += int(r_off.found.sum())
        add("ccs_off", r_off.K.cpu(), r_off.calibration.success, r_off.rms, r_off.used.sum())
        if cv_method is not None:
            t0 = time.perf_counter()
            c, f = cv_method.detect(scenes.images[t], cfg.board)
            d = cv2_calibrate(c, f, cfg.board, cfg.square, size, OPENCV5)
            seconds["opencv"] += time.perf_counter() - t0
            found_cv += int(f.sum())
            add("opencv", d["K"], d["success"], d["rms"], d["views"])
            # OpenCV's corners through ccs_kornia's corrected solver (the pooled correction of the same views)
            t0 = time.perf_counter()
            cc = torch.as_tensor(c, dtype=torch.float64, device=device)[None]
            ff = torch.as_tensor(f, dtype=torch.bool, device=device)[None]
            if int(ff.sum()) >= 3:
                from ccs_kornia.pipeline.result import PipelineResult

                given = PipelineResult.from_detections(cc, ff, size, on.view_corrections(imgs).reshape(1, V, 5))
                cal = on.finish(given, cfg.board, cfg.square).calibration
                add("opencv_ccs_corrected", cal.K[0].cpu(), cal.success[0], cal.rms[0], cal.used[0].sum())
            else:
                add("opencv_ccs_corrected", np.full((3, 3), np.nan), False, float("nan"), int(ff.sum()))
            seconds["opencv_ccs_corrected"] += time.perf_counter() - t0
    labels = {
        "ccs_on": "ccs_kornia (learned detector, distortion correction on)",
        "ccs_off": "ccs_kornia, correction off (ablation)",
        "opencv": "OpenCV classic + cornerSubPix + calibrateCamera",
        "opencv_ccs_corrected": "OpenCV's corners + ccs_kornia corrected solver",
    }
    found = {"ccs_on": found_on, "ccs_off": found_off, "opencv": found_cv, "opencv_ccs_corrected": found_cv}
    for key, d in acc.items():
        m = _score(np.stack(d["K"]), K_ref, np.array(d["ok"]), np.array(d["rms"]), np.array(d["views"]))
        m.update(label=labels[key], boards_found=found[key] / float(T * V), seconds=seconds[key])
        rows[key] = m
        log(f"[distortion] {tag:6s} {labels[key]:55s} E_IP {format_metric(m['e_ip'])} "
            f"var {format_metric(m['e_ip_var'])} ok {T - m['failures']}/{T} within 5px {m['within_5px']:.2f}")
    return {"trials": T, "views": V, "image_size": list(size), "correction_applied": applied, "methods": rows}


def run_distortion(cfg: BenchConfig, methods: dict[str, DetectionMethod], device: str = "cpu", log=print) -> dict:
    """Run the Table IV section (or report why it cannot run)."""
    net, reason = distortion_available(cfg.distortion_weights)
    if net is None:
        log(f"[distortion] skipped: {reason}")
        return {"skipped": reason}
    from ccs_kornia.modules.detection.factory import make_detector
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    try:
        detector = make_detector("learned")
        detector_name = "learned"
    except Exception as err:  # no shipped detector weights: the OpenCV backend carries the pipeline
        log(f"[distortion] learned detector unavailable ({err}); using the OpenCV backend")
        detector, detector_name = make_detector("opencv"), "opencv"
    on = CalibrationPipeline(detector, distortion_correction=net.to(device)).to(device)
    off = CalibrationPipeline(detector, distortion_correction=False).to(device)
    cv_method = methods.get("opencv_subpix")
    cv_method = cv_method if cv_method is not None and cv_method.available else None
    out: dict = {"detector": detector_name, "weights": str(cfg.distortion_weights or DEFAULT_DISTORTION_WEIGHTS)}

    scenes = render_scenes(cfg, "severe", cfg.dc_trials, cfg.dc_views, "distortion")
    log(f"[distortion] severe: {cfg.dc_trials}x{cfg.dc_views} views rendered in {scenes.render_seconds:.1f}s")
    out["network"] = _network_part(on, scenes, cfg.image_size, cfg.board)
    n = out["network"]
    log(f"[distortion] network: grid loss {n['grid_loss']['network']:.2f} px (identity {n['grid_loss']['identity']:.2f}, "
        f"oracle {n['grid_loss']['oracle']:.2f}); straightness {n['straightness_before']:.3f} -> "
        f"{n['straightness_after']:.3f} px ({100 * (n['straightness_reduction'] or 0):.0f} % less)")
    out["severe"] = _calibrate_scenes(scenes, cfg, cfg.image_size, on, off, cv_method, device, log, "severe")
    if cfg.wide_trials > 0:
        wide = render_wide_scenes(cfg, cfg.wide_trials, cfg.wide_views)
        log(f"[distortion] wide: {cfg.wide_trials}x{cfg.wide_views} views rendered in {wide.render_seconds:.1f}s")
        out["wide"] = _calibrate_scenes(wide, cfg, tuple(cfg.wide_size), on, off, cv_method, device, log, "wide")
        out["wide"]["fx_range"] = list(cfg.wide_fx)
    out["summary"] = {
        "severe_straightness_reduction": n["straightness_reduction"],
        "severe_e_ip": {k: v["e_ip"] for k, v in out["severe"]["methods"].items()},
        "severe_e_ip_var": {k: v["e_ip_var"] for k, v in out["severe"]["methods"].items()},
    }
    return out
