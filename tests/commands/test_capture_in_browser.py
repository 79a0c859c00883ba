"""``capture``'s page in a real browser: headless Chromium loads it while a rendered recording plays as the source (at
its own rate, as a camera gives it) and shows the live image with the board, the suggestion and the kept frames, then
the calibration's result. Needs Debian's ``chromium`` (or Chrome); without one the test is skipped and says so."""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import threading
import time
import urllib.request

import cv2
import numpy as np
import pytest
from _videos import BOARD, board_frames, write_video

from ccs_kornia import cli

OPTIONS = ["--board", f"{BOARD[0]}x{BOARD[1]}", "--detector", "opencv", "--no-distortion-correction", "--jobs", "1",
           "--square", "0.025", "--model", "k1k2", "--no-ransac"]


@pytest.fixture(scope="module")
def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium on this machine (Debian: apt-get install chromium): the page's browser test needs one")


def _browser(chromium: str, url: str, *args: str) -> str:
    run = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=1000",
                          *args, url], capture_output=True, text=True, timeout=60)
    return run.stdout


def _text(dom: str, element: str) -> str:
    found = re.search(rf'id="{element}"[^>]*>(.*?)</', dom, re.S)
    return found.group(1).strip() if found else ""


def test_the_page_in_chromium(chromium, tmp_path):
    video = write_video(str(tmp_path / "held.avi"), np.repeat(board_frames(24, seed=3)[::2], 3, axis=0))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url, result = f"http://127.0.0.1:{port}/", {}
    worker = threading.Thread(target=lambda: result.update(code=cli.main([str(a) for a in (
        "capture", video, *OPTIONS, "--port", port, "--output", tmp_path / "calib.json", "--target", "5",
        "--page-linger", "20")])))
    worker.start()
    try:
        live = ""
        while worker.is_alive() and "kept" not in live:  # until the first frame is kept, as the page shows it
            dom = _browser(chromium, url, "--dump-dom")
            live = dom if int(_text(dom, "count") or 0) >= 1 and _text(dom, "next") not in ("", "-") else ""
        assert live, "the page never showed a kept frame"
        assert "frame_" in _text(live, "kept") and _text(live, "target") == "5"
        shot = str(tmp_path / "page.png")
        _browser(chromium, url, f"--screenshot={shot}", "--window-size=1280,720")
        image = cv2.imread(shot)
        assert image is not None
        b, g, r = (image[..., k].astype(int) for k in range(3))
        assert ((g > 200) & (r < 60) & (b < 60)).sum() > 50  # the board seen now (green)
        assert ((r > 200) & (g > 130) & (g < 200) & (b < 60)).sum() > 50  # the suggested pose (orange)
        final = ""
        deadline = time.monotonic() + 60
        while not final and time.monotonic() < deadline:
            dom = _browser(chromium, url, "--dump-dom")
            status = _text(dom, "status")
            final = status if status.startswith("calibrated from") else ""
        assert "held-out views" in final and os.path.exists(tmp_path / "calib.json"), final
    finally:
        try:  # the page's close button ends its wait
            urllib.request.urlopen(urllib.request.Request(url + "close", data=b"", method="POST"), timeout=5).read()
        except OSError:
            pass
        worker.join(timeout=60)
    assert result.get("code") == 0
