"""Seconds per rig calibration of :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver` (the joint fit, the outlier
check and the k-fold refits, all on the LM core) on rendered rigs.

Stereo heads (two ``opencv5`` cameras, 12 cm baseline) and four-camera rigs (``k1k2`` and fisheye mixed), 20 frames of
a 7x5 board, 0.2 px noise, 10 % of the frames missed per camera; ``B`` rigs solved in one batched call. Prints, best of
``--repeats`` (the machine may be shared: compare runs made one after the other), the seconds per call and per rig and
the mean joint-LM iterations:

    python -m ccs_kornia.bench.micro.rig_lm_speed [--rigs 1 8] [--repeats 5] [--device cpu|cuda] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import time

import torch

from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import FISHEYE, K1K2, OPENCV5
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.rig.rig_solver import RigSolver

F64 = torch.float64
SIZE = (640, 480)


def _rig(kind: str, seed: int):
    K = torch.tensor([[520.0, 0, 320], [0, 518, 240], [0, 0, 1]], dtype=F64)
    Kf = torch.tensor([[260.0, 0, 322], [0, 259, 238], [0, 0, 1]], dtype=F64)
    if kind == "stereo":
        cams = [Camera.from_opencv(OPENCV5, K, torch.tensor([-0.2, 0.05, 1e-3, -5e-4, 0.0], dtype=F64), SIZE)] * 2
        R = torch.eye(3, dtype=F64).expand(2, 3, 3).clone()
        T = torch.tensor([[0.0, 0, 0], [-0.12, 0.001, 0.002]], dtype=F64)
        models = OPENCV5
    else:
        cams = [Camera.from_opencv(K1K2, K, torch.tensor([-0.15, 0.03], dtype=F64), SIZE),
                Camera.from_opencv(FISHEYE, Kf, torch.tensor([0.02, -0.01, 0.002, 0.0], dtype=F64), SIZE)] * 2
        yaw = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, -0.1, 0.0], [0.05, 0.0, 0.0]], dtype=F64)
        R = exp_so3(yaw)
        T = torch.tensor([[0.0, 0, 0], [-0.1, 0, 0], [0.1, 0, 0], [0.0, -0.1, 0]], dtype=F64)
        models = [K1K2, FISHEYE, K1K2, FISHEYE]
    s = render_rig(Camera.cat(cams), R, T, num_frames=20, seed=seed, noise_px=0.2, drop=0.1)
    return s, models


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rigs", type=int, nargs="+", default=[1, 8])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    print(f"rig solver, device {a.device}, {a.threads} thread(s), best of {a.repeats}; load average "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{'rig':>8} {'B':>3} {'s/call':>8} {'s/rig':>8} {'LM iters':>8}")
    for kind in ("stereo", "4-camera"):
        for B in a.rigs:
            scenes = [_rig(kind, seed) for seed in range(B)]
            models = scenes[0][1]
            corners = torch.stack([s.corners for s, _ in scenes]).to(a.device)
            valid = torch.stack([s.valid for s, _ in scenes]).to(a.device)
            obj, sizes = scenes[0][0].object_points.to(a.device), scenes[0][0].image_sizes
            solver = RigSolver(models)
            solver(corners, valid, obj, sizes)  # warm-up
            times = []
            for _ in range(a.repeats):
                if a.device.startswith("cuda"):
                    torch.cuda.synchronize()
                t0 = time.perf_counter()
                out = solver(corners, valid, obj, sizes)
                if a.device.startswith("cuda"):
                    torch.cuda.synchronize()
                times.append(time.perf_counter() - t0)
            iters = sum(r.iterations for r in out) / B
            print(f"{kind:>8} {B:3d} {min(times):8.4f} {min(times) / B:8.4f} {iters:8.1f}")


if __name__ == "__main__":
    main()
