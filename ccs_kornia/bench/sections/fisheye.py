"""Section 7: fisheye lenses — the Kannala-Brandt model against ``cv2.fisheye.calibrate``.

*Synthetic*: ``fisheye_trials`` Kannala-Brandt cameras (640x480, horizontal field of view uniform in
``fisheye_fov`` degrees, :mod:`~ccs_kornia.bench.scenes.fisheye_data`), ``fisheye_views`` board views each with exact
corners plus ``fisheye_noise`` px of Gaussian noise; both solvers get the same corners (OpenCV's are what its own
detector would give at best). A calibration fails when it raises, returns non-finite values or is more than
``fisheye_fail_px`` (E_IP) off; E_IP statistics are over each method's successful trials.

*Rendered* (:mod:`~ccs_kornia.bench.sections.fisheye_rendered`): the same kind of cameras, views rendered through the lens,
every method detecting its own corners.

*Real*: the fisheye sets of ``real_dir``: (a) OpenCV classic corners (cornerSubPix, 11x11 px window) through
``CalibrationSolver(model=FISHEYE)`` and through ``cv2.fisheye.calibrate`` (views it rejects dropped and rerun, as
ROS does); (b) the default product path (``CalibrationPipeline``, learned detector, ``model=ModelChoice()``, as
``--model auto``): boards found, the model chosen, the camera against the published reference.
"""

from __future__ import annotations

import glob
import os

import cv2
import numpy as np
import torch

from ccs_kornia.bench.common import Timer, e_ip_px, summary
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.fisheye_opencv import opencv_fisheye
from ccs_kornia.bench.scenes.fisheye_data import random_board_views, random_kb_cameras
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models.factory import FISHEYE
from ccs_kornia.modules.calibration.model_selection import ModelChoice

__all__ = ["FISHEYE_SETS", "fisheye_md", "run_fisheye"]

#: name -> (cols, rows, square, reference (fx, fy, cx, cy) or None, intrinsic guess for cv2 or None: the one the
#: set's SOURCE.md used, without which cv2.fisheye.calibrate cannot initialise on it)
FISHEYE_SETS: dict[str, tuple] = {
    "ros_fisheye_mono": (8, 6, 0.108, (290.050152, 289.392837, 399.938345, 273.885669), None),
    "boofcv_fisheye_chessboard": (6, 4, 0.03, None, ((190.0, 0.0, 319.5), (0.0, 190.0, 319.5), (0.0, 0.0, 1.0))),
}
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def _scores(errors: list[float], fail: float, seconds: float) -> dict:
    e = np.asarray(errors, dtype=np.float64)
    ok = np.isfinite(e) & (e <= fail)
    out = {"failures": int((~ok).sum()), "trials": len(e), "seconds": seconds}
    out.update({f"e_ip_{k}": v for k, v in (summary(e[ok]) or {}).items()})
    return out


def _synthetic(cfg: BenchConfig, log) -> dict:
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    size = (640, 480)
    K, D = random_kb_cameras(cfg.fisheye_trials, tuple(cfg.fisheye_fov), size, seed=BENCH_SEED_BASE + 700_000)
    _, _, uv, obj = random_board_views(K, D, cfg.fisheye_views, image_size=size, seed=BENCH_SEED_BASE + 700_000)
    g = torch.Generator().manual_seed(BENCH_SEED_BASE + 700_007)
    uv = uv + cfg.fisheye_noise * torch.randn(uv.shape, generator=g, dtype=torch.float64)
    with Timer() as t_ours, torch.inference_mode():
        res = CalibrationSolver(model=FISHEYE)(uv, None, obj, size)
    ours = [e_ip_px(res.K[c].numpy(), K[c].numpy()) if bool(res.success[c]) else float("inf")
            for c in range(cfg.fisheye_trials)]
    cv = []
    with Timer() as t_cv:
        for c in range(cfg.fisheye_trials):
            r = opencv_fisheye(obj.numpy(), [uv[c, v].numpy() for v in range(cfg.fisheye_views)], size)
            cv.append(e_ip_px(r["K"], K[c].numpy()) if r["ok"] else float("inf"))
    out = {"ccs": _scores(ours, cfg.fisheye_fail_px, t_ours.seconds),
           "opencv": _scores(cv, cfg.fisheye_fail_px, t_cv.seconds)}
    for key, label in (("ccs", "ccs_kornia fisheye"), ("opencv", "cv2.fisheye.calibrate")):
        s = out[key]
        log(f"[fisheye] synthetic {label:22s} failures {s['failures']}/{s['trials']} E_IP mean "
            f"{_f(s.get('e_ip_mean'), 4)} var {_f(s.get('e_ip_var'), 5)} ({s['seconds']:.1f}s)")
    return out


def _classic_corners(folder: str, cols: int, rows: int):
    files = sorted(glob.glob(os.path.join(folder, "*.png")) + glob.glob(os.path.join(folder, "*.jpg")),
                   key=lambda f: (len(os.path.basename(f)), f))
    corners, size = [], None
    for f in files:
        g = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        size = (g.shape[1], g.shape[0])
        ok, c = cv2.findChessboardCorners(g, (cols, rows), cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE)
        corners.append(cv2.cornerSubPix(g, c, (5, 5), (-1, -1), _SUBPIX).reshape(-1, 2) if ok else None)
    return files, corners, size


def _camera(K: np.ndarray, D, rms, used: int, ref) -> dict:
    out = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
           "D": [float(x) for x in np.asarray(D).ravel()], "rms": float(rms), "views_used": int(used)}
    if ref is not None:
        out["max_diff_to_reference"] = max(abs(out[k] - r) for k, r in zip(("fx", "fy", "cx", "cy"), ref))
    return out


def _real(cfg: BenchConfig, log) -> dict:
    from ccs_kornia.bench.sections.real import default_real_dir
    from ccs_kornia.modules.calibration.solver import CalibrationSolver
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
    from ccs_kornia.pipeline.sources import FileSource

    sets = {}
    for name, (cols, rows, square, ref, guess) in FISHEYE_SETS.items():
        if name not in cfg.fisheye_real_sets:
            continue
        folder = os.path.join(str(cfg.real_dir or default_real_dir()), name)
        if not os.path.isdir(folder):
            log(f"[fisheye] {name}: not present at {folder} — skipped")
            continue
        files, det, size = _classic_corners(folder, cols, rows)
        found = [i for i, c in enumerate(det) if c is not None]
        obj = board_object_points(cols, rows, square, dtype=torch.float64)
        entry: dict = {"images": len(files), "size": list(size), "board": [cols, rows], "reference": ref,
                       "classic_found": len(found)}
        uv = torch.tensor(np.stack([det[i] for i in found]), dtype=torch.float64)
        with torch.inference_mode():
            ours = CalibrationSolver(model=FISHEYE)(uv, None, obj, size)
        entry["ccs_on_classic"] = _camera(ours.K.numpy(), ours.dist.numpy(), ours.rms, ours.used.sum(), ref)
        r = opencv_fisheye(obj.numpy(), [det[i] for i in found], size)
        if not r["ok"] and guess is not None:  # as the set's publisher did
            r = opencv_fisheye(obj.numpy(), [det[i] for i in found], size, K_guess=np.array(guess))
            r["with_guess"] = True
        if r["ok"]:
            entry["opencv_on_classic"] = _camera(r["K"], r["D"], r["rms"], len(r["used"]), ref)
            entry["opencv_on_classic"]["intrinsic_guess"] = bool(r.get("with_guess"))
            sub = torch.tensor(r["used"])
            with torch.inference_mode():
                same = CalibrationSolver(model=FISHEYE)(uv[sub], None, obj, size)
            entry["ccs_on_opencv_views_rms"] = float(same.rms)
        else:
            entry["opencv_on_classic"] = {"error": r["error"]}
        pipe = CalibrationPipeline("learned", model=ModelChoice())
        with Timer() as t, torch.inference_mode():
            out = pipe.run(FileSource([files]), (cols, rows), square).select(0)
        cal = out.calibration
        entry["default_path"] = {"found": int(out.found.sum()), "success": bool(cal.success), "seconds": t.seconds,
                                 "model": (out.model_selection or {}).get("chosen")}
        if bool(cal.success):
            entry["default_path"].update(_camera(cal.K.numpy(), cal.dist.numpy(), cal.rms, cal.used.sum(), ref))
        log(f"[fisheye] {name}: classic corners on {len(found)}/{len(files)}; ccs {entry['ccs_on_classic']}; "
            f"cv2 {entry['opencv_on_classic']}; default path {entry['default_path']}")
        sets[name] = entry
    return sets


def run_fisheye(cfg: BenchConfig, log=print) -> dict:
    """Run the fisheye section; returns ``{"synthetic": ..., "real": {set: ...}}``."""
    from ccs_kornia.bench.sections.fisheye_rendered import run_fisheye_rendered

    out = {"fov": list(cfg.fisheye_fov), "trials": cfg.fisheye_trials, "views": cfg.fisheye_views,
           "noise_px": cfg.fisheye_noise, "fail_px": cfg.fisheye_fail_px, "synthetic": _synthetic(cfg, log)}
    if cfg.fisheye_rendered:
        out["rendered"] = run_fisheye_rendered(cfg, log)
    out["real"] = _real(cfg, log)
    return out


def _f(x, digits: int = 3) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def fisheye_md(sec: dict) -> list[str]:
    """Markdown of the section."""
    syn = sec["synthetic"]
    lines = [
        f"Synthetic: {sec['trials']} Kannala-Brandt cameras (640x480, horizontal field of view "
        f"{sec['fov'][0]:g}–{sec['fov'][1]:g}°) x {sec['views']} views, exact corners + {sec['noise_px']:g} px noise, "
        f"the same corners to both solvers; failed = raised, non-finite or E_IP > {sec['fail_px']:g} px.",
        "",
        "| solver | failed | E_IP mean | var | median | max | time (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, label in (("ccs", "ccs_kornia `model=\"fisheye\"`"), ("opencv", "cv2.fisheye.calibrate")):
        s = syn[key]
        lines.append(f"| {label} | {s['failures']}/{s['trials']} | {_f(s.get('e_ip_mean'), 4)} | "
                     f"{_f(s.get('e_ip_var'), 5)} | {_f(s.get('e_ip_median'), 4)} | {_f(s.get('e_ip_max'))} | "
                     f"{s['seconds']:.1f} |")
    if "rendered" in sec:
        from ccs_kornia.bench.sections.fisheye_rendered import fisheye_rendered_md

        lines += [""] + fisheye_rendered_md(sec["rendered"], sec["fail_px"])[:-1]
    lines += ["", "Real fisheye sets (*classic*: OpenCV classic corners + cornerSubPix 11x11; *default path*: "
              "learned detector, `--model auto`):", "",
              "| set | method | boards / views used | fx | fy | cx | cy | RMS px | max diff to reference |",
              "|---|---|---|---|---|---|---|---|---|"]
    for name, e in sec["real"].items():
        rows = [("classic → ccs_kornia fisheye", e["ccs_on_classic"], e["classic_found"]),
                ("classic → cv2.fisheye" + (" (intrinsic guess)" if e["opencv_on_classic"].get("intrinsic_guess")
                                            else ""), e["opencv_on_classic"], e["classic_found"]),
                (f"default path ({e['default_path'].get('model')})", e["default_path"], e["default_path"]["found"])]
        for label, c, found in rows:
            if "fx" not in c:
                lines.append(f"| {name} | {label} | {found}/{e['images']} | failed: {c.get('error', '')} ||||||")
                continue
            lines.append(f"| {name} | {label} | {found}/{e['images']} / {c['views_used']} | {c['fx']:.2f} | "
                         f"{c['fy']:.2f} | {c['cx']:.2f} | {c['cy']:.2f} | {c['rms']:.4f} | "
                         f"{_f(c.get('max_diff_to_reference'), 2)} |")
        if "ccs_on_opencv_views_rms" in e:
            lines.append(f"| {name} | ccs_kornia on cv2's views | | | | | | {e['ccs_on_opencv_views_rms']:.4f} | |")
    return lines + [""]
