"""Video in, on a generated hand-held recording: screening frames/s, ``calibrate video.mp4`` end to end, peak memory.

A recording of a known camera (1280x720, 30 frames/s, a minute by default) is generated first: a chessboard swept
through tilts and positions by a hand that pauses now and then, with stretches where the board is out of view;
written with OpenCV's FFmpeg writer (MPEG-4 part 2: the codec OpenCV can write here; H.264 decodes at a similar
rate). Then:

1. the screening pass alone (:func:`~ccs_kornia.pipeline.screening.screen_video`, ``--jobs`` processes): frames/s;
2. ``python -m ccs_kornia calibrate video.mp4`` as a user runs it (learned detector, ``--model auto``, diagnostics):
   wall time, the console's figures, and the peak memory of the command's processes together (the sum of their
   proportional set sizes, sampled every 50 ms; and the largest single process's peak RSS);
3. the calibration against the generated camera.

    python -m ccs_kornia.bench.micro.video                      # 1280x720, 60 s at 30 fps, 2 processes
    python -m ccs_kornia.bench.micro.video --seconds 10 --jobs 1
    python -m ccs_kornia.bench.micro.video --video rec.mp4 --board 9x6   # an existing recording (no truth)

Timings depend on the machine's load: measure on idle cores.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time

import cv2
import numpy as np

BOARD = (9, 6)
SQUARE = 0.025
K_TRUE = np.array([[900.0, 0.0, 639.5], [0.0, 900.0, 359.5], [0.0, 0.0, 1.0]])
DIST_TRUE = np.array([-0.12, 0.05, 0.0, 0.0, 0.0])


def _board_texture(px: int = 60) -> tuple[np.ndarray, np.ndarray]:
    cols, rows = BOARD
    squares = (np.indices((rows + 1, cols + 1)).sum(0) % 2) * 255
    board = cv2.copyMakeBorder(np.kron(squares, np.ones((px, px))).astype(np.uint8), px, px, px, px,
                               cv2.BORDER_CONSTANT, value=255)
    s = px / SQUARE
    return board, np.array([[s, 0.0, px - 0.5], [0.0, s, px - 0.5], [0.0, 0.0, 1.0]])


def _hand(t: float, rng_phase: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Board pose at ``t`` seconds: sweeps with pauses (the hand holds still for a second every four), out of view
    for two seconds every fifteen."""
    cycle = t % 4.0
    held = t - cycle + min(cycle, 3.0)  # time stands still in the last second of every four
    u = held / 4.0
    rx = 0.6 * math.sin(0.9 * u + rng_phase[0]) * math.cos(0.37 * u)
    ry = 0.6 * math.sin(1.3 * u + rng_phase[1])
    rz = 0.35 * math.sin(0.7 * u + rng_phase[2])
    R, _ = cv2.Rodrigues(np.array([rx, ry, rz]))
    centre = np.array([(BOARD[0] + 1) * SQUARE / 2, (BOARD[1] + 1) * SQUARE / 2, 0.0])
    target = np.array([0.16 * math.sin(1.1 * u + rng_phase[3]), 0.09 * math.sin(0.8 * u + rng_phase[4]),
                       0.55 + 0.12 * math.sin(0.5 * u)])
    return R, target - R @ centre, (t % 15.0) < 13.0


def generate(path: str, seconds: float, fps: float = 30.0, size: tuple[int, int] = (1280, 720), seed: int = 0) -> int:
    """Write the recording (with the lens's distortion applied by a remap); returns its frame count."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * math.pi, 5)
    w, h = size
    texture, to_texture = _board_texture()
    background = cv2.GaussianBlur(rng.uniform(60, 190, (h, w)).astype(np.float32), (0, 0), 4)
    # distorted image pixel -> undistorted pixel: the renderer warps into the pinhole image, then the remap distorts
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    pinhole = cv2.undistortPoints(grid, K_TRUE, DIST_TRUE, P=K_TRUE).reshape(h, w, 2).astype(np.float32)
    out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not out.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path}")
    n = int(round(seconds * fps))
    for k in range(n):
        R, t, visible = _hand(k / fps, phase)
        frame = background
        if visible:
            H = K_TRUE @ np.column_stack([R[:, 0], R[:, 1], t]) @ np.linalg.inv(to_texture)
            warped = cv2.warpPerspective(texture.astype(np.float32), H, (w, h), flags=cv2.INTER_LINEAR,
                                         borderValue=-1.0)
            frame = np.where(warped >= 0, warped, background)
        frame = cv2.remap(frame, pinhole[..., 0], pinhole[..., 1], cv2.INTER_LINEAR)
        noise = rng.normal(0, 2.0, frame.shape).astype(np.float32)
        out.write(cv2.cvtColor(np.clip(frame + noise, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    out.release()
    return n


def _tree(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as handle:
                    todo.extend(int(c) for c in handle.read().split())
        except OSError:
            pass
    return out


def _pss_mb(pids: list[int]) -> float:
    total = 0
    for p in pids:
        try:
            with open(f"/proc/{p}/smaps_rollup") as handle:
                for line in handle:
                    if line.startswith("Pss:"):
                        total += int(line.split()[1])
                        break
        except OSError:
            pass
    return total / 1024.0


def run_command(argv: list[str]) -> tuple[int, float, float, str]:
    """Run the command line; ``(exit status, wall s, peak PSS of its process tree in MB, output)``."""
    env = dict(os.environ)
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "ccs_kornia", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env)
    peak = [0.0]

    def sample() -> None:
        while proc.poll() is None:
            peak[0] = max(peak[0], _pss_mb(_tree(proc.pid)))
            time.sleep(0.05)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    output, _ = proc.communicate()
    sampler.join()
    return proc.returncode, time.perf_counter() - start, peak[0], output


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0, help="length of the generated recording (default 60)")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--video", default=None, help="an existing recording instead of the generated one")
    p.add_argument("--board", default=f"{BOARD[0]}x{BOARD[1]}")
    p.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    p.add_argument("--keep", default=None, help="folder to keep the recording and the JSON in")
    a = p.parse_args(argv)
    folder = a.keep or tempfile.mkdtemp(prefix="ccs_video_bench_")
    os.makedirs(folder, exist_ok=True)
    video = a.video
    if video is None:
        video = os.path.join(folder, f"handheld_{int(a.seconds)}s.mp4")
        if not os.path.exists(video):
            t = time.perf_counter()
            n = generate(video, a.seconds, a.fps)
            print(f"generated {video}: {n} frames 1280x720 at {a.fps:g} fps in {time.perf_counter() - t:.1f} s")
    from ccs_kornia.io.boards import parse_board
    from ccs_kornia.modules.detection.screening import BoardScreen
    from ccs_kornia.pipeline.screening import screen_video

    board = parse_board(a.board)
    t = time.perf_counter()
    seen = screen_video(video, BoardScreen(board), workers=a.jobs)
    dt = time.perf_counter() - t
    print(f"screening: {len(seen.frames)} frames in {dt:.1f} s = {len(seen.frames) / dt:.1f} frames/s "
          f"({a.jobs} processes), board seen in {seen.found}; this process's peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    out = os.path.join(folder, "calib.json")
    argv_cmd = ["calibrate", video, "--board", a.board, "--square", str(SQUARE), "--jobs", str(a.jobs),
                "--output", out]
    code, wall, pss, text = run_command(argv_cmd)
    largest = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"calibrate end to end: {wall:.1f} s (exit {code}); peak memory {pss:.0f} MB (PSS of its processes together), "
          f"largest process {largest:.0f} MB RSS")
    for line in text.splitlines():
        if "\r" not in line and line.strip():
            print("  | " + line)
    if code == 0:
        import json

        data = json.load(open(out))
        screening = sum(v["screening_s"] for v in data["video"])
        print(f"  of which: screening {screening:.1f} s, detection and solve {data['timings']['load_detect_solve_s']:.1f} "
              f"s, the command's own total {data['timings']['total_s']:.1f} s (the rest: starting Python and torch)")
    if code == 0 and a.video is None:
        K = np.array(data["K"])
        e_fl = abs(K[0, 0] - K_TRUE[0, 0]) + abs(K[1, 1] - K_TRUE[1, 1])
        e_pp = abs(K[0, 2] - K_TRUE[0, 2]) + abs(K[1, 2] - K_TRUE[1, 2])
        print(f"against the generated camera: E_FL {e_fl:.2f} px, E_PP {e_pp:.2f} px, model "
              f"{data['distortion']['model']}, {data['num_views']['used']} views used of "
              f"{len(data['views'])} detected")


if __name__ == "__main__":
    main()
