"""Speed of the recording renderer: a hand-held board filmed by a webcam (or a rig of webcams), frames per second.

Builds :func:`~ccs_kornia.data.recordings.recordings.handheld_recording` (or :func:`~ccs_kornia.data.recordings.recordings.handheld_rig_recording`
with ``--cameras N``), computes its ground truth, then renders its frames one at a time (optionally into a video
file) and prints the wall-clock and process CPU seconds per frame, the time for the whole recording, the
sub-exposures the motion blur needed, the share of each frame rendered (the board's box) and the peak resident
memory. The wall-clock figures depend on what else the machine runs; the CPU figures less so.

    python -m ccs_kornia.bench.micro.bench_recordings                            # one minute, 1280x720, chessboard
    python -m ccs_kornia.bench.micro.bench_recordings --frames 300 --board charuco
    python -m ccs_kornia.bench.micro.bench_recordings --write /tmp/rec.mp4         # with the video encoding
    python -m ccs_kornia.bench.micro.bench_recordings --cameras 3 --size 640x480 --write /tmp/rig
"""

from __future__ import annotations

import os

# sleeping OpenMP waits: on shared cores a spinning pool stalls every small tensor op (read when torch loads)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import resource
import time
from pathlib import Path

import torch

from ccs_kornia.data.recordings import exposure
from ccs_kornia.data.recordings.patterns import ChessPattern, TexturePattern
from ccs_kornia.data.recordings.recordings import (
    handheld_recording,
    handheld_rig_recording,
    webcam,
    webcam_rig,
)


def _pattern(name: str):
    if name == "chessboard":
        return ChessPattern(9, 6, 0.03)
    from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard

    if name == "charuco":
        return TexturePattern(CharucoBoard(7, 5, 0.04, 0.03, "DICT_4X4_50"))
    return TexturePattern(AprilGrid(6, 4, 0.04, 0.3))


def _box_share(rec, index: int) -> float:
    w, h = rec.camera.image_size
    box = exposure._board_box(rec.camera, rec.pattern, rec.trajectory, float(rec.frame_start[index]), 3.0)
    return 0.0 if box is None else (box[1] - box[0]) * (box[3] - box[2]) / (w * h)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds recorded")
    parser.add_argument("--size", default="1280x720", help="WxH")
    parser.add_argument("--board", choices=("chessboard", "charuco", "aprilgrid"), default="chessboard")
    parser.add_argument("--cameras", type=int, default=1, help="webcams in a rig (1: a single camera)")
    parser.add_argument("--frames", type=int, default=None, help="render only the first N frames of each camera")
    parser.add_argument("--supersample", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write", default=None, help="a video file (one camera) or a folder (a rig) to write")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    w, h = (int(v) for v in args.size.lower().split("x"))
    pattern = _pattern(args.board)
    t0, c0 = time.perf_counter(), time.process_time()
    if args.cameras > 1:
        rig = handheld_rig_recording(webcam_rig(args.cameras, (w, h), seed=args.seed), pattern, args.duration,
                                     args.seed, supersample=args.supersample)
        recs = rig.recordings
    else:
        rig = None
        recs = [handheld_recording(webcam((w, h), seed=args.seed), pattern, args.duration, args.seed,
                                   supersample=args.supersample)]
    for rec in recs:
        _ = rec.truth, rec.background, rec.camera.rays
    setup, setup_cpu = time.perf_counter() - t0, time.process_time() - c0
    total = sum(len(r) for r in recs)
    print(f"{len(recs)} camera(s) {w}x{h}, {args.board}, {args.duration:g} s: {total} frames; trajectory, truth, "
          f"backgrounds and rays {setup:.1f} s wall ({setup_cpu:.1f} s CPU); torch threads {args.threads}")
    n = min(len(r) for r in recs) if args.frames is None else min(args.frames, min(len(r) for r in recs))
    t0, c0 = time.perf_counter(), time.process_time()
    if args.write:
        from ccs_kornia.data.recordings import recording_files

        if rig is not None and args.frames is None:
            recording_files.write_rig_recording(rig, args.write)
        elif rig is None and args.frames is None:
            recording_files.write_recording(recs[0], args.write)
        else:
            for c, rec in enumerate(recs):
                path = Path(args.write) if rig is None else Path(args.write) / f"cam_{c}.mp4"
                path.parent.mkdir(parents=True, exist_ok=True)
                recording_files.write_video((img for _, img in rec.frames(0, n)), path, rec.camera.fps,
                                            rec.camera.image_size)
    else:
        for rec in recs:
            for _ in rec.frames(0, n):
                pass
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    done = n * len(recs)
    full = sum(len(r) for r in recs)
    sub = torch.cat([r.truth.subframes[:n] for r in recs])
    share = [_box_share(r, i) for r in recs for i in range(0, n, max(1, n // 100))]
    print(f"rendered {done} frames{' and wrote them' if args.write else ''}: {wall / done * 1e3:.1f} ms wall, "
          f"{cpu / done * 1e3:.1f} ms CPU per frame ({done / wall:.1f} frames/s wall)")
    print(f"the whole recording ({full} frames) at that rate: {full * wall / done / 60:.1f} min wall, "
          f"{full * cpu / done / 60:.1f} min CPU")
    hist = torch.bincount(sub)
    print("sub-exposures per frame: " + ", ".join(f"{k}: {int(v)}" for k, v in enumerate(hist.tolist()) if v)
          + f" (mean {sub.double().mean():.2f})")
    print(f"share of the image rendered (the board's box): median {sorted(share)[len(share) // 2]:.2f}, "
          f"max {max(share):.2f}")
    print(f"peak resident memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
