"""A live source of frames: a camera by index, a device, a stream URL, or a video file played at its own rate.

:func:`open_live` reads what ``capture`` is given as ``SOURCE`` and opens it with OpenCV; :class:`LiveSource` hands
out grey ``uint8`` frames with their index and timestamp (s from the first frame: the stream's own time for a file,
the wall clock for the others) until the stream ends. A file is played at its own rate (a frame is handed out no
earlier than its time: as a camera would give it) unless ``realtime=False``.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import cv2
import numpy as np

from ccs_kornia.io.video import ffmpeg_capture, grey_frame
from ccs_kornia.runtime.errors import UserError

__all__ = ["STREAM_SCHEMES", "LiveFrame", "LiveSource", "open_live", "source_kind"]

#: a SOURCE starting with one of these is a stream URL
STREAM_SCHEMES = ("rtsp://", "rtsps://", "http://", "https://", "udp://", "tcp://", "rtmp://")


def source_kind(text: str) -> str:
    """What a ``SOURCE`` names: ``"index"``, ``"device"``, ``"stream"`` or ``"file"``.

    Example:
        >>> [source_kind(s) for s in ("0", "/dev/video2", "rtsp://10.0.0.2/live", "board.mp4")]
        ['index', 'device', 'stream', 'file']
    """
    if text.isdigit():
        return "index"
    if text.lower().startswith(STREAM_SCHEMES):
        return "stream"
    if text.startswith("/dev/"):
        return "device"
    return "file"


@dataclass
class LiveFrame:
    """One frame: grey ``uint8`` :math:`(H, W)`, its index from 0 and its timestamp (s)."""

    image: np.ndarray
    index: int
    timestamp: float


class LiveSource:
    """An opened source (:func:`open_live`); iterate for :class:`LiveFrame` until the stream ends."""

    def __init__(self, text: str, capture: cv2.VideoCapture, kind: str, realtime: bool = True) -> None:
        self.text, self.kind = text, kind
        self._cap = capture
        fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if 0.5 <= fps <= 1000 else None
        self.realtime = realtime
        self.size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))

    def close(self) -> None:
        self._cap.release()

    def __enter__(self) -> LiveSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self):
        start = time.monotonic()
        index = 0
        while True:
            ok, frame = self._cap.read()
            if not ok or frame is None:
                return
            if self.kind == "file" and self.fps:
                stamp = index / self.fps
                wait = start + stamp - time.monotonic()
                if self.realtime and wait > 0:
                    time.sleep(wait)
            else:
                stamp = time.monotonic() - start
            yield LiveFrame(np.ascontiguousarray(grey_frame(frame)), index, stamp)
            index += 1


def open_live(text: str, realtime: bool = True) -> LiveSource:
    """Open a ``SOURCE``: a camera index (``0``), a device path, a stream URL or a video file.

    Raises:
        UserError: one line where it cannot be opened (no camera at that index, no such file, a stream that does not
            answer).
    """
    kind = source_kind(text)
    if kind == "file" and not os.path.isfile(text):
        raise UserError(f"{text}: no such file (a SOURCE is a camera index, a device, a stream URL or a video file)")
    if kind == "index":
        cap = cv2.VideoCapture(int(text))
    elif kind == "device":
        cap = cv2.VideoCapture(text, cv2.CAP_V4L2) if hasattr(cv2, "CAP_V4L2") else cv2.VideoCapture(text)
    else:
        cap = ffmpeg_capture(text)
    if not cap.isOpened():
        cap.release()
        what = {"index": f"no camera at index {text}", "device": f"{text}: no camera there (or no permission)",
                "stream": f"{text}: the stream does not answer", "file": f"{text}: not a video OpenCV can read"}[kind]
        raise UserError(what)
    return LiveSource(text, cap, kind, realtime)
