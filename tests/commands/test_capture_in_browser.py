"""``capture``'s page in a real browser: headless Chromium loads it while a rendered recording plays as the source (at
its own rate, as a camera gives it) and shows the live image with the board, the suggestion and the kept frames, then
the calibration's result. Needs Debian's ``chromium`` (or Chrome), installed by the fixture where missing and
possible; where it cannot be had, the test is skipped and says why."""

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


BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def _installed_browser() -> str | None:
    return next((path for path in map(shutil.which, BROWSERS) if path), None)


@pytest.fixture(scope="module")
def chromium() -> str:
    """A headless browser: the one on the machine, else Debian's ``chromium``, installed here where this runs as root
    with apt-get (a clean CI machine: about 110 MB, under a minute); skipped, saying why, only where neither works."""
    path = _installed_browser()
    if path is None and shutil.which("apt-get") and os.geteuid() == 0:
        quiet = {"capture_output": True, "text": True, "timeout": 600,
                 "env": {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}}
        run = subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends", "chromium"], **quiet)
        if run.returncode != 0:  # the package lists may be missing or stale on a fresh machine
            subprocess.run(["apt-get", "update", "-q"], **quiet)
            run = subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends", "chromium"], **quiet)
        path = _installed_browser()
        if path is None:
            pytest.skip(f"Chromium could not be installed (apt-get install chromium: {run.stderr.strip()[-200:]})")
    if path is None:
        pytest.skip("no Chromium on this machine and no root apt-get to install it (Debian: apt-get install "
                    "chromium): the page's browser test needs one")
    return path


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
