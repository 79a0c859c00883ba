"""Section 3: real photographs (paper Table II and the RPE box plot).

For every known set in ``../shared/data/real`` (board, square and model from its README; the BoofCV sets
use the reference's k1, k2 model): every detection method's corners go to ccs_kornia's solver and to
``cv2.calibrateCamera`` (same model), first on all images, then on ``real_subsets`` random view subsets
(mean and spread of fx, fy, cx, cy and RMS; the subsets are the same image indices for every method, each
method using the views it found among them). The ccs_kornia solver calibrates all subsets in one batched
call. Where a published reference exists (read from the set's ``reference/`` files), the all-images
intrinsics are compared with it within the tolerance the set's README states.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.bench.common import Timer, ccs_calibrate, cv2_calibrate, summary
from ccs_kornia.bench.config import FISHEYE_REAL_SETS, BenchConfig
from ccs_kornia.bench.methods.methods import DetectionMethod
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.geometry.models.factory import K1K2, OPENCV5

__all__ = ["REAL_SETS", "default_real_dir", "load_reference", "load_real_set", "run_real"]

#: known sets: board (cols, rows), square (unknown ones: unit squares), camera model, reference tolerance (px on f, on
#: the principal point) from ``shared/data/real/README.md`` and the sets' SOURCE.md
REAL_SETS: dict[str, dict] = {
    "opencv_left": {"board": (9, 6), "square": 0.025, "model": OPENCV5, "tol_f": 4.0, "tol_pp": 5.0,
                    "reference": "reference/left_intrinsics.yml"},
    "udacity_camera_cal": {"board": (9, 6), "square": 1.0, "model": OPENCV5},
    "udacity_gopro_wide": {"board": (8, 6), "square": 1.0, "model": OPENCV5},
    "boofcv_sony_hx5v": {"board": (4, 6), "square": 0.03, "model": K1K2, "tol_f": 3.0, "tol_pp": 3.0,
                         "reference": "reference/intrinsic.yaml"},
    "boofcv_bumblebee2_left": {"board": (4, 6), "square": 0.03, "model": K1K2, "tol_f": 3.0, "tol_pp": 3.0,
                               "reference": "reference/intrinsicLeft.yaml"},
    # the stereo partner (same instants as the left set): its intrinsics are the "right" camera of BoofCV's stereo
    # calibration
    "boofcv_bumblebee2_right": {"board": (4, 6), "square": 0.03, "model": K1K2, "tol_f": 3.0, "tol_pp": 3.0,
                                "reference": "stereo.yaml", "reference_section": "right"},
}
_IMAGE_EXT = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


def default_real_dir() -> Path:
    """``$CCS_REAL_DATA`` when set, else ``shared/data/real`` next to the repository (the layout CI uses)."""
    env = os.environ.get("CCS_REAL_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[3].parent / "shared" / "data" / "real"


def load_reference(path: Path, section: str | None = None) -> dict | None:
    """``{fx, fy, cx, cy}`` from an OpenCV ``.yml`` (``camera_matrix``) or a BoofCV ``.yaml`` (``pinhole``; with
    ``section``, the camera under that top-level key of a stereo file, e.g. ``"right"``)."""
    if not path.is_file():
        return None
    text = path.read_text(errors="replace")
    if section is not None:
        m = re.search(rf"^{re.escape(section)}:\s*$(.*?)(?=^\S|\Z)", text, re.MULTILINE | re.DOTALL)
        if m is None:
            return None
        text = m.group(1)
    if "camera_matrix" in text:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        K = fs.getNode("camera_matrix").mat()
        fs.release()
        if K is None:
            return None
        return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}
    vals = {}
    for key in ("fx", "fy", "cx", "cy"):
        m = re.search(rf"^\s*{key}\s*:\s*([-+0-9.eE]+)", text, re.MULTILINE)
        if m is None:
            return None
        vals[key] = float(m.group(1))
    return vals


def load_real_set(folder: Path, max_images: int | None = None) -> tuple[torch.Tensor, list[str], tuple[int, int]]:
    """Grey images ``(B, 1, H, W)`` of one set, cropped to the most common size (two Udacity images are one
    pixel larger; cropping the last row/column keeps every pixel coordinate)."""
    from ccs_kornia.io.images import load_image_gray, natural_key
    # calibration2 before calibration10
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXT), key=lambda p: natural_key(p.name))
    if max_images is not None:
        files = files[:max_images]
    arrays, names = [], []
    for p in files:
        img, _ = load_image_gray(p)
        if img is not None:
            arrays.append(img)
            names.append(p.name)
    if not arrays:
        raise FileNotFoundError(f"no readable images in {folder}")
    sizes = [a.shape for a in arrays]
    h, w = max(set(sizes), key=sizes.count)
    keep = [(a, n) for a, n in zip(arrays, names) if a.shape[0] >= h and a.shape[1] >= w]
    stack = np.stack([a[:h, :w] for a, _ in keep]).astype(np.float32)
    return torch.from_numpy(stack)[:, None], [n for _, n in keep], (w, h)


def _params(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    return np.stack([K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]], -1)


def run_real(cfg: BenchConfig, methods: dict[str, DetectionMethod], device: str = "cpu", log=print) -> dict:
    """Run the real-photograph section; returns ``{"sets": {name: {...}}, "skipped": {...}}``."""
    root = Path(cfg.real_dir) if cfg.real_dir else default_real_dir()
    out: dict = {"root": str(root), "subsets": cfg.real_subsets, "sets": {}, "skipped": {}}
    if not root.is_dir():
        out["skipped"]["*"] = f"real data folder not found: {root}"
        log(f"[real] skipped: {root} not found")
        return out
    names = cfg.real_sets if cfg.real_sets is not None else tuple(sorted(p.name for p in root.iterdir() if p.is_dir()))
    for name in names:
        folder = root / name
        if name not in REAL_SETS:
            # the fisheye sets need a fisheye model on both sides: section 7 calibrates them
            out["skipped"][name] = ("fisheye lens: calibrated in section 7 (fisheye lenses)" if name in FISHEYE_REAL_SETS
                                    else "unknown set (board size not recorded in the benchmark)")
            continue
        if not folder.is_dir():
            out["skipped"][name] = f"not found in {root}"
            continue
        spec = REAL_SETS[name]
        board, square, model = spec["board"], spec["square"], spec["model"]
        images, files, size = load_real_set(folder, cfg.real_max_images)
        reference = (load_reference(folder / spec["reference"], spec.get("reference_section"))
                     if "reference" in spec else None)
        n_img = len(files)
        k = max(3, min(n_img - 1, int(round(cfg.real_subset_fraction * n_img))))
        rng = np.random.default_rng(BENCH_SEED_BASE + sum(map(ord, name)))
        subsets = np.stack([np.sort(rng.choice(n_img, k, replace=False)) for _ in range(cfg.real_subsets)])
        entry: dict = {
            "images": n_img, "image_size": list(size), "board": list(board), "square": square, "model": str(model),
            "subset_size": k, "reference": reference, "tol_f": spec.get("tol_f"), "tol_pp": spec.get("tol_pp"),
            "methods": {},
        }
        log(f"[real] {name}: {n_img} images {size[0]}x{size[1]}, board {board[0]}x{board[1]}, model {model}")
        for key, m in methods.items():
            if not m.available:
                continue
            with Timer() as t:
                corners, found = m.detect(images, board)
            res: dict = {"label": m.label, "found": int(found.sum()), "seconds_per_image": t.seconds / n_img}
            # all images
            r = ccs_calibrate(corners[None], found[None], board, square, size, model, device)
            c = cv2_calibrate(corners, found, board, square, size, model)
            res["all"] = {
                "ccs": _one(_params(r["K"][0]), float(r["rms"][0]), int(r["views"][0]), bool(r["success"][0]), reference, spec),
                "opencv": _one(_params(c["K"]), c["rms"], c["views"], c["success"], reference, spec),
            }
            # random subsets
            sc, sf = corners[subsets], found[subsets]
            r = ccs_calibrate(sc, sf, board, square, size, model, device)
            cv = [cv2_calibrate(sc[i], sf[i], board, square, size, model) for i in range(len(subsets))]
            res["subsets"] = {
                "ccs": _spread(_params(r["K"]), r["rms"], r["success"]),
                "opencv": _spread(_params(np.stack([d["K"] for d in cv])), np.array([d["rms"] for d in cv]),
                                  np.array([d["success"] for d in cv])),
            }
            entry["methods"][key] = res
            a = res["all"]
            log(f"[real] {name:24s} {m.label:30s} found {res['found']}/{n_img}  fx ccs {_f(a['ccs']['fx'])} "
                f"cv2 {_f(a['opencv']['fx'])}  RMS ccs {_f(a['ccs']['rms'], 3)} cv2 {_f(a['opencv']['rms'], 3)}")
        pipe_res = _pipeline_on_set(cfg, images, board, square, size, model, subsets, reference, spec, device)
        if pipe_res is not None:
            entry["methods"]["pipeline"] = pipe_res
            a = pipe_res["all"]
            log(f"[real] {name:24s} {pipe_res['label']:30s} found {pipe_res['found']}/{n_img}  fx {_f(a['ccs']['fx'])} "
                f"RMS {_f(a['ccs']['rms'], 3)}  correction applied: {pipe_res['correction_applied']}")
        out["sets"][name] = entry
    return out


def _pipeline_on_set(cfg, images, board, square, size, model, subsets, reference, spec, device) -> dict | None:
    """The product's default path on one set: ``CalibrationPipeline`` with the distortion correction (learned
    detector; detection on corrected images where the pooled correction applies; corrected solver stage)."""
    from ccs_kornia.bench.common import distortion_available
    from ccs_kornia.modules.detection.factory import make_detector
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
    from ccs_kornia.pipeline.sources import TensorSource

    net, _ = distortion_available(cfg.distortion_weights)
    if net is None:
        return None
    try:
        detector = make_detector("learned")
    except Exception:  # no detector weights: the section's other methods still run
        return None
    pipe = CalibrationPipeline(detector, model=model, distortion_correction=net).to(device)
    n_img = images.shape[0]
    source = TensorSource(images[None])
    with Timer() as t:
        full = pipe.run(source, board, square)  # the product path, as `calibrate` runs it
    one = full.select(0)
    cal, corners, found = one.calibration, one.detections.corners.double().cpu(), one.found.cpu()
    res: dict = {"label": "ccs_kornia pipeline (+ correction)", "found": int(found.sum()),
                 "seconds_per_image": t.seconds / n_img, "correction_applied": bool(one.corrected),
                 "correction_gate": bool(one.correction_tried)}
    c_np, f_np = corners.numpy(), found.numpy()
    cv = cv2_calibrate(c_np, f_np, board, square, size, model)
    res["all"] = {
        "ccs": _one(_params(cal.K.cpu().numpy()), float(cal.rms), int(cal.used.sum()), bool(cal.success),
                    reference, spec),
        "opencv": _one(_params(cv["K"]), cv["rms"], cv["views"], cv["success"], reference, spec),
    }
    # view subsets: the same detections (the second look at missed views included), the rest of the pipeline per
    # subset (pooled correction, evidence, solver)
    subs = torch.as_tensor(subsets, dtype=torch.long)
    trials = full.take_views(torch.zeros(subs.shape[0], dtype=torch.long), subs)
    done = pipe.finish(trials, board, square)
    cal_s = done.calibration
    sc, sf = corners[subsets], found[subsets]
    cvs = [cv2_calibrate(sc[i].numpy(), sf[i].numpy(), board, square, size, model) for i in range(len(subsets))]
    res["subsets"] = {
        "ccs": _spread(_params(cal_s.K.cpu().numpy()), cal_s.rms.cpu().numpy(), cal_s.success.cpu().numpy()),
        "opencv": _spread(_params(np.stack([d["K"] for d in cvs])), np.array([d["rms"] for d in cvs]),
                          np.array([d["success"] for d in cvs])),
    }
    res["subsets_correction_applied"] = 0 if done.corrected is None else int(done.corrected.sum())
    return res


def _f(x, digits: int = 2) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def _one(p: np.ndarray, rms: float, views: int, success: bool, reference: dict | None, spec: dict) -> dict:
    d = {"success": bool(success), "views": int(views), "rms": float(rms) if success else None}
    for i, key in enumerate(("fx", "fy", "cx", "cy")):
        d[key] = float(p[i]) if success and np.isfinite(p[i]) else None
    if reference is not None and success:
        diff = {key: d[key] - reference[key] for key in ("fx", "fy", "cx", "cy")}
        d["diff_reference"] = diff
        d["within_tolerance"] = bool(
            max(abs(diff["fx"]), abs(diff["fy"])) <= spec["tol_f"] and max(abs(diff["cx"]), abs(diff["cy"])) <= spec["tol_pp"]
        )
    return d


def _spread(p: np.ndarray, rms: np.ndarray, success: np.ndarray) -> dict:
    ok = np.asarray(success, dtype=bool) & np.isfinite(p).all(-1)
    d: dict = {"trials": int(len(ok)), "failures": int((~ok).sum())}
    for i, key in enumerate(("fx", "fy", "cx", "cy")):
        s = summary(p[ok, i])
        d[key] = {"mean": s["mean"], "std": s["std"]}
    s = summary(np.asarray(rms)[ok])
    d["rms"] = {"mean": s["mean"], "std": s["std"], "median": s["median"]}
    d["rms_values"] = [float(v) for v in np.asarray(rms)[ok]]
    return d
