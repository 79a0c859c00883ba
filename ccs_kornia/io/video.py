"""Video files in at the boundary of the library: frames decoded one at a time, each with its index and timestamp.

A recording is read through OpenCV's ``VideoCapture`` (FFmpeg: mp4, mkv, avi, mov, mjpeg, ...) as a stream, so a
one-minute recording never sits in memory: :meth:`VideoReader.frames` yields grey ``uint8`` frames in order, bounded
by a :class:`FrameSpan` (``--every N``, ``--start`` / ``--end`` seconds), optionally downscaled for a quick first
look; :meth:`VideoReader.read` gets one frame back by its index (the full detector's look at a chosen frame).

Decisions recorded here:

* a frame's **index** is its position in decoding order counted from the file's first frame, and its **timestamp**
  the container's presentation time in seconds (``CAP_PROP_POS_MSEC`` after the frame is grabbed: exact for
  variable frame rates and B-frames, see ``docs/video.md``); a frame is named ``VIDEO#INDEX`` (:func:`frame_name`);
* seeking is never trusted blindly: a frame read by index after a seek must carry the timestamp the sequential pass
  saw, else the file is decoded forward from its start instead (a container's index can be off by frames);
* a file that stops decoding before the end its container states (truncated, damaged) gives the frames before the
  damage; :attr:`VideoReader.stopped` says where it stopped and what was lost;
* FFmpeg's own log lines are silenced (``OPENCV_FFMPEG_LOGLEVEL``, unless already set) so that a damaged file is
  reported in the library's one line, not in FFmpeg's.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass

# FFmpeg prints its own lines about damaged data ("moov atom not found"); the reader reports them itself. Read once,
# by the first capture opened in the process, so it is set before OpenCV is imported.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

__all__ = [
    "VIDEO_EXTENSIONS",
    "FrameSpan",
    "VideoFrame",
    "VideoInfo",
    "VideoReader",
    "ffmpeg_capture",
    "frame_name",
    "grey_frame",
    "is_video",
    "open_video",
    "scaled_frame",
    "split_frame_name",
]

#: file name endings read as videos (any FFmpeg container would do: these decide what a folder's videos are)
VIDEO_EXTENSIONS: tuple[str, ...] = (
    ".mp4", ".m4v", ".mkv", ".webm", ".avi", ".mov", ".mjpeg", ".mjpg", ".mpg", ".mpeg", ".ts", ".mts", ".m2ts",
    ".wmv", ".flv", ".3gp",
)

#: a frame read by index more than this many frames ahead of the decoder is reached by a seek, nearer by decoding
#: forward (a seek decodes from the key frame before it anyway)
SEEK_AHEAD = 48


def is_video(path: str | os.PathLike) -> bool:
    """A video file's name (by its ending, any case).

    Example:
        >>> is_video("rig/cam0.MP4"), is_video("left01.jpg")
        (True, False)
    """
    return os.fspath(path).lower().endswith(VIDEO_EXTENSIONS)


def frame_name(path: str, index: int) -> str:
    """The name of frame ``index`` of video ``path`` in every output: ``VIDEO#INDEX``.

    Example:
        >>> frame_name("cam0.mp4", 412)
        'cam0.mp4#412'
    """
    return f"{path}#{int(index)}"


def split_frame_name(name: str) -> tuple[str, int] | None:
    """``(video, index)`` of a name made by :func:`frame_name`, ``None`` for other names.

    Example:
        >>> split_frame_name("cam0.mp4#412"), split_frame_name("left01.jpg")
        (('cam0.mp4', 412), None)
    """
    path, sep, index = name.rpartition("#")
    if not sep or not index.isdigit() or not is_video(path):
        return None
    return path, int(index)


@dataclass(frozen=True)
class VideoInfo:
    """What a video's container says about it.

    Attributes:
        path: the file.
        width, height: frame size in pixels.
        fps: the container's frame rate (0 when it states none).
        frame_count: the container's frame count (an estimate in some containers; 0 when it states none).
    """

    path: str
    width: int
    height: int
    fps: float
    frame_count: int

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    @property
    def duration(self) -> float | None:
        """Seconds from the first frame to the end the container states (``None``: unknown)."""
        return self.frame_count / self.fps if self.fps > 0 and self.frame_count > 0 else None

    @property
    def period(self) -> float | None:
        """Seconds between frames at the stated rate (``None``: unknown)."""
        return 1.0 / self.fps if self.fps > 0 else None


@dataclass
class VideoFrame:
    """One decoded frame.

    Attributes:
        index: position in decoding order from the file's first frame (0-based).
        timestamp: presentation time in seconds.
        image: grey ``uint8`` :math:`(H, W)` (downscaled when asked, see :meth:`VideoReader.frames`).
    """

    index: int
    timestamp: float
    image: np.ndarray


@dataclass(frozen=True)
class FrameSpan:
    """Which frames of a video to read: every ``every``-th frame from the first at or after ``start`` seconds, up to
    ``end`` seconds (``None``: the file's start / end).

    Example:
        >>> span = FrameSpan(every=3, start=1.0)
        >>> [i for i in range(60) if span.wants(i, i / 30, first=30)][:4]
        [30, 33, 36, 39]
    """

    every: int = 1
    start: float | None = None
    end: float | None = None

    def __post_init__(self) -> None:
        if int(self.every) < 1:
            raise ValueError(f"every must be >= 1, got {self.every}.")
        if self.start is not None and self.start < 0:
            raise ValueError(f"start must be >= 0 s, got {self.start}.")
        if self.start is not None and self.end is not None and self.end <= self.start:
            raise ValueError(f"end ({self.end} s) must come after start ({self.start} s).")

    def before_start(self, timestamp: float) -> bool:
        return self.start is not None and timestamp < self.start - 1e-6

    def past_end(self, timestamp: float) -> bool:
        return self.end is not None and timestamp > self.end + 1e-6

    def wants(self, index: int, timestamp: float, first: int) -> bool:
        """Frame ``index`` at ``timestamp`` is read, ``first`` being the index of the first frame at or after
        ``start``."""
        return not self.before_start(timestamp) and not self.past_end(timestamp) and (index - first) % self.every == 0


def open_video(path: str | os.PathLike) -> tuple[VideoInfo | None, str]:
    """The container's description of a video, without raising: ``(info, "")`` or ``(None, reason)``.

    Example:
        >>> open_video("/nonexistent.mp4")
        (None, 'no such file')
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        return None, "no such file" if not os.path.exists(path) else "not a file"
    if not os.access(path, os.R_OK):
        return None, "cannot read file: permission denied"
    cap = ffmpeg_capture(path)
    try:
        if not cap.isOpened():
            return None, "not a readable video (unknown format, or a damaged or truncated file)"
        width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if width < 8 or height < 8:
            return None, f"not a readable video (frame size {width}x{height})"
        if not cap.grab():
            return None, "not a readable video: no frame could be decoded (damaged or truncated file?)"
    finally:
        cap.release()
    fps = fps if math.isfinite(fps) and 0 < fps < 10_000 else 0.0
    return VideoInfo(path, width, height, fps, max(0, count)), ""


def ffmpeg_capture(path: str) -> cv2.VideoCapture:
    """FFmpeg's capture of ``path`` (a file or a stream URL); OpenCV's warning about a source it cannot open is left out
    (the caller says why)."""
    logging = cv2.utils.logging
    level = logging.getLogLevel()
    logging.setLogLevel(min(level, logging.LOG_LEVEL_ERROR))
    try:
        return cv2.VideoCapture(path, cv2.CAP_FFMPEG)
    finally:
        logging.setLogLevel(level)


def grey_frame(frame: np.ndarray) -> np.ndarray:
    """A decoded frame :math:`(H, W)`, :math:`(H, W, 1)`, BGR or BGRA as one grey channel :math:`(H, W)`.

    Example:
        >>> grey_frame(np.zeros((4, 6, 3), np.uint8)).shape
        (4, 6)
    """
    if frame.ndim == 2:
        return frame
    if frame.shape[2] == 1:
        return frame[..., 0]
    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY if frame.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)


def scaled_frame(image: np.ndarray, max_side: int | None) -> np.ndarray:
    """A frame downscaled so that its longer side is at most ``max_side`` (area interpolation; ``None``: as it is).

    Example:
        >>> scaled_frame(np.zeros((480, 640), np.uint8), 320).shape
        (240, 320)
    """
    h, w = image.shape[:2]
    if max_side is None or max(h, w) <= max_side:
        return image
    s = max_side / max(h, w)
    return cv2.resize(image, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)


class VideoReader:
    """One video file, decoded forward one frame at a time; frames got back by index on demand.

    Args:
        path: the video.
        info: its :class:`VideoInfo` (probed when not given).

    Raises:
        ValueError: the file is not a readable video (the reason, one line).

    Example:
        >>> import tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "clip.avi")
        >>> out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
        >>> for k in range(5):
        ...     _ = out.write(np.full((48, 64, 3), 50 * k, np.uint8))
        >>> out.release()
        >>> reader = VideoReader(path)
        >>> [(f.index, round(f.timestamp, 2)) for f in reader.frames(FrameSpan(every=2))]
        [(0, 0.0), (2, 0.2), (4, 0.4)]
        >>> frame = reader.read(3)
        >>> frame.index, round(float(frame.image.mean()) / 50), reader.stopped
        (3, 3, '')
    """

    def __init__(self, path: str | os.PathLike, info: VideoInfo | None = None) -> None:
        self.path = os.fspath(path)
        if info is None:
            info, reason = open_video(self.path)
            if info is None:
                raise ValueError(f"{self.path}: {reason}")
        self.info = info
        self._cap: cv2.VideoCapture | None = None
        self._next = 0  # index of the frame the next grab returns
        self._seeks = True  # False once a seek landed elsewhere than it said: then only decoding forward
        #: ``""``, or why decoding stopped before the end the container states (set by :meth:`frames`)
        self.stopped = ""
        #: frames decoded in all (grabbed), for the record
        self.decoded = 0
        #: frames the file decodes from its start, once :meth:`frames` reached its end (``None`` before)
        self.length: int | None = None

    # -- the decoder --------------------------------------------------------------------------------

    def _open(self) -> cv2.VideoCapture:
        if self._cap is None:
            self._cap = ffmpeg_capture(self.path)
            self._next = 0
            if not self._cap.isOpened():
                self._cap = None
                raise ValueError(f"{self.path}: the video can no longer be opened")
        return self._cap

    def close(self) -> None:
        """Release the decoder (a later read opens it again)."""
        if self._cap is not None:
            self._cap.release()
            self._cap = None
            self._next = 0

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _grab(self) -> float | None:
        """Decode the next frame (not converted yet); its timestamp (s), or ``None`` at the end of what decodes."""
        cap = self._open()
        if not cap.grab():
            return None
        self._next += 1
        self.decoded += 1
        return float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0

    def _retrieve(self) -> np.ndarray | None:
        ok, frame = self._open().retrieve()
        return grey_frame(frame) if ok and frame is not None and frame.size else None

    # -- reading ------------------------------------------------------------------------------------

    def frames(self, span: FrameSpan = FrameSpan(), max_side: int | None = None) -> Iterator[VideoFrame]:
        """The frames ``span`` asks for, in order, from the file's start.

        Frames skipped by ``span`` are decoded but not converted (inter-frame codecs need them). When decoding stops
        before the end the container states, :attr:`stopped` says so after the last frame.

        Args:
            span: which frames.
            max_side: frames whose longer side exceeds this are downscaled to it (area interpolation; ``None``: full
                size).

        Yields:
            :class:`VideoFrame` items.
        """
        self.close()
        self.stopped = ""
        first: int | None = None
        last_time, last_index = None, -1
        while True:
            index = self._next
            timestamp = self._grab()
            if timestamp is None:
                self.stopped = self._damage(last_index, last_time)
                self.length = last_index + 1
                return
            last_time, last_index = timestamp, index
            if span.past_end(timestamp):
                return
            if span.before_start(timestamp):
                continue
            first = index if first is None else first
            if not span.wants(index, timestamp, first):
                continue
            image = self._retrieve()
            if image is None:
                self.stopped = self._damage(index - 1, timestamp)
                return
            yield VideoFrame(index, timestamp, scaled_frame(image, max_side))

    def _damage(self, last_index: int, last_time: float | None) -> str:
        """Why decoding stopped after frame ``last_index`` when the container states more (``""``: it did not)."""
        info = self.info
        if info.duration is None:
            return ""
        read = last_index + 1
        # the container's count is an estimate in some formats (mkv, variable rates): the time the frames reached
        # decides, with two frame periods to spare
        reached = -math.inf if last_time is None else last_time
        if reached + 2.0 * info.period >= info.duration:
            return ""
        where = f"after frame {last_index} ({reached:.2f} s)" if read else "before its first frame"
        return (f"decoding stopped {where} of the {info.duration:.2f} s the file states (about {info.frame_count} "
                f"frames): damaged or truncated; the {read} frames before are used")

    def read(self, index: int, timestamp: float | None = None) -> VideoFrame | None:
        """Frame ``index`` at full size, ``None`` when the file does not decode that far.

        Args:
            index: the frame's index (as :meth:`frames` gave it).
            timestamp: its timestamp as :meth:`frames` saw it: a seek that lands elsewhere is redone by decoding
                forward from the start (``None``: the seek is trusted only where the container's index agrees with
                the decoder's position).
        """
        index = int(index)
        if index < 0:
            raise ValueError(f"index must be >= 0, got {index}.")
        cap = self._open()
        if index < self._next or (self._seeks and index > self._next + SEEK_AHEAD):
            if self._seeks:
                cap.set(cv2.CAP_PROP_POS_FRAMES, index)
                at = int(round(cap.get(cv2.CAP_PROP_POS_FRAMES)))
                self._next = at if at <= index else self._restart()
            else:
                self._restart()
        while self._next < index:
            if self._grab() is None:
                return None
        got = self._grab()
        if got is None:
            return None
        if timestamp is not None and abs(got - timestamp) > 1e-3:
            self._seeks = False
            self._restart()
            return self._read_forward(index, timestamp)
        image = self._retrieve()
        return None if image is None else VideoFrame(index, got, image)

    def _restart(self) -> int:
        self.close()
        self._open()
        return 0

    def _read_forward(self, index: int, timestamp: float | None) -> VideoFrame | None:
        """Frame ``index`` by decoding from the decoder's position (never seeking)."""
        while self._next < index:
            if self._grab() is None:
                return None
        got = self._grab()
        image = None if got is None else self._retrieve()
        return None if image is None else VideoFrame(index, got, image)
