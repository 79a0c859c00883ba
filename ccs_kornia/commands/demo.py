"""``ccs_kornia demo``: render a set with a known camera, calibrate it with the path of ``calibrate``, compare."""

from __future__ import annotations

import argparse
import os
import time

import torch

from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._messages import verdict_line
from ccs_kornia.commands._output_paths import make_dir
from ccs_kornia.commands._printing import info
from ccs_kornia.commands._run import calibrate_files
from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.metrics import e_fl, e_ip, e_pp
from ccs_kornia.geometry.models import OPENCV5
from ccs_kornia.io.files import write_json
from ccs_kornia.io.images import write_image
from ccs_kornia.outputs.report.calibration import write_report

__all__ = ["run", "DEMO_K", "DEMO_DIST", "DEMO_IMAGE_SIZE", "DEMO_BOARD", "DEMO_SQUARE"]

# the demo camera: independent fx/fy, off-centre principal point, strong barrel distortion
DEMO_K = ((620.0, 0.0, 322.0), (0.0, 610.0, 236.0), (0.0, 0.0, 1.0))
DEMO_DIST = (-0.28, 0.09, 0.0005, -0.0008, 0.0)
DEMO_IMAGE_SIZE = (640, 480)
DEMO_BOARD = (9, 6)
DEMO_SQUARE = 0.025


def run(args: argparse.Namespace) -> int:
    device = resolve_device(args.device)
    make_dir("--out-dir", args.out_dir)
    K_true = torch.tensor(DEMO_K, dtype=torch.float64)
    dist_true = torch.tensor(DEMO_DIST, dtype=torch.float64)
    info(f"rendering {args.views} views of a {DEMO_BOARD[0]}x{DEMO_BOARD[1]} board ({DEMO_IMAGE_SIZE[0]}x{DEMO_IMAGE_SIZE[1]}) ...")
    start = time.perf_counter()
    batch = make_calibration_set(
        K_true, DEMO_BOARD, DEMO_SQUARE, DEMO_IMAGE_SIZE, num_views=args.views, dist=dist_true, seed=args.seed, supersample=2
    )
    files = []
    for k in range(batch.images.shape[0]):
        path = os.path.join(args.out_dir, f"view_{k:02d}.png")
        write_image(path, batch.images[k, 0])
        files.append(path)
    render_s = time.perf_counter() - start
    write_json(
        os.path.join(args.out_dir, "ground_truth.json"),
        {
            "image_size": list(DEMO_IMAGE_SIZE), "K": K_true.tolist(),
            "distortion": {"model": str(OPENCV5), "coeffs": dist_true.tolist()},
            "board": list(DEMO_BOARD), "square": DEMO_SQUARE,
            "views": [{"path": f, "corners": batch.corners[k].tolist(), "rvec": batch.rvec[k].tolist(),
                       "tvec": batch.tvec[k].tolist()} for k, f in enumerate(files)],
        },
    )
    # the very path of `calibrate`, on the files just written
    pipeline = make_pipeline(argparse.Namespace(detector=args.detector, batch_size=8, jobs="auto",
                                                 distortion_correction=args.distortion_correction, diagnostics=True))
    output = os.path.join(args.out_dir, "calib.json")
    data, _ = calibrate_files("demo", files, DEMO_BOARD, DEMO_SQUARE, pipeline, device, OPENCV5, args.detector)
    data["device"] = str(device)
    data["success"] = True
    data["timings"]["render_s"] = render_s
    write_json(output, data)

    report_dir = os.path.join(args.out_dir, "report")
    make_dir("--out-dir", report_dir)
    write_report(report_dir, data)

    K_est = torch.tensor(data["K"], dtype=torch.float64)
    dist_est = data["distortion"]["coeffs"]
    rows = [
        ("fx", K_true[0, 0].item(), K_est[0, 0].item()),
        ("fy", K_true[1, 1].item(), K_est[1, 1].item()),
        ("cx", K_true[0, 2].item(), K_est[0, 2].item()),
        ("cy", K_true[1, 2].item(), K_est[1, 2].item()),
    ] + [(name, float(t), float(e)) for name, t, e in zip(("k1", "k2", "p1", "p2", "k3"), DEMO_DIST, dist_est)]
    print(f"{'param':>6} {'true':>12} {'estimated':>12} {'error':>11}")
    for name, t, e in rows:
        print(f"{name:>6} {t:12.5f} {e:12.5f} {e - t:+11.5f}")
    print(f"E_FL {float(e_fl(K_est, K_true)):.4f} px   E_PP {float(e_pp(K_est, K_true)):.4f} px   "
          f"E_IP {float(e_ip(K_est, K_true)):.4f} px   RMS {data['rms']:.4f} px "
          f"({data['num_views']['used']} of {args.views} views used)")
    line = verdict_line(data.get("diagnostics"))
    if line:
        print(line)
    print(f"wrote {len(files)} images, ground_truth.json, calib.json and report/index.html to {args.out_dir}")
    return 0
