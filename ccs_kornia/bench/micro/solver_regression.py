"""Before/after check of the calibration solver on fixed corners: K, distortion, RMS and std per case.

The corners are captured once (``--capture``: synthetic sets of the solver tests, the real sets detected as
``shared/data/real/verify_opencv.py`` does, and the inputs of the corrected-frame stage of the pipeline tests and
of ``opencv_left``), so a change of the solver is compared on exactly the same input:

    python -m ccs_kornia.bench.micro.solver_regression --capture /tmp/solver_inputs.pt [--real-dir ../shared/data/real]
    python -m ccs_kornia.bench.micro.solver_regression --inputs /tmp/solver_inputs.pt --out before.json
    ... change the solver ...
    python -m ccs_kornia.bench.micro.solver_regression --inputs /tmp/solver_inputs.pt --out after.json --compare before.json
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.models.factory import K1K2, OPENCV5, PINHOLE, RATIONAL

F64 = torch.float64
SIZE = (640, 480)
DIST5 = torch.tensor([-0.28, 0.09, 5e-4, -8e-4, 0.01], dtype=F64)
REAL_SETS = [("opencv_left", (9, 6), 25.0, (OPENCV5, RATIONAL, K1K2)),
             ("boofcv_sony_hx5v", (4, 6), 30.0, (K1K2, OPENCV5)),
             ("boofcv_bumblebee2_left", (4, 6), 30.0, (K1K2, OPENCV5))]


def _classic(setdir, size):
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    out = []
    for f in sorted(glob.glob(os.path.join(setdir, "*.jpg"))):
        gray = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(gray, size, cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            out.append(cv2.cornerSubPix(gray, c, (11, 11), (-1, -1), crit).reshape(-1, 2))
    return torch.from_numpy(np.stack(out)).double(), (gray.shape[1], gray.shape[0])


def capture(path, real_dir):
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "..", "tests", "modules", "calibration"))
    from _board_views import synthetic

    from ccs_kornia.data.scenes.scenes import make_calibration_set
    from ccs_kornia.geometry.board_points import board_object_points
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    cases = {}
    for name, C, V, dist, noise, seed in [("exact_none", 4, 15, None, 0.0, 4), ("exact_opencv5", 4, 15, DIST5, 0.0, 4),
                                          ("noisy_opencv5", 2, 15, DIST5, 0.1, 9), ("noisy_k1k2", 2, 15, DIST5[:2], 0.2, 3),
                                          ("noisy_rational", 1, 15, torch.cat([DIST5, torch.tensor([0.02, -0.01, 0.003], dtype=F64)]), 0.1, 6)]:
        K, obj, uv, _, _ = synthetic(C=C, V=V, dist=dist, noise=noise, seed=seed)
        cases[name] = {"corners": uv, "obj": obj, "size": SIZE}
    real = {}
    for name, board, square, _ in REAL_SETS:
        d = os.path.join(real_dir, name)
        if os.path.isdir(d):
            uv, size = _classic(d, board)
            real[name] = {"corners": uv, "obj": board_object_points(board[0], board[1], square, dtype=F64), "size": size}
    # inputs of the corrected-frame stage: the pipeline tests' synthetic lenses and opencv_left
    corrected = {}
    from ccs_kornia.modules.calibration import corrected_frame

    pipe = CalibrationPipeline("opencv", seed=0)
    grab = {}
    solve_with_correction = corrected_frame.solve_with_correction

    def record(solver, usual, corners, found, correction, apply, board_size, square, image_size, **kwargs):
        grab.update(corners=corners.clone(), found=found.clone(), correction=correction.clone(), apply=apply.clone(),
                    board=tuple(board_size), square=float(square), size=tuple(image_size))
        return solve_with_correction(solver, usual, corners, found, correction, apply, board_size, square, image_size,
                                     **kwargs)

    corrected_frame.solve_with_correction = record
    cams = [(torch.tensor([[620.0, 0.0, 322.0], [0.0, 610.0, 236.0], [0.0, 0.0, 1.0]], dtype=F64),
             torch.tensor([-0.28, 0.09, 0.0005, -0.0008, 0.0], dtype=F64)),
            (torch.tensor([[540.0, 0.0, 310.0], [0.0, 545.0, 250.0], [0.0, 0.0, 1.0]], dtype=F64),
             torch.tensor([-0.1, 0.02, 0.0, 0.0, 0.0], dtype=F64))]
    imgs = torch.stack([make_calibration_set(K, (9, 6), 0.025, SIZE, num_views=10, dist=d, seed=11 + c, supersample=2).images
                        for c, (K, d) in enumerate(cams)])
    pipe(imgs, (9, 6), 0.025)
    corrected["pipeline_test_lenses"] = dict(grab)
    grab.clear()
    K = torch.tensor([[420.0, 0.0, 326.0], [0.0, 425.0, 236.0], [0.0, 0.0, 1.0]], dtype=F64)
    s = make_calibration_set(K, (9, 6), 0.025, SIZE, num_views=12, radial=torch.tensor([1.0, -0.45, 0.05]), seed=5, supersample=2)
    pipe(s.images[None], (9, 6), 0.025)
    corrected["severe_radial"] = dict(grab)
    grab.clear()
    from ccs_kornia.io.images import load_image_gray
    d = os.path.join(real_dir, "opencv_left")
    if os.path.isdir(d):
        ims = torch.stack([torch.from_numpy(load_image_gray(f)[0])[None] for f in sorted(glob.glob(os.path.join(d, "*.jpg")))])
        pipe(ims[None], (9, 6), 25.0)
        corrected["opencv_left"] = dict(grab)
    corrected_frame.solve_with_correction = solve_with_correction
    corrected = {k: v for k, v in corrected.items() if v}  # (a set whose cameras never went the corrected way)
    torch.save({"cases": cases, "real": real, "corrected": corrected}, path)
    print("captured", {k: list(v) for k, v in {"cases": cases, "real": real, "corrected": corrected}.items()})


def _record(res, extra=None):
    out = {"K": res.K.tolist(), "dist": res.dist.tolist(), "rms": res.rms.tolist(), "success": res.success.tolist(),
           "std_intrinsics": res.std_intrinsics.tolist(), "used": res.used.sum(-1).tolist()}
    cov = getattr(res, "cov_camera", None)
    if cov is not None:
        out["std_cov"] = cov.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt().tolist()
    out.update(extra or {})
    return out


def run(inputs):
    from ccs_kornia.modules.calibration.corrected_frame import (
        calibrate_corrected,
        solve_with_correction,
    )
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    data = torch.load(inputs, weights_only=False)
    out = {}
    models = {"exact_none": [PINHOLE], "exact_opencv5": [OPENCV5], "noisy_opencv5": [OPENCV5, K1K2],
              "noisy_k1k2": [K1K2], "noisy_rational": [RATIONAL]}
    for name, c in data["cases"].items():
        for m in models[name]:
            res = CalibrationSolver(model=m)(c["corners"], None, c["obj"], c["size"])
            out[f"{name}/{m}"] = _record(res)
        if name == "noisy_opencv5":
            res = CalibrationSolver(fix_aspect_ratio=True, fix_principal_point=True)(c["corners"], None, c["obj"], c["size"])
            out[f"{name}/opencv5_fixar_fixpp"] = _record(res)
            s = CalibrationSolver()
            first = s(c["corners"], None, c["obj"], c["size"])
            warm = s(c["corners"], None, c["obj"], c["size"], initial=first, fix_intrinsics=True)
            out[f"{name}/warm_fix_intrinsics"] = _record(warm)
    for name, c in data["real"].items():
        for m in next(r[3] for r in REAL_SETS if r[0] == name):
            res = CalibrationSolver(model=m)(c["corners"], None, c["obj"], c["size"])
            out[f"real/{name}/{m}"] = _record(res)

    for name, g in data["corrected"].items():
        solver = CalibrationSolver(model=OPENCV5, seed=0)
        valid = g["found"][..., None].expand(g["corners"].shape[:-1])
        from ccs_kornia.geometry.board_points import board_object_points as bop

        obj = bop(g["board"][0], g["board"][1], g["square"], dtype=F64)
        usual = solver(g["corners"], valid, obj, g["size"])
        calib, corr, applied = solve_with_correction(solver, usual, g["corners"], g["found"], g["correction"], g["apply"],
                                                     g["board"], g["square"], g["size"])
        out[f"corrected/{name}/solve_with_correction"] = _record(calib, {"applied": applied.tolist()})
        forced, corr, model_rms = calibrate_corrected(solver, g["corners"], g["found"], g["correction"], g["board"],
                                                     g["square"], g["size"])
        out[f"corrected/{name}/calibrate_corrected"] = _record(forced, {"model_rms": model_rms.tolist(),
                                                                         "correction": corr.tolist()})
    return out


def compare(a, b):
    print(f"{'case':52s} {'max|dK| px':>11s} {'max|d dist|':>11s} {'max|d rms|':>11s} {'succ':>5s}")
    for k in a:
        if k not in b:
            print(f"{k:52s} missing")
            continue
        dK = np.nanmax(np.abs(np.array(a[k]["K"]) - np.array(b[k]["K"]))) if np.isfinite(a[k]["K"]).any() else float("nan")
        dd = np.nanmax(np.abs(np.array(a[k]["dist"]) - np.array(b[k]["dist"]))) if np.isfinite(a[k]["dist"]).any() else float("nan")
        dr = np.nanmax(np.abs(np.array(a[k]["rms"]) - np.array(b[k]["rms"]))) if np.isfinite(a[k]["rms"]).any() else float("nan")
        same = a[k]["success"] == b[k]["success"]
        print(f"{k:52s} {dK:11.3g} {dd:11.3g} {dr:11.3g} {str(same):>5s}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture")
    ap.add_argument("--real-dir", default=os.environ.get("CCS_REAL_DATA") or os.path.join(
        os.path.dirname(__file__), "..", "..", "..", "..", "shared", "data", "real"))
    ap.add_argument("--inputs")
    ap.add_argument("--out")
    ap.add_argument("--compare")
    a = ap.parse_args()
    torch.set_num_threads(1)
    if a.capture:
        capture(a.capture, a.real_dir)
    if a.inputs:
        out = run(a.inputs)
        if a.out:
            with open(a.out, "w") as f:
                json.dump(out, f, indent=1)
        for k, v in out.items():
            K = np.array(v["K"]).reshape(-1, 3, 3)
            print(k, "fx fy cx cy:", [[round(float(x), 4) for x in (k_[0, 0], k_[1, 1], k_[0, 2], k_[1, 2])] for k_ in K],
                  "rms", [round(r, 5) if r == r else r for r in np.atleast_1d(v["rms"]).tolist()])
        if a.compare:
            with open(a.compare) as f:
                compare(json.load(f), out)


if __name__ == "__main__":
    main()
