"""Calibrations per second of the whole CalibrationSolver against cv2.calibrateCamera on the same corners.

Synthetic cameras as ``bench_solver.py`` (independent fx, fy, cx, cy, opencv5 distortion), 15 views of a 9x6 board,
corners with Gaussian noise (0.1 px). For C = 1, 64, 256 cameras prints, in one run, best of ``--repeats``:

* ``cv2.calibrateCamera`` in a Python loop (flags 0, one thread; for C > 16 a 16-camera loop scaled to C);
  the methods alternate within each round (the machine may be shared) and the best round of each is kept;
* ``CalibrationSolver`` (homographies -> copies -> Zhang/RANSAC -> LM core -> outlier check -> degeneracy
  checks), batched over the C cameras, and the same with ``checks=False``;
* the ratio of the solver's calibrations/s to OpenCV's (> 1: faster).

``--profile`` adds the time of every solver stage (the stage functions wrapped with timers; their sum is close
to the whole call). The machine's load average is printed: compare ratios within one run.

    python -m ccs_kornia.bench.micro.lm_speed [--cameras 1 64 256] [--device cpu|cuda] [--threads 1] [--profile]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict

import cv2
import torch

sys.path.insert(0, os.path.dirname(__file__))
from bench_solver import opencv_loop, synthetic_cameras  # noqa: E402

import ccs_kornia.modules.calibration.solver as solver_mod  # noqa: E402
from ccs_kornia.geometry.metrics import e_ip  # noqa: E402
from ccs_kornia.geometry.models.factory import OPENCV5  # noqa: E402
from ccs_kornia.modules.calibration.solver import CalibrationSolver  # noqa: E402

#: solver stages: (label, module attribute of solver.py or (object, method name))
STAGES = [
    ("homographies", "find_homographies"),
    ("copies (duplicate_views)", "duplicate_views"),
    ("Zhang + RANSAC", ("ImageRansac", "forward")),
    ("Zhang (no RANSAC)", "zhang_intrinsics"),
    ("poses from H", "extrinsics_from_homography"),
    ("LM core (joint_refinement)", "joint_refinement"),
    ("degeneracy checks", "check_degeneracy"),
]


def timed(fn, repeats, device):
    fn()  # warm-up
    best = float("inf")
    for _ in range(repeats):
        if device == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        out = fn()
        if device == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t)
    return best, out


def interleaved(fns, repeats, device):
    """Best time of each function over ``repeats`` rounds, the functions alternating within a round."""
    outs = [fn() for fn in fns]  # warm-up
    best = [float("inf")] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            if device == "cuda":
                torch.cuda.synchronize()
            t = time.perf_counter()
            outs[i] = fn()
            if device == "cuda":
                torch.cuda.synchronize()
            best[i] = min(best[i], time.perf_counter() - t)
    return best, outs


def profile_stages(solver, args, repeats, device):
    """Per-stage seconds of one solver call (best of ``repeats`` per stage), and the whole call."""
    spent = defaultdict(list)
    originals = []
    for label, target in STAGES:
        owner, name = (solver_mod, target) if isinstance(target, str) else (getattr(solver_mod, target[0]), target[1])
        if not hasattr(owner, name):
            continue
        fn = getattr(owner, name)

        def wrap(*a, _fn=fn, _label=label, **k):
            if device == "cuda":
                torch.cuda.synchronize()
            t = time.perf_counter()
            out = _fn(*a, **k)
            if device == "cuda":
                torch.cuda.synchronize()
            spent[_label][-1] += time.perf_counter() - t
            return out

        originals.append((owner, name, fn))
        setattr(owner, name, wrap)
    try:
        for label, _ in STAGES:
            spent[label].append(0.0)
        solver(*args)
        rows = defaultdict(lambda: float("inf"))
        whole = float("inf")
        for _ in range(repeats):
            for label, _ in STAGES:
                spent[label].append(0.0)
            t = time.perf_counter()
            solver(*args)
            whole = min(whole, time.perf_counter() - t)
            for label, _ in STAGES:
                rows[label] = min(rows[label], spent[label][-1])
    finally:
        for owner, name, fn in originals:
            setattr(owner, name, fn)
    return rows, whole


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 64, 256])
    ap.add_argument("--views", type=int, default=15)
    ap.add_argument("--noise", type=float, default=0.1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--profile", action="store_true", help="time every solver stage")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    cv2.setNumThreads(a.threads)
    size = (640, 480)
    print(f"{a.views} views of a 9x6 board, noise {a.noise} px, device {a.device}, {a.threads} thread(s); best of "
          f"{a.repeats}; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs")
    print(f"{'cameras':>7} {'method':34s} {'s':>8} {'cal/s':>8} {'x cv2':>6} {'E_IP px':>8}  (E_IP: mean over the first 16)")
    for C in a.cameras:
        K, dist, obj, uv = synthetic_cameras(C, a.views, a.noise, seed=C)
        valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
        n_cv = min(C, 16)  # OpenCV runs camera after camera: time a few and scale
        uvd, vd, objd = uv.to(a.device), valid.to(a.device), obj.to(a.device)
        solvers = [CalibrationSolver(model=OPENCV5), CalibrationSolver(model=OPENCV5, checks=False)]
        fns = [lambda: opencv_loop(obj, uv[:n_cv], size)] + [lambda s=s: s(uvd, vd, objd, size) for s in solvers]
        # interleaved rounds (the machine is shared: each method sees the same load), best round of each
        best, outs = interleaved(fns, a.repeats if C <= 64 else max(2, a.repeats // 2), a.device)
        t_cv = best[0] * C / n_cv
        rows = [("cv2.calibrateCamera (loop)", t_cv, float(e_ip(torch.tensor(outs[0][0]), K[:n_cv]).mean()))]
        for label, t, res in zip(["CalibrationSolver", "CalibrationSolver(checks=False)"], best[1:], outs[1:]):
            rows.append((label, t, float(e_ip(res.K[:n_cv].cpu(), K[:n_cv]).mean())))  # E_IP on OpenCV's cameras
        for label, t, e in rows:
            print(f"{C:7d} {label:34s} {t:8.4f} {C / t:8.1f} {t_cv / t:6.2f} {e:8.4f}")
        if a.profile:
            stages, whole = profile_stages(CalibrationSolver(model=OPENCV5), (uvd, vd, objd, size), a.repeats, a.device)
            for label, t in stages.items():
                if t > 0:
                    print(f"{'':7s}   stage {label:28s} {t:8.4f} {100 * t / whole:5.1f} %")
            print(f"{'':7s}   {'(rest: bookkeeping, outlier check)':34s} {whole - sum(stages.values()):8.4f}")


if __name__ == "__main__":
    main()
