"""Throughput of the synthetic chessboard renderer (images per second).

Renders random scenes with :class:`ccs_kornia.data.scenes.scenes.SyntheticChessboards` (random camera,
board, pose, distortion and textured background) in batches, for each image size, condition and
supersampling setting, and prints the images/s of the whole ``sample`` call and of the renderer alone.

    python -m ccs_kornia.bench.micro.bench_render                      # CPU, 480x480 and 640x480, batch 16
    python -m ccs_kornia.bench.micro.bench_render --device cuda --batch 64
"""

from __future__ import annotations

import argparse
import time

import torch

from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.data.scenes.sampling import sample_poses
from ccs_kornia.data.scenes.scenes import SyntheticChessboards


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _time(fn, device: str, repeats: int) -> tuple[float, float]:
    """Best wall-clock and process CPU seconds over ``repeats`` calls (after one warm-up call)."""
    fn()
    _sync(device)
    best, best_cpu = float("inf"), float("inf")
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        _sync(device)
        best, best_cpu = min(best, time.perf_counter() - t), min(best_cpu, time.process_time() - c)
    return best, best_cpu


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--sizes", nargs="+", default=["480x480", "640x480"])
    parser.add_argument("--conditions", nargs="+", default=["clean", "combined"])
    parser.add_argument("--supersample", nargs="+", type=int, default=[1, 2, 3, 4])
    parser.add_argument("--distortion", default="mixed", help="none|opencv|radial|mixed")
    parser.add_argument("--repeats", type=int, default=2, help="timed repeats (best is reported)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: leave torch's default)")
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    dev = args.device
    print(f"device={dev} threads={torch.get_num_threads()} batch={args.batch} distortion={args.distortion} "
          f"torch={torch.__version__} (best of {args.repeats})")
    print("img/s from wall-clock time; cpu ms/img is process CPU time (robust on a shared machine)")
    print(f"{'size':>8} {'condition':>10} {'ss':>3} {'sample img/s':>13} {'cpu ms/img':>11} {'render img/s':>13} {'cpu ms/img':>11}")
    for size in args.sizes:
        w, h = (int(v) for v in size.lower().split("x"))
        # renderer alone: one fixed camera, 9x6 board, poses drawn once
        K = torch.tensor([[0.8 * w, 0.0, (w - 1) / 2], [0.0, 0.8 * w, (h - 1) / 2], [0.0, 0.0, 1.0]])
        rvec, tvec = sample_poses(K, (9, 6), 0.025, (w, h), args.batch, torch.Generator().manual_seed(0))
        Kb, rvec, tvec = K.expand(args.batch, 3, 3).to(dev), rvec.to(dev), tvec.to(dev)
        for cond in args.conditions:
            for ss in args.supersample:
                data = SyntheticChessboards(image_size=(w, h), distortion=args.distortion, conditions=(cond,), supersample=ss)
                gen = torch.Generator().manual_seed(1)
                t_s, c_s = _time(lambda: data.sample(args.batch, gen, device=dev), dev, args.repeats)
                line = f"{size:>8} {cond:>10} {ss:>3} {args.batch / t_s:13.1f} {1000 * c_s / args.batch:11.1f}"
                if cond == args.conditions[0]:
                    t_r, c_r = _time(lambda: render_chessboard(Kb, rvec, tvec, (9, 6), 0.025, (w, h), supersample=ss), dev,
                                     args.repeats)
                    line += f" {args.batch / t_r:13.1f} {1000 * c_r / args.batch:11.1f}"
                print(line, flush=True)


if __name__ == "__main__":
    main()
