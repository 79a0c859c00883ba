"""Random inputs for the command line's contract (``test_cli_fuzz.py``): random bytes as images and videos, damaged
and tiny real ones, random pose files and random option values, each case in its own folder.

Run as a program, it runs every case of a seed in this one process and writes one JSON line per case (the command,
its exit status, what it printed on stderr, the folder's files before and after) to a file: a case that kills the
process (a signal) is named by the last line started.

    python tests/commands/_fuzz_cli.py SEED CASES FOLDER OUT.jsonl
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import random
import sys

import cv2
import numpy as np

#: option values a new user may type, good and bad
VALUES = {
    "--board": ["9x6", "6x4", "3x3", "0x0", "9x", "x6", "-1x5", "100x100", "9*6", ""],
    "--square": ["0.025", "1", "0", "-1", "nan", "inf", "1e-300", "1e300", "abc"],
    "--max-frames": ["1", "3", "0", "-3", "99999999999999999999"],
    "--every": ["1", "2", "0", "-1", "x"],
    "--start": ["0", "0.5", "-1", "1e9", "nan"],
    "--end": ["0", "0.2", "1e9", "-2"],
    "--model": ["auto", "k1k2", "fisheye", "none", "bogus"],
    "--batch-size": ["1", "2", "0", "-1"],
    "--max-detection-side": ["0", "16", "64", "-5", "x"],
    "--seed": ["0", "7", "-1", "x"],
    "--pose-format": ["auto", "quat", "quat-wxyz", "rotvec", "matrix", "euler"],
    "--pose-units": ["m", "mm", "km"],
    "--balance": ["0", "1", "0.5", "2", "nan"],
    "--alpha": ["0", "1", "-1"],
    "--pair": ["0,1", "1,0", "0,0", "5,6", "x"],
}
#: the options each command takes from :data:`VALUES` (beside its inputs and outputs)
OPTIONS = {
    "detect": ["--board", "--square", "--max-frames", "--every", "--start", "--end", "--batch-size",
               "--max-detection-side"],
    "calibrate": ["--board", "--square", "--max-frames", "--every", "--start", "--end", "--model", "--batch-size",
                  "--max-detection-side", "--seed"],
    "calibrate-rig": ["--board", "--square", "--max-frames", "--every", "--model", "--seed", "--pair"],
    "calibrate-hand-eye": ["--board", "--square", "--pose-format", "--pose-units", "--model"],
    "undistort": ["--balance"],
    "rectify": ["--alpha", "--pair"],
}
FAST = ["--detector", "opencv", "--jobs", "1", "--no-distortion-correction"]


def _board_image(rng: random.Random, squares=(7, 5), side: int = 12) -> np.ndarray:
    board = np.kron((np.indices(squares[::-1]).sum(0) % 2).astype(np.uint8) * 255, np.ones((side, side), np.uint8))
    image = np.pad(board, 16, constant_values=255)
    return np.roll(image, (rng.randrange(4), rng.randrange(4)), axis=(0, 1))


def _image_bytes(rng: random.Random, ext: str) -> bytes:
    """An image file's bytes: random, a real image (noise or a board), a damaged or cut one, or nothing."""
    kind = rng.choice(["random", "noise", "board", "board", "board", "board", "damaged", "cut", "empty", "tiny",
                       "header"])
    if kind == "random":
        return rng.randbytes(rng.randrange(1, 2000))
    if kind == "empty":
        return b""
    if kind == "header":  # a PNG header and garbage
        return b"\x89PNG\r\n\x1a\n" + rng.randbytes(rng.randrange(0, 200))
    if kind == "tiny":
        image = np.full((rng.randrange(1, 9), rng.randrange(1, 9)), 128, np.uint8)
    elif kind == "noise":
        image = np.frombuffer(rng.randbytes(48 * 64), np.uint8).reshape(48, 64)
    else:
        image = _board_image(rng)
    _, buf = cv2.imencode(ext if ext in (".png", ".jpg", ".bmp") else ".png", image)
    data = bytearray(buf.tobytes())
    if kind == "damaged" and len(data) > 80:
        at = rng.randrange(40, len(data) - 20)
        data[at:at + 16] = rng.randbytes(16)
    if kind == "cut":
        data = data[:rng.randrange(1, len(data))]
    return bytes(data)


def _video(rng: random.Random, path: str) -> None:
    """A video file: random bytes, a short real recording of a board, or one cut short."""
    kind = rng.choice(["random", "real", "cut"])
    if kind == "random":
        with open(path, "wb") as handle:
            handle.write(rng.randbytes(rng.randrange(1, 4000)))
        return
    frames = [cv2.cvtColor(np.pad(_board_image(rng), ((0, 4), (0, 4)), constant_values=255), cv2.COLOR_GRAY2BGR)
              for _ in range(rng.randrange(2, 6))]
    h, w = frames[0].shape[:2]
    out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), rng.choice([5.0, 10.0, 0.5]), (w, h))
    for frame in frames:
        out.write(frame)
    out.release()
    if kind == "cut" and os.path.getsize(path) > 10:
        with open(path, "rb") as handle:
            data = handle.read()
        with open(path, "wb") as handle:
            handle.write(data[:rng.randrange(1, len(data))])


def _inputs(rng: random.Random, folder: str, name: str, video: bool | None = None) -> str:
    """A folder of random image files, or one video (``video``; ``None``: one in four), for one camera."""
    os.makedirs(folder)
    if (rng.random() < 0.25) if video is None else video:
        path = os.path.join(folder, f"{name}.avi")
        _video(rng, path)
        return path
    for k in range(rng.randrange(0, 7)):
        ext = rng.choice([".png", ".jpg", ".bmp", ".tif"])
        with open(os.path.join(folder, f"{name}{k:02d}{ext}"), "wb") as handle:
            handle.write(_image_bytes(rng, ext))
    return folder


def _poses(rng: random.Random, path: str, names: list[str]) -> None:
    """A pose file: rows of random numbers (any count, NaN, huge), a header or not, names that match or not."""
    rows = ["image,x,y,z,qx,qy,qz,qw"] if rng.random() < 0.5 else []
    for name in names + ["other.png"] * rng.randrange(0, 2):
        count = rng.choice([6, 7, 7, 16, 3])
        values = [rng.choice([f"{rng.uniform(-2, 2):.6g}", "nan", "1e308", "x"]) if rng.random() < 0.1 else
                  f"{rng.uniform(-1, 1):.6g}" for _ in range(count)]
        rows.append(",".join([name, *values]))
    if rng.random() < 0.1:
        rows = [rng.randbytes(40).decode("latin-1")]
    with open(path, "w", encoding="utf-8", errors="surrogateescape") as handle:
        handle.write("\n".join(rows) + "\n")


def _calibration(rng: random.Random, path: str) -> None:
    if rng.random() < 0.15:
        with open(path, "wb") as handle:
            handle.write(rng.randbytes(rng.randrange(0, 100)))
        return
    f = rng.choice([100.0, 100.0, 100.0, 0.0, -5.0, float("nan")])
    size = rng.choice([[116, 92], [116, 92], [64, 48]])  # the board images' size, or another
    data = {"K": [[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]], "image_size": size,
            "distortion": {"model": rng.choice(["k1k2", "k1k2", "opencv5", "fisheye", "bogus"]),
                           "coeffs": [0.0] * (4 if rng.random() < 0.2 else 5)}}
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(json.dumps(data).replace("NaN", "null"))


def make_case(seed: int, root: str) -> tuple[list[str], list[str]]:
    """One case's arguments and the outputs it names (files and folders), its inputs written under ``root``."""
    rng = random.Random(seed)
    command = rng.choice(list(OPTIONS))
    out = os.path.join(root, "out")
    os.makedirs(out)
    named: list[str] = []
    if command in ("detect", "calibrate", "undistort"):
        argv = [command, _inputs(rng, os.path.join(root, "a"), "a")]
    elif command == "calibrate-hand-eye":
        folder = _inputs(rng, os.path.join(root, "a"), "a")
        names = sorted(os.listdir(folder)) if os.path.isdir(folder) else [os.path.basename(folder)]
        _poses(rng, os.path.join(root, "poses.csv"), names)
        argv = [command, folder, "--robot-poses", os.path.join(root, "poses.csv"),
                rng.choice(["--eye-in-hand", "--eye-to-hand"])]
    else:
        video = rng.random() < 0.3  # a rig of recordings, or of folders
        argv = [command, _inputs(rng, os.path.join(root, "a"), "a", video),
                _inputs(rng, os.path.join(root, "b"), "b", video)]
    if command in ("undistort", "rectify"):
        _calibration(rng, os.path.join(root, "calib.json"))
        named.append(os.path.join(out, "images"))
        argv += ["--calibration", os.path.join(root, "calib.json"), "--out-dir", named[-1]]
    else:
        argv += FAST
        if "--board" not in argv:
            argv += ["--board", rng.choice(["6x4", "4x6", "6x4", "9x6"])]
        named.append(os.path.join(out, rng.choice(["c.json", "same"])))
        argv += ["--output", named[-1]]
        if command == "calibrate":
            argv += ["--no-diagnostics"]
            for option in ("--report", "--opencv-yaml"):
                if rng.random() < 0.3:  # sometimes the same path as --output
                    named.append(named[0] if rng.random() < 0.3 else os.path.join(out, option[2:]))
                    argv += [option, named[-1]]
    for option in rng.sample(OPTIONS[command], min(len(OPTIONS[command]), rng.choice([0, 0, 1, 2]))):
        argv += [option, rng.choice(VALUES[option])]
    if rng.random() < 0.1:
        argv += [rng.choice(["--bogus", "--outpt", "extra"])]
    return argv, named


def snapshot(root: str) -> dict[str, str]:
    """Every file under ``root`` and its content's hash (folders as ``"dir"``)."""
    out = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs:
            out[os.path.join(folder, name)] = "dir"
        for name in files:
            path = os.path.join(folder, name)
            with open(path, "rb") as handle:
                out[path] = hashlib.sha1(handle.read()).hexdigest()
    return out


def run_cases(seed: int, cases: int, base: str, report: str) -> None:
    from ccs_kornia import cli

    with open(report, "w", encoding="utf-8") as log:
        for k in range(cases):
            root = os.path.join(base, f"case{k:03d}")
            os.makedirs(root)
            argv, named = make_case(seed * 100_003 + k, root)
            before = snapshot(root)
            log.write(json.dumps({"case": k, "argv": argv, "started": True}) + "\n")
            log.flush()
            err, out = io.StringIO(), io.StringIO()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                code = cli.main(argv)
            log.write(json.dumps({"case": k, "argv": argv, "named": named, "code": code, "stderr": err.getvalue(),
                                  "before": before, "after": snapshot(root)}) + "\n")
            log.flush()


if __name__ == "__main__":
    run_cases(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4])
