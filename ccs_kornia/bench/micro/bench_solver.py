"""Speed and accuracy of the batched calibration solver against a Python loop of cv2.calibrateCamera.

Synthetic cameras (independent fx, fy, cx, cy, OpenCV distortion), 15 random board poses each, 9x6 board;
corners exact or with Gaussian noise. Both solvers get the same corners; OpenCV with flags 0 (k1,k2,p1,p2,k3),
ours with model=OPENCV5. Prints wall times and E_IP (paper metric, px) side by side.

    python -m ccs_kornia.bench.micro.bench_solver --cameras 256 --views 15 --noise 0.1 [--device cuda] [--threads 1]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import axis_angle_to_rotation_matrix, project_points
from ccs_kornia.geometry.metrics import e_ip
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.calibration.solver import CalibrationSolver


def synthetic_cameras(
    num_cameras: int, num_views: int, noise: float, seed: int = 0, cols: int = 9, rows: int = 6, square: float = 0.03
):
    """Random cameras and board views; returns K (C,3,3), dist (C,5), obj (N,3), corners (C,V,N,2) float64."""
    g = torch.Generator().manual_seed(seed)
    dt = torch.float64

    def rand(*shape):
        return torch.rand(*shape, generator=g, dtype=dt)

    C, V = num_cameras, num_views
    fx = 450 + 500 * rand(C)
    fy = fx * (0.97 + 0.06 * rand(C))
    cx = 319.5 + 40 * (rand(C) - 0.5)
    cy = 239.5 + 40 * (rand(C) - 0.5)
    K = torch.zeros(C, 3, 3, dtype=dt)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, cx, cy, 1
    dist = torch.stack(
        [-0.3 * rand(C), 0.1 * rand(C), 2e-3 * (rand(C) - 0.5), 2e-3 * (rand(C) - 0.5), 0.02 * (rand(C) - 0.5)], -1
    )
    obj = board_object_points(cols, rows, square, dtype=dt)
    centre = obj.mean(0)
    axis = torch.nn.functional.normalize(torch.randn(C, V, 3, generator=g, dtype=dt), dim=-1)
    rvec = axis * (0.15 + 0.55 * rand(C, V))[..., None]
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(C, V, 3, 3)
    depth = (fx[:, None] / 500) * 0.45 * (0.8 + 0.5 * rand(C, V))
    offset = (rand(C, V, 2) - 0.5) * 0.1
    tvec = torch.cat([offset, depth[..., None]], -1) - R @ centre
    uv = project_points(
        obj.expand(C, V, -1, -1), K[:, None].expand(C, V, 3, 3), dist[:, None].expand(C, V, 5), rvec, tvec
    )
    uv = uv + noise * torch.randn(uv.shape, generator=g, dtype=dt)
    return K, dist, obj, uv


def opencv_loop(obj: torch.Tensor, uv: torch.Tensor, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    o = obj.numpy().astype(np.float32)
    pts = uv.numpy().astype(np.float32)
    Ks, rms = [], []
    for c in range(pts.shape[0]):
        r, K, _, _, _ = cv2.calibrateCamera(
            [o] * pts.shape[1], [p.reshape(-1, 1, 2) for p in pts[c]], image_size, None, None, flags=0
        )
        Ks.append(K)
        rms.append(r)
    return np.stack(Ks), np.array(rms)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, default=256)
    ap.add_argument("--views", type=int, default=15)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.1])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1, help="torch and OpenCV CPU threads (shared machine: 1)")
    ap.add_argument("--no-ransac", action="store_true")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    image_size = (640, 480)
    solver = CalibrationSolver(model=OPENCV5, use_ransac=not args.no_ransac)
    print(
        f"solver benchmark: {args.cameras} cameras x {args.views} views x 54 corners, device={args.device}, "
        f"threads={args.threads}, ransac={not args.no_ransac}, torch {torch.__version__}, OpenCV {cv2.__version__}"
    )
    # warm-up (allocator, lazy linalg init, CUDA context)
    K, dist, obj, uv = synthetic_cameras(4, args.views, 0.0, seed=123)
    warm_valid = torch.ones(uv.shape[:-1], dtype=torch.bool, device=args.device)
    solver(uv.to(args.device), warm_valid, obj.to(args.device), image_size)

    for noise in args.noise:
        K, dist, obj, uv = synthetic_cameras(args.cameras, args.views, noise, seed=1)
        valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
        uv_d, valid_d, obj_d = uv.to(args.device), valid.to(args.device), obj.to(args.device)
        t_ours, c_ours, t_cv, c_cv = [], [], [], []
        for _ in range(args.repeats):
            if args.device.startswith("cuda"):
                torch.cuda.synchronize()
            t0, c0 = time.perf_counter(), time.process_time()
            res = solver(uv_d, valid_d, obj_d, image_size)
            if args.device.startswith("cuda"):
                torch.cuda.synchronize()
            t_ours.append(time.perf_counter() - t0)
            c_ours.append(time.process_time() - c0)
            t0, c0 = time.perf_counter(), time.process_time()
            K_cv, rms_cv = opencv_loop(obj, uv, image_size)
            t_cv.append(time.perf_counter() - t0)
            c_cv.append(time.process_time() - c0)
        K_ours = res.K.cpu()
        eip_ours = e_ip(K_ours, K)
        eip_cv = e_ip(torch.from_numpy(K_cv), K)
        print(f"\nnoise sigma = {noise} px")
        print(
            f"  {'':28s}{'wall s':>10s}{'CPU s':>8s}{'calib/s':>10s}{'E_IP mean':>12s}{'E_IP std':>11s}"
            f"{'E_IP max':>11s}{'RMS mean':>11s}"
        )
        tb, tc = min(t_ours), min(t_cv)
        print(
            f"  {'ccs_kornia batched solver':28s}{tb:10.3f}{min(c_ours):8.2f}{args.cameras / tb:10.1f}"
            f"{eip_ours.mean():12.5f}{eip_ours.std():11.5f}{eip_ours.max():11.5f}{res.rms.cpu().mean():11.5f}"
        )
        print(
            f"  {'cv2.calibrateCamera loop':28s}{tc:10.3f}{min(c_cv):8.2f}{args.cameras / tc:10.1f}"
            f"{eip_cv.mean():12.5f}{eip_cv.std():11.5f}{eip_cv.max():11.5f}{rms_cv.mean():11.5f}"
        )
        print(
            f"  speed-up x{tc / tb:.2f} wall, x{min(c_cv) / min(c_ours):.2f} CPU (best of {args.repeats}); "
            f"success {int(res.success.sum())}/{args.cameras}; "
            f"views used {int(res.used.sum())}/{res.used.numel()}; "
            f"max |K_ours - K_cv| = {np.abs(K_ours.numpy() - K_cv).max():.2e} px"
        )


if __name__ == "__main__":
    main()
