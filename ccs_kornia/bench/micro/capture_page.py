"""Frame rate of ``capture``'s live loop and page at 720p on this machine's CPU.

A 1280x720 recording of a chessboard (9x6 inner corners, held still at hand-held poses and moved between them) is
rendered, then each frame goes
through what ``capture`` does with it: the guided capture's look (:class:`~ccs_kornia.pipeline.guided_capture.
GuidedCapture`: the screen, the gates, the corners and the solve of a frame it keeps), the annotated frame and its JPEG
for the page (:class:`~ccs_kornia.outputs.capture_page.CapturePage`), while a client reads the page's MJPEG stream.
Printed: frames per second processed, frames per second the client received, and the time from a frame's arrival to
its JPEG on the page (median and 95th percentile, ms).

    python -m ccs_kornia.bench.micro.capture_page [--frames 300] [--detector opencv]
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
import urllib.request

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import K1K2, PINHOLE
from ccs_kornia.modules.calibration.quality.next_pose import place_board
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.outputs.capture_page import CapturePage, annotate
from ccs_kornia.pipeline.guided_capture import GuidedCapture

SIZE = (1280, 720)
BOARD = (9, 6)


def render(num: int, seed: int = 0) -> list[np.ndarray]:
    """Grey 1280x720 frames of a 10x7-square chessboard (25 mm squares) seen by a pinhole camera (fx 1000): held still
    for 10 frames at a random hand-held pose (:func:`~ccs_kornia.modules.calibration.quality.next_pose.place_board`:
    centre in the middle half of the image, 30-50 % of the width, tilted up to 35 degrees about each axis),
    then 5 frames moving to the next."""
    rng = np.random.default_rng(seed)
    square, px = 0.025, 40  # texture pixels per square
    cols, rows = BOARD
    board = np.kron((np.indices((rows + 1, cols + 1)).sum(0) % 2) * 200 + 30, np.ones((px, px))).astype(np.float32)
    board = cv2.copyMakeBorder(board, px, px, px, px, cv2.BORDER_CONSTANT, value=230)
    s = px / square  # the first inner corner (square, square) at texture pixel 2 px - 0.5
    to_texture = np.array([[s, 0.0, px - 0.5], [0.0, s, px - 0.5], [0.0, 0.0, 1.0]])
    K = np.array([[1000.0, 0.0, 639.5], [0.0, 1000.0, 359.5], [0.0, 0.0, 1.0]])
    camera = Camera(PINHOLE, torch.tensor([1000.0, 1000.0, 639.5, 359.5], dtype=torch.float64), SIZE)
    obj = board_object_points(cols, rows, square, dtype=torch.float64) + square  # the texture's corner at (0, 0)
    count = num // 15 + 2
    u = torch.from_numpy(rng.uniform(0, 1, (count, 5)))
    pixels = torch.stack([(0.25 + 0.5 * u[:, 0]) * SIZE[0], (0.3 + 0.4 * u[:, 1]) * SIZE[1]], -1)
    rvec, tvec, _, _ = place_board(camera, obj, pixels, 0.3 + 0.2 * u[:, 2], (u[:, 3:5] - 0.5) * 70.0)
    background = cv2.GaussianBlur(rng.uniform(60, 190, (SIZE[1], SIZE[0])).astype(np.float32), (0, 0), 8)
    homographies = []
    for r, t in zip(rvec.numpy(), tvec.numpy(), strict=True):
        R, _ = cv2.Rodrigues(r)
        homographies.append(K @ np.column_stack([R[:, 0], R[:, 1], t]) @ np.linalg.inv(to_texture))
    frames = []
    for k in range(num):
        p, t = divmod(k, 15)
        H = homographies[p] if t < 10 else homographies[p] + (homographies[p + 1] - homographies[p]) * (t - 9) / 6
        warped = cv2.warpPerspective(board, H, SIZE, flags=cv2.INTER_LINEAR, borderValue=-1)
        frames.append(np.where(warped >= 0, warped, background).clip(0, 255).astype(np.uint8))
    return frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--detector", default="opencv", choices=("opencv", "learned"))
    args = parser.parse_args()
    frames = render(args.frames)
    detector = make_detector(args.detector)

    def detect(gray8: np.ndarray):
        with torch.inference_mode():
            found = detector(torch.from_numpy(gray8).float().div_(255.0)[None, None], BOARD)
        return found.corners[0].double().numpy() if bool(found.found[0]) else None

    capture = GuidedCapture(BOARD, board_object_points(*BOARD, 0.025, dtype=torch.float64), SIZE, detect,
                            live_model=K1K2, target=0.05, max_frames=10_000)
    page = CapturePage("127.0.0.1", 0)
    received = [0]
    stop = threading.Event()

    def client() -> None:
        with urllib.request.urlopen(page.url + "stream.mjpg", timeout=10) as r:
            while not stop.is_set():
                line = r.readline()
                if line.startswith(b"Content-Length:"):
                    received[0] += 1

    reader = threading.Thread(target=client, daemon=True)
    reader.start()
    time.sleep(0.2)
    latency, kept, shown = [], 0, {}
    start = time.perf_counter()
    for k, gray in enumerate(frames):
        t0 = time.perf_counter()
        decision = capture.offer(gray, k, k / 30.0)
        if decision.kept:
            kept += 1
            shown = {"map": capture.uncertainty_map(),
                     "outline": capture.suggestion().poses.outline[0].numpy()}
        page.show(annotate(gray, decision.sighting.outline, [f.outline for f in capture.kept], shown.get("outline"),
                           shown.get("map"), 0.05, None))
        latency.append(1000 * (time.perf_counter() - t0))
    seconds = time.perf_counter() - start
    time.sleep(0.3)
    stop.set()
    page.close()
    q = statistics.quantiles(latency, n=20)
    print(f"{len(frames)} frames 1280x720 in {seconds:.1f} s: {len(frames) / seconds:.1f} frames/s processed, "
          f"{received[0] / seconds:.1f} frames/s received by the page's client; frame to page median "
          f"{statistics.median(latency):.0f} ms, 95th percentile {q[-1]:.0f} ms; {kept} frames kept; "
          f"torch threads {torch.get_num_threads()}")


if __name__ == "__main__":
    main()
