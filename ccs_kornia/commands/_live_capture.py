"""What ``capture`` does the same for one camera and for a rig: the detector and model used live, the kept frames'
names, how much of the image the board fills, and the ending: the kept frames moved into place, calibrated, the page's
last line and its wait once the calibration is written."""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable

import numpy as np
import torch

from ccs_kornia.commands._factories import make_detector_from
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import K1K2

__all__ = ["board_fill", "frame_name", "linger", "live_detector", "live_model", "result_line"]


def live_detector(args: argparse.Namespace):
    """Grey ``uint8`` frame -> corners :math:`(N, 2)` (NaN where not seen) or ``None``: the command's detector."""
    detector = make_detector_from(args)
    board_size = tuple(args.board)

    def detect(gray8: np.ndarray) -> np.ndarray | None:
        image = torch.from_numpy(gray8).float().div_(255.0)[None, None]
        with torch.inference_mode():
            found = detector(image, board_size)
        if not bool(found.found[0]):
            return None
        return found.corners[0].double().numpy()

    return detect


def live_model(args: argparse.Namespace):
    """The model solved while capturing: the one asked for, or k1k2 where the full pipeline will choose
    (``--model auto``)."""
    return args.model if isinstance(args.model, CameraModel) else K1K2


def board_fill(outline: np.ndarray, width: int) -> float:
    """How much of the image's width the board's outline spans (the next pose's distance is said against it)."""
    return float(np.ptp(outline[:, 0])) / max(1, width)


def frame_name(index: int) -> str:
    """A kept frame's file name (the same for every camera of a rig at one instant)."""
    return f"frame_{index:06d}.png"


def result_line(output: str, frames: int) -> str:
    """The page's last line: the verdict and the held-out figure the calibration wrote (a camera's JSON), or the
    verdict and RMS (a rig's), and where."""
    try:
        with open(output, encoding="utf-8") as handle:
            record = json.load(handle)
    except (OSError, ValueError):
        record = {}
    diagnostics = record.get("diagnostics") or {}
    held, rms = diagnostics.get("heldout_rms_px"), record.get("rms")
    if isinstance(held, (int, float)):
        said = f"{diagnostics.get('verdict', '')}, held-out views {held:.3f} px"
    else:  # a rig, or --no-diagnostics: no held-out figure
        verdict = f"{record['verdict']}, " if isinstance(record.get("verdict"), str) else ""
        said = f"{verdict}RMS {rms:.3f} px" if isinstance(rms, (int, float)) else "no figure"
    return f"calibrated from {frames} frames: {said}; wrote {output}"


def linger(page, seconds: float) -> None:
    """The page kept up ``seconds`` after the calibration, so that its result can be read there (the page's close
    button or Ctrl-C end it: the files are written)."""
    if seconds <= 0:
        return
    print(f"the result stays on {page.url} for {seconds:g} s (its close button or Ctrl-C end it now)", flush=True)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end and "close" not in page.take_actions():
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass


def calibrate_kept(staging: str, folder: str, calibrate: Callable[[], int], wrote: Callable[[float], str], page,
                   output: str, frames: int, page_linger: float) -> int:
    """The end of a capture, for a camera and a rig alike: the kept frames moved from ``staging`` to ``folder`` (an
    empty folder there is replaced), ``calibrate()`` run on them, the line ``wrote(seconds)`` printed, and the result
    shown on the page for ``page_linger`` seconds. Returns the calibration's exit status."""
    if os.path.isdir(folder):
        os.rmdir(folder)  # empty (checked before the capture)
    os.makedirs(os.path.dirname(os.path.abspath(folder)), exist_ok=True)
    os.replace(staging, folder)
    start = time.perf_counter()
    code = calibrate()
    print(wrote(time.perf_counter() - start))
    if page is not None:
        page.set_state(status=result_line(output, frames), done=True)
        linger(page, page_linger)
    return code
