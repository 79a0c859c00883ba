"""``python -m ccs_kornia.bench`` (and ``python -m ccs_kornia bench``): run the benchmarks.

    python -m ccs_kornia bench                     # full run (~45 min on 2 cores)
    python -m ccs_kornia bench --quick             # smoke run of every section (~130 s on 2 cores)
    python -m ccs_kornia bench --sections corners speed --out /tmp/bench
    python -m ccs_kornia bench --markdown docs/benchmarks.md
    python -m ccs_kornia bench --quick --sections wild    # detection in the wild (~40 s on 2 cores)
    python -m ccs_kornia bench --sections video           # recordings: the frames chosen (about 15 min on 2 cores)
    python -m ccs_kornia bench --sections real_poor       # the real sets made poor (dark, blur, small, JPEG)
    python -m ccs_kornia bench --sections action_camera   # an action camera's large ChArUco board made poor
    python -m ccs_kornia bench --sections hand_eye        # hand-eye: rendered robots against OpenCV, and a real robot
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Sequence

# sleeping OpenMP waits: see ccs_kornia/__main__.py (only effective when torch is not loaded yet)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__all__ = ["main", "build_parser"]


def build_parser(prog: str = "python -m ccs_kornia bench") -> argparse.ArgumentParser:
    from ccs_kornia.bench.config import METHODS, SECTIONS

    p = argparse.ArgumentParser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="smoke run of every section: one or two images, trials or sets each (~130 s on 2 cores)")
    size.add_argument("--tiny", action="store_true", help="the smallest run that touches every section (tests)")
    p.add_argument("--out", default="bench_results", help="output folder for results.json, report.md, box plot")
    p.add_argument("--markdown", default=None, help="also write the markdown report here (e.g. docs/benchmarks.md)")
    p.add_argument("--sections", nargs="+", choices=SECTIONS, default=None, help="sections to run (default: all)")
    p.add_argument("--methods", nargs="+", choices=tuple(METHODS), default=None, help="detection methods")
    p.add_argument("--corner-images", type=int, default=None, help="images per condition, corner section")
    p.add_argument("--calib-trials", type=int, default=None, help="trials per condition, calibration section")
    p.add_argument("--calib-views", type=int, default=None, help="views per trial")
    p.add_argument("--calib-pool-views", type=int, default=None, help="views rendered per camera (>= --calib-views)")
    p.add_argument("--calib-conditions", nargs="+", default=None,
                   help="conditions of the calibration section (default: preset's)")
    p.add_argument("--calib-trials-per-camera", type=int, default=None, help="trials drawn from one camera's pool")
    p.add_argument("--real-subsets", type=int, default=None, help="random view subsets per real set")
    p.add_argument("--real-sets", nargs="+", default=None, help="names of the real sets to run (default: preset's)")
    p.add_argument("--real-max-images", type=int, default=None, help="at most this many images per real set")
    p.add_argument("--real-dir", default=None, help="folder of the real sets (default: ../shared/data/real)")
    p.add_argument("--dc-trials", type=int, default=None, help="trials of the distortion-correction section")
    p.add_argument("--distortion-weights", default=None, help="DistortionNet export (default: shipped weights)")
    p.add_argument("--wild-images", type=int, default=None, help="images per condition, wild section")
    p.add_argument("--wild-big-images", type=int, default=None, help="images per wild condition of 4 Mpx and more")
    p.add_argument("--wild-free-images", type=int, default=None, help="board-free images, wild section")
    p.add_argument("--wild-real-images", type=int, default=None, help="images per real set and scale, wild section")
    p.add_argument("--wild-time-limit", type=float, default=None, help="seconds a peer may spend on one wild image")
    p.add_argument("--wild-conditions", nargs="+", default=None, help="wild conditions to run (default: all)")
    p.add_argument("--wild-real-scales", nargs="+", type=float, default=None, help="rescaling of the real photos")
    p.add_argument("--markers-views", type=int, default=None, help="ChArUco renders per condition, markers section")
    p.add_argument("--markers-aprilgrid-views", type=int, default=None,
                   help="AprilGrid renders per condition, markers section")
    p.add_argument("--video-recordings", type=int, default=None, help="rendered recordings of the video section")
    p.add_argument("--video-seconds", type=float, default=None, help="seconds of each rendered recording (30 fps)")
    p.add_argument("--real-poor-images", type=int, default=None,
                   help="images per set (per camera) of the real_poor section")
    p.add_argument("--real-poor-sets", nargs="+", default=None, help="real sets of the real_poor section")
    p.add_argument("--action-camera-views", type=int, default=None,
                   help="rendered views per condition of the action_camera section")
    p.add_argument("--hand-eye-trials", type=int, default=None, help="rendered robots per set-up, hand_eye section")
    p.add_argument("--hand-eye-kinematic-trials", type=int, default=None,
                   help="rendered arms with kinematic errors per set-up, hand_eye section")
    p.add_argument("--no-cuda", action="store_true", help="do not time CUDA even when present")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    return p


def main(argv: Sequence[str] | None = None, prog: str = "python -m ccs_kornia bench") -> int:
    """Entry point; returns 0 when every section ran, 1 when a section failed, 2 on bad arguments."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser(prog).parse_args(argv)
    except SystemExit as exit_:  # --help, or a bad argument (argparse has printed why)
        return exit_.code if isinstance(exit_.code, int) else 2
    import torch

    from ccs_kornia.bench.config import BenchConfig
    from ccs_kornia.bench.runner import run_bench
    from ccs_kornia.runtime.allocator import keep_freed_memory

    keep_freed_memory()  # as the command line runs (ccs_kornia/runtime/allocator.py)
    if args.threads:
        torch.set_num_threads(args.threads)
    overrides = {}
    for name in ("corner_images", "calib_trials", "calib_views", "calib_pool_views", "calib_trials_per_camera",
                 "real_subsets", "real_max_images", "real_dir", "dc_trials", "distortion_weights", "wild_images",
                 "wild_big_images", "wild_free_images", "wild_real_images", "markers_views", "markers_aprilgrid_views",
                 "hand_eye_trials", "hand_eye_kinematic_trials", "video_recordings", "real_poor_images",
                 "action_camera_views"):
        value = getattr(args, name)
        if value is not None:
            if isinstance(value, int) and value < 1:
                print(f"{prog}: error: --{name.replace('_', '-')} must be >= 1", file=sys.stderr)
                return 2
            overrides[name] = value
    if args.real_sets:
        overrides["real_sets"] = tuple(args.real_sets)
    if args.real_poor_sets:
        overrides["real_poor_sets"] = tuple(args.real_poor_sets)
    for name, kind in (("calib_conditions", "calibration"), ("wild_conditions", "wild")):
        asked = getattr(args, name)
        if not asked:
            continue
        if kind == "wild":
            from ccs_kornia.bench.sections.wild import WILD_CONDITIONS as known
        else:
            from ccs_kornia.bench.config import CALIB_CONDITIONS as known
        unknown = [c for c in asked if c not in known]
        if unknown:
            print(f"{prog}: error: unknown {kind} condition(s) {unknown}; expected some of {list(known)}", file=sys.stderr)
            return 2
        overrides[name] = tuple(asked)
    if args.wild_time_limit is not None:
        if args.wild_time_limit <= 0:
            print(f"{prog}: error: --wild-time-limit must be > 0", file=sys.stderr)
            return 2
        overrides["wild_time_limit"] = args.wild_time_limit
    if args.video_seconds is not None:
        if not args.video_seconds > 0:
            print(f"{prog}: error: --video-seconds must be > 0", file=sys.stderr)
            return 2
        overrides["video_seconds"] = args.video_seconds
    if args.wild_real_scales:
        overrides["wild_real_scales"] = tuple(args.wild_real_scales)
    if args.sections:
        overrides["sections"] = tuple(args.sections)
    if args.methods:
        overrides["methods"] = tuple(args.methods)
    if args.no_cuda:
        overrides["devices"] = ("cpu",)
    if "calib_views" in overrides and "calib_pool_views" not in overrides:
        overrides["calib_pool_views"] = overrides["calib_views"]
    preset = BenchConfig.tiny if args.tiny else BenchConfig.quick if args.quick else BenchConfig.full
    try:
        cfg = preset(**overrides)
        if cfg.calib_pool_views < cfg.calib_views:
            raise ValueError("--calib-pool-views must be >= --calib-views")
    except (TypeError, ValueError) as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    command = " ".join([prog, *map(shlex.quote, argv)])
    try:
        results = run_bench(cfg, args.out, command=command, markdown=args.markdown,
                            log=lambda msg: print(msg, file=sys.stderr, flush=True))
    except OSError as err:  # unwritable output folder or markdown path
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    failed = [name for name, sec in results["sections"].items() if "error" in sec]
    if failed:
        print(f"{prog}: error: section(s) failed: {', '.join(failed)} (see {args.out}/results.json)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main(prog="python -m ccs_kornia.bench"))
