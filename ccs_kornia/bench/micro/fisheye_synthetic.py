"""Synthetic fisheye calibration: ccs_kornia's calibrate_fisheye against cv2.fisheye.calibrate on the same corners.

Kannala-Brandt cameras (640x480, horizontal field of view uniform in 120-200 degrees, k1..k4 random, fy/fx within
1%, principal point within 10 px of the centre), 15 board views each (9x6, random directions up to the rim,
tilts up to 70 degrees), exact corners plus Gaussian noise. E_IP = (|dfx| + |dfy| + |dcx| + |dcy|) / 2 px.
A calibration fails when it raises, returns non-finite values or has E_IP > 20 px; mean and variance of E_IP are
over each method's successful trials.

    python -m ccs_kornia.bench.micro.fisheye_synthetic --trials 50 --views 15 --noise 0.1
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from ccs_kornia.bench.methods.fisheye_opencv import opencv_fisheye
from ccs_kornia.bench.scenes.fisheye_data import random_board_views, random_kb_cameras
from ccs_kornia.modules.calibration.fisheye_calibration import calibrate_fisheye


def e_ip(K, K_true):
    return 0.5 * float(abs(K[0, 0] - K_true[0, 0]) + abs(K[1, 1] - K_true[1, 1]) + abs(K[0, 2] - K_true[0, 2])
                       + abs(K[1, 2] - K_true[1, 2]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--views", type=int, default=15)
    ap.add_argument("--noise", type=float, default=0.1)
    ap.add_argument("--fov", type=float, nargs=2, default=[120.0, 200.0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fail", type=float, default=20.0, help="E_IP (px) above which a calibration counts as failed")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu", help="device of ccs_kornia's solve (OpenCV runs on the CPU)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    import cv2

    cv2.setNumThreads(a.threads)
    size = (640, 480)
    K, D = random_kb_cameras(a.trials, tuple(a.fov), size, seed=a.seed)
    rv, tv, uv, obj = random_board_views(K, D, a.views, image_size=size, seed=a.seed)
    g = torch.Generator().manual_seed(a.seed + 7)
    uv = uv + a.noise * torch.randn(uv.shape, generator=g, dtype=torch.float64)
    from ccs_kornia.geometry.camera import transform_points_rt

    Xc = transform_points_rt(obj, rv, tv)
    theta = torch.atan2(Xc[..., :2].norm(dim=-1), Xc[..., 2]).amax(-1)
    print(f"{a.trials} cameras x {a.views} views, noise {a.noise} px; views reaching beyond 90 deg: "
          f"{int((theta > np.pi / 2).sum())}, beyond 75 deg: {int((theta > np.radians(75)).sum())}")

    t = time.perf_counter()
    res = calibrate_fisheye(uv.to(a.device), None, obj.to(a.device), size)
    res = type(res)(**{k: v.cpu() for k, v in res.__dict__.items()})
    t_ours = time.perf_counter() - t
    ours = [e_ip(res.K[c], K[c]) if bool(res.success[c]) else float("inf") for c in range(a.trials)]

    t = time.perf_counter()
    cv, cv_err, cv_views = [], [], []
    for c in range(a.trials):
        r = opencv_fisheye(obj.numpy(), [uv[c, v].numpy() for v in range(a.views)], size)
        cv.append(e_ip(r["K"], K[c].numpy()) if r["ok"] else float("inf"))
        cv_err.append(r["error"])
        cv_views.append(len(r["used"]))
    t_cv = time.perf_counter() - t

    def summary(name, e, secs):
        e = np.array(e)
        ok = e <= a.fail
        print(f"{name:28s} failures {int((~ok).sum()):3d}/{len(e)}  E_IP mean {e[ok].mean():.4f} var {e[ok].var():.5f} "
              f"median {np.median(e[ok]):.4f} max {e[ok].max():.3f} px   {secs:.1f} s")

    summary("ccs_kornia calibrate_fisheye", ours, t_ours)
    summary("cv2.fisheye.calibrate", cv, t_cv)
    print(f"ccs_kornia views used: mean {float(res.used.sum(-1).double().mean()):.2f}; cv2 views used: mean {np.mean(cv_views):.2f}")
    errs = [e for e in cv_err if e]
    if errs:
        print("cv2 failure reasons:", sorted(set(errs))[:5])


if __name__ == "__main__":
    main()
