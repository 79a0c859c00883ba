"""Calibrations per second: the LM core (through CalibrationSolver) against cv2.calibrateCamera on the same corners.

Synthetic cameras as ``bench_solver.py`` (independent fx, fy, cx, cy, opencv5 distortion), 15 views of a 9x6 board,
corners with Gaussian noise. For C = 1, 64, 256 cameras prints:

* ``cv2.calibrateCamera`` in a Python loop (flags 0, one thread);
* ``CalibrationSolver`` (homographies -> Zhang -> RANSAC -> LM -> outlier check) with the former ``refine.py`` LM
  and with the LM core (``modules/calibration/refinement.joint_refinement``), batched over the C cameras;
* the LM alone (both implementations) from the same Zhang start.

    python benchmarks/lm_speed.py [--cameras 1 64 256] [--device cpu|cuda] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import cv2
import numpy as np
import torch

sys.path.insert(0, os.path.dirname(__file__))
from bench_solver import opencv_loop, synthetic_cameras  # noqa: E402

import ccs_kornia.modules.calibrator as calibrator  # noqa: E402
from ccs_kornia.metrics import e_ip  # noqa: E402
from ccs_kornia.modules import refine  # noqa: E402
from ccs_kornia.modules.calibration import refinement  # noqa: E402
from ccs_kornia.modules.homography import find_homographies  # noqa: E402
from ccs_kornia.modules.zhang import extrinsics_from_homography, zhang_intrinsics  # noqa: E402


def timed(fn, repeats, device):
    fn()  # warm-up
    if device == "cuda":
        torch.cuda.synchronize()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        if device == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 64, 256])
    ap.add_argument("--views", type=int, default=15)
    ap.add_argument("--noise", type=float, default=0.1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    cv2.setNumThreads(a.threads)
    size = (640, 480)
    print(f"{a.views} views of a 9x6 board, noise {a.noise} px, device {a.device}, {a.threads} thread(s); best of {a.repeats}")
    print(f"{'cameras':>7} {'method':44s} {'s':>8} {'cal/s':>8} {'E_IP px':>8}")
    for C in a.cameras:
        K, dist, obj, uv = synthetic_cameras(C, a.views, a.noise, seed=C)
        valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
        rows = []
        n_cv = min(C, 16)  # OpenCV runs camera after camera: time a few and scale
        t, (Kcv, _) = timed(lambda: opencv_loop(obj, uv[:n_cv], size), max(1, a.repeats if C == 1 else 1), "cpu")
        rows.append(("cv2.calibrateCamera (loop)", t * C / n_cv, float(e_ip(torch.tensor(Kcv), K[:n_cv]).mean())))
        uvd, vd, objd = uv.to(a.device), valid.to(a.device), obj.to(a.device)
        for label, fn in [("CalibrationSolver + refine.py LM (former)", refine.joint_refinement),
                          ("CalibrationSolver + LM core", refinement.joint_refinement)]:
            calibrator.joint_refinement = fn
            solver = calibrator.CalibrationSolver(model="opencv5")
            t, res = timed(lambda: solver(uvd, vd, objd, size), a.repeats, a.device)
            rows.append((label, t, float(e_ip(res.K.cpu(), K).mean())))
        calibrator.joint_refinement = refine.joint_refinement
        # the LM alone, from Zhang's closed form
        H = find_homographies(objd[:, :2], uvd, vd)
        used = torch.ones(C, a.views, dtype=torch.bool, device=a.device)
        K0 = zhang_intrinsics(H, used, size)
        rv0, tv0 = extrinsics_from_homography(K0, H)
        for label, fn in [("LM alone: refine.py (former)", refine.joint_refinement), ("LM alone: LM core", refinement.joint_refinement)]:
            t, res = timed(lambda: fn(uvd, vd, objd, K0, rv0, tv0, model="opencv5"), a.repeats, a.device)
            rows.append((label, t, float(e_ip(res.K.cpu(), K).mean())))
        for label, t, e in rows:
            print(f"{C:7d} {label:44s} {t:8.3f} {C / t:8.1f} {e:8.3f}")


if __name__ == "__main__":
    main()
