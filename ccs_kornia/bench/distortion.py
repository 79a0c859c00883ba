"""Section 4: calibration with and without the learned distortion correction (paper Table IV).

Views rendered with the paper's Table IV distortion (``k0 = 1, k1 = -0.3, k2 = -0.1`` by default), clean.
For the ccs_kornia detector and OpenCV's classic detector, each with both solvers:

* ``none``: corners of the distorted images, 5-coefficient OpenCV model (the "optimization" row);
* ``cnn_points``: corners of the distorted images, corrected with the DistortionNet's correction (mean of its
  per-view predictions, one lens per camera), then the solver with a residual k1, k2 model;
* ``cnn_image``: the images undistorted with that correction (``zoom`` 0.9 so the corrected board stays in
  the frame), corners detected there and mapped to the zoom-1 corrected frame, k1, k2 model;
* ``oracle_points``: the correction fitted to the true coefficients (:func:`fit_radial_correction`),
  an upper bound for what the network could give.

The corrected frame of the paper's model is the ideal pinhole image of the same ``K``, so every variant is
scored against the true intrinsics. Needs ``modules/distortion_net.py``, ``modules/undistort.py`` and the
network's weights; otherwise the section reports why it was skipped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ccs_kornia.bench.calibration import _fmt, calibration_metrics
from ccs_kornia.bench.common import BenchConfig, DetectionMethod, ccs_calibrate, cv2_calibrate, render_scenes

__all__ = ["DEFAULT_DISTORTION_WEIGHTS", "distortion_available", "run_distortion"]

DEFAULT_DISTORTION_WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "distortion_net.pt"
_ZOOM = 0.9


def distortion_available(weights: str | Path | None = None):
    """``(net, "")`` when the DistortionNet module and its weights load, else ``(None, reason)``."""
    try:
        from ccs_kornia.modules.distortion_net import DistortionNet
        from ccs_kornia.modules import undistort  # noqa: F401
    except ImportError as err:
        return None, f"distortion correction module not available ({err})"
    path = Path(weights) if weights else DEFAULT_DISTORTION_WEIGHTS
    if not path.is_file():
        return None, f"distortion correction weights not available ({path} not found)"
    try:
        return DistortionNet.from_export(path), ""
    except Exception as err:  # a half-written or incompatible export must not stop the other sections
        return None, f"distortion correction weights could not be loaded ({type(err).__name__}: {err})"


def _solve_both(corners, found, cfg, model, K_true, device) -> dict:
    r = ccs_calibrate(corners, found, cfg.board, cfg.square, cfg.image_size, model, device)
    ccs = calibration_metrics(r["K"], K_true, r["success"], r["rms"], r["views"])
    cv = [cv2_calibrate(corners[i], found[i], cfg.board, cfg.square, cfg.image_size, model) for i in range(len(corners))]
    cvm = calibration_metrics(np.stack([d["K"] for d in cv]), K_true, np.array([d["success"] for d in cv]),
                              np.array([d["rms"] for d in cv]), np.array([d["views"] for d in cv]))
    return {"ccs": ccs, "opencv": cvm}


def run_distortion(cfg: BenchConfig, methods: dict[str, DetectionMethod], device: str = "cpu", log=print) -> dict:
    """Run the Table IV section (or report why it cannot run)."""
    net, reason = distortion_available(cfg.distortion_weights)
    if net is None:
        log(f"[distortion] skipped: {reason}")
        return {"skipped": reason}
    from ccs_kornia.camera import fit_radial_correction
    from ccs_kornia.modules.undistort import correct_points, radial_undistort_image

    keys = [k for k in ("learned", "opencv_saddle", "opencv_subpix") if k in methods and methods[k].available]
    if "learned" in keys and "opencv_saddle" in keys:
        keys.remove("opencv_saddle")  # the ccs_kornia detector is the learned one when it is available
    scenes = render_scenes(cfg, "clean", cfg.dc_trials, cfg.dc_views, "distortion", radial=tuple(cfg.dc_radial))
    log(f"[distortion] {cfg.dc_trials}x{cfg.dc_views} views rendered in {scenes.render_seconds:.1f}s")
    T, V = cfg.dc_trials, cfg.dc_views
    w, h = cfg.image_size
    images = scenes.flat_images
    K_true = scenes.K.numpy()
    net = net.to(device)
    with torch.inference_mode():
        pred = torch.cat([net(images[i : i + 16].to(device)).double().cpu() for i in range(0, T * V, 16)])
    corr = pred.reshape(T, V, 5).mean(1)  # one lens per camera
    oracle = fit_radial_correction(scenes.radial.double(), (w, h))
    corrected = radial_undistort_image(images, corr.float().repeat_interleave(V, 0), zoom=_ZOOM).clamp(0, 1)
    corrected = torch.round(corrected * 255.0) / 255.0
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])

    def points(c: np.ndarray, coeffs: torch.Tensor) -> np.ndarray:
        p = torch.as_tensor(c.reshape(T, -1, 2), dtype=torch.float64)
        return correct_points(p, coeffs.double(), (w, h)).numpy().reshape(c.shape)

    out: dict = {"radial": list(cfg.dc_radial), "trials": T, "views": V, "zoom": _ZOOM,
                 "predicted_correction_mean": corr.mean(0).tolist(), "oracle_correction": oracle[0].tolist(), "methods": {}}
    for key in keys:
        m = methods[key]
        c, f = m.detect(images, cfg.board)
        c, f = c.reshape(T, V, *c.shape[1:]), f.reshape(T, V)
        cc, fc = m.detect(corrected, cfg.board)
        cc = ((cc - centre) / _ZOOM + centre).reshape(T, V, *cc.shape[1:])
        fc = fc.reshape(T, V)
        res = {
            "label": m.label,
            "none": _solve_both(c, f, cfg, "opencv5", K_true, device),
            "cnn_points": _solve_both(points(c, corr), f, cfg, "k1k2", K_true, device),
            "cnn_image": _solve_both(cc, fc, cfg, "k1k2", K_true, device),
            "oracle_points": _solve_both(points(c, oracle), f, cfg, "k1k2", K_true, device),
        }
        res["found"] = {"distorted": float(f.mean()), "corrected": float(fc.mean())}
        out["methods"][key] = res
        log(f"[distortion] {m.label:30s} E_IP (ccs solver) none {_fmt(res['none']['ccs']['e_ip'])}, cnn points "
            f"{_fmt(res['cnn_points']['ccs']['e_ip'])}, cnn image {_fmt(res['cnn_image']['ccs']['e_ip'])}, oracle "
            f"{_fmt(res['oracle_points']['ccs']['e_ip'])}")
    return out
