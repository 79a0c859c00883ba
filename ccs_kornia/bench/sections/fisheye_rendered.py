"""Section 7, rendered part: every method calibrates a fisheye from its *own* corners on rendered images.

``fisheye_trials`` Kannala-Brandt cameras (the synthetic part's camera and pose distribution, seeds of their own)
x ``fisheye_views`` views rendered through the exact lens (:func:`~ccs_kornia.bench.scenes.fisheye_data.render_kb_views`:
point spread, gamma, read noise, 8 bits). Methods:

* **ccs_kornia**: the product path, :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` with the learned detector,
  once with ``model=FISHEYE`` (a user who names the lens, ``--model fisheye``) and once with ``model=ModelChoice()``
  (the default, ``--model auto``);
* **cv2.fisheye.calibrate** on OpenCV's classic corners (``findChessboardCorners`` + ``cornerSubPix``, window
  0.45 spacing) and on SB's (``findChessboardCornersSB``), run as ROS users do
  (:func:`~ccs_kornia.bench.methods.fisheye_opencv.opencv_fisheye`).

A calibration fails when fewer than 3 boards are found, the solver raises or returns non-finite values, or E_IP
exceeds ``fisheye_fail_px``; E_IP statistics are over each method's successful trials (and, for a fair
comparison, over the trials where every method succeeded).
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from ccs_kornia.bench.common import Timer, e_ip_px, summary
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.fisheye_opencv import opencv_fisheye
from ccs_kornia.bench.scenes.fisheye_data import (
    random_board_views,
    random_kb_cameras,
    render_kb_views,
)
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models.factory import FISHEYE
from ccs_kornia.modules.calibration.model_selection import ModelChoice

__all__ = ["RENDERED_METHODS", "run_fisheye_rendered", "fisheye_rendered_md"]

_SEED = BENCH_SEED_BASE + 710_000
_BOARD, _SQUARE, _SIZE = (9, 6), 0.03, (640, 480)

#: key -> label of the rendered part's rows
RENDERED_METHODS = {
    "ccs_fisheye": "ccs_kornia, `--model fisheye`",
    "ccs_auto": "ccs_kornia, `--model auto` (default)",
    "opencv_subpix": "OpenCV classic + cornerSubPix → cv2.fisheye",
    "opencv_sb": "OpenCV SB → cv2.fisheye",
}


def _ours(images: torch.Tensor, K_true: torch.Tensor, log) -> dict[str, dict]:
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
    from ccs_kornia.pipeline.sources import TensorSource

    source = TensorSource(images)
    out: dict[str, dict] = {}
    with Timer() as t_det, torch.inference_mode():
        detected = CalibrationPipeline("learned", model=FISHEYE).detect_views(source, _BOARD)
    for model in (FISHEYE, ModelChoice()):
        pipe = CalibrationPipeline("learned", model=model)
        with Timer() as t, torch.inference_mode():
            res = pipe.finish(copy.deepcopy(detected), _BOARD, _SQUARE, source)
        errors, found, chosen = [], [], []
        for c in range(images.shape[0]):
            one = res.select(c)
            cal = one.calibration
            ok = bool(cal.success) and bool(torch.isfinite(cal.K).all())
            errors.append(e_ip_px(cal.K, K_true[c]) if ok else float("inf"))
            found.append(int(one.found.sum()))
            if one.model_selection:
                chosen.append(one.model_selection.get("chosen"))
        out[f"ccs_{model}"] = {"errors": errors, "found": found, "seconds": t_det.seconds + t.seconds,
                               "models": {m: chosen.count(m) for m in sorted(set(chosen)) if m}}
        log(f"[fisheye] rendered ccs_kornia {model}: {sum(found)} boards found ({t_det.seconds + t.seconds:.1f}s)")
    return out


def _opencv(images: torch.Tensor, K_true: torch.Tensor, key: str, log) -> dict:
    from ccs_kornia.bench.methods.methods import make_methods

    method = make_methods((key,))[key]
    obj = board_object_points(*_BOARD, _SQUARE, dtype=torch.float64).numpy()
    errors, found = [], []
    with Timer() as t:
        for c in range(images.shape[0]):
            corners, ok = method.detect(images[c], _BOARD)
            idx = np.nonzero(ok)[0]
            found.append(len(idx))
            r = opencv_fisheye(obj, [corners[i] for i in idx], _SIZE) if len(idx) >= 3 else {"ok": False}
            errors.append(e_ip_px(r["K"], K_true[c]) if r["ok"] else float("inf"))
    log(f"[fisheye] rendered {key}: {sum(found)} boards found ({t.seconds:.1f}s)")
    return {"errors": errors, "found": found, "seconds": t.seconds}


def run_fisheye_rendered(cfg: BenchConfig, log=print) -> dict:
    """Render, detect and calibrate; returns ``{"trials", "views", "methods": {key: scores}, "common": ...}``."""
    T, V = cfg.fisheye_trials, cfg.fisheye_views
    K, D = random_kb_cameras(T, tuple(cfg.fisheye_fov), _SIZE, seed=_SEED)
    rv, tv, _, _ = random_board_views(K, D, V, *_BOARD, _SQUARE, image_size=_SIZE, seed=_SEED)
    with Timer() as t_render:
        images, _ = render_kb_views(K, D, rv, tv, *_BOARD, _SQUARE, _SIZE, seed=_SEED, supersample=cfg.supersample)
    log(f"[fisheye] rendered {T}x{V} views ({t_render.seconds:.1f}s)")
    raw = _ours(images, K, log)
    for key in ("opencv_subpix", "opencv_sb"):
        raw[key] = _opencv(images, K, key, log)
    fail = cfg.fisheye_fail_px
    ok_all = np.all([np.isfinite(r["errors"]) & (np.asarray(r["errors"]) <= fail) for r in raw.values()], axis=0)
    methods = {}
    for key, r in raw.items():
        e = np.asarray(r["errors"], dtype=np.float64)
        ok = np.isfinite(e) & (e <= fail)
        s = {"failures": int((~ok).sum()), "trials": T, "boards_found": int(sum(r["found"])),
             "boards": T * V, "seconds": r["seconds"], "e_ip_per_trial": [float(x) for x in e]}
        s.update({f"e_ip_{k}": v for k, v in (summary(e[ok]) or {}).items()})
        s.update({f"common_e_ip_{k}": v for k, v in (summary(e[ok_all]) or {}).items()})
        if "models" in r:
            s["models"] = r["models"]
        methods[key] = s
        log(f"[fisheye] rendered {RENDERED_METHODS[key]:45s} failures {s['failures']}/{T} E_IP mean "
            f"{_f(s.get('e_ip_mean'), 4)} var {_f(s.get('e_ip_var'), 5)}")
    return {"trials": T, "views": V, "render_seconds": t_render.seconds, "common_trials": int(ok_all.sum()),
            "methods": methods}


def _f(x, digits: int = 3) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def fisheye_rendered_md(sec: dict, fail_px: float) -> list[str]:
    """Markdown of the rendered part."""
    lines = [
        f"Rendered: {sec['trials']} Kannala-Brandt cameras x {sec['views']} views rendered through the exact lens "
        "(0.3–1 px optical blur, gamma 1.8–2.4, read noise 0.01, 8 bits); every method detects its own corners. "
        f"Failed = fewer than 3 boards, raised, non-finite or E_IP > {fail_px:g} px. *Common*: the "
        f"{sec['common_trials']} trials every method calibrated.",
        "",
        "| method | boards found | failed | E_IP mean | var | median | max | common mean | common var | time (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, s in sec["methods"].items():
        label = RENDERED_METHODS.get(key, key)
        if s.get("models"):
            label += " (" + ", ".join(f"{m} {n}" for m, n in s["models"].items()) + ")"
        lines.append(f"| {label} | {s['boards_found']}/{s['boards']} | {s['failures']}/{s['trials']} | "
                     f"{_f(s.get('e_ip_mean'), 4)} | {_f(s.get('e_ip_var'), 5)} | {_f(s.get('e_ip_median'), 4)} | "
                     f"{_f(s.get('e_ip_max'))} | {_f(s.get('common_e_ip_mean'), 4)} | "
                     f"{_f(s.get('common_e_ip_var'), 5)} | {s['seconds']:.1f} |")
    return lines + [""]
