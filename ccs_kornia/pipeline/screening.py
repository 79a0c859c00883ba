"""The screening pass over a recording: every frame decoded once, looked at quickly, the board's rough outline kept.

:func:`screen_video` streams a video's frames (:class:`~ccs_kornia.io.video.VideoReader`, in a decoding thread of this
process, downscaled to the screen's side) through a
:class:`~ccs_kornia.modules.detection.screening.BoardScreen` in the pipeline's worker processes
(:func:`~ccs_kornia.pipeline.workers.worker_pool`, a bounded number of batches in flight: the frames are never all in
memory). What it keeps per frame is small (index, timestamp, :class:`~ccs_kornia.modules.detection.screening.Sighting`):
the frame choice (:mod:`~ccs_kornia.pipeline.frame_candidates`) works on these records, and the full detector then
reads only the chosen frames again (:class:`~ccs_kornia.pipeline.sources.VideoSource`).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ccs_kornia.io.recordings import recording_reader
from ccs_kornia.io.video import FrameSpan, VideoInfo, VideoReader
from ccs_kornia.modules.detection.screening import BoardScreen, Sighting
from ccs_kornia.pipeline.sources import prefetched
from ccs_kornia.pipeline.workers import worker_pool

__all__ = ["SCREEN_BATCH", "ScreenedFrame", "ScreenedVideo", "screen_video"]

#: frames handed to a worker at once (a 640x360 copy is 0.23 MB: a batch costs little to pass)
SCREEN_BATCH = 16


@dataclass
class ScreenedFrame:
    """One frame as the screen saw it: its index and timestamp (s) in the video, and the :class:`Sighting`."""

    index: int
    timestamp: float
    sighting: Sighting

    @property
    def found(self) -> bool:
        return self.sighting.found


@dataclass
class ScreenedVideo:
    """A video's screening pass.

    Attributes:
        info: the container's description.
        span: the frames asked for.
        frames: the frames read, in order.
        stopped: ``""``, or why decoding stopped before the end the container states (damaged or truncated).
        length: frames the file decodes (``None``: the pass stopped before its end, at ``--end``).
        seconds: the pass's wall time.
    """

    info: VideoInfo
    span: FrameSpan
    frames: list[ScreenedFrame] = field(default_factory=list)
    stopped: str = ""
    length: int | None = None
    seconds: float = 0.0

    @property
    def path(self) -> str:
        return self.info.path

    @property
    def found(self) -> int:
        """Frames in which the screen saw the board."""
        return sum(1 for f in self.frames if f.found)

    @property
    def timestamps(self) -> list[float]:
        return [f.timestamp for f in self.frames]

    @property
    def timestamps_usable(self) -> bool:
        """The frames' timestamps increase strictly (a container without presentation times gives repeats or
        zeros: its frames then pair by index)."""
        t = self.timestamps
        return len(t) > 0 and all(b > a for a, b in zip(t, t[1:])) and (len(t) > 1 or t[0] >= 0)


def _screen_batch(screen: BoardScreen, full_size: tuple[int, int],
                  batch: list[tuple[int, float, np.ndarray]]) -> list[tuple[int, float, Sighting]]:
    return [(index, timestamp, screen(image, full_size)) for index, timestamp, image in batch]


def _batches(reader: VideoReader, span: FrameSpan, max_side: int, size: int) -> Iterator[list]:
    batch: list[tuple[int, float, np.ndarray]] = []
    for frame in reader.frames(span, max_side=max_side):
        batch.append((frame.index, frame.timestamp, frame.image))
        if len(batch) >= size:
            yield batch
            batch = []
    if batch:
        yield batch


def screen_video(
    video: str | VideoInfo,
    screen: BoardScreen,
    span: FrameSpan = FrameSpan(),
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    batch_size: int = SCREEN_BATCH,
) -> ScreenedVideo:
    """Screen every frame ``span`` asks for.

    Args:
        video: the video's path or :class:`~ccs_kornia.io.video.VideoInfo`.
        screen: the quick look (its ``max_side`` sets the decoded copies' size).
        span: which frames (``--every``, ``--start``, ``--end``).
        workers: processes looking at the frames (1: this one); decoding stays in this process, in a thread.
        progress: called after every batch with the frames screened and the boards seen in it.
        batch_size: frames per batch.

    Returns:
        :class:`ScreenedVideo`.

    Raises:
        ValueError: the file is not a readable video (one line).

    Example:
        >>> import os, tempfile, cv2
        >>> path = os.path.join(tempfile.mkdtemp(), "board.avi")
        >>> board = np.kron((np.indices((5, 6)).sum(0) % 2) * 255, np.ones((20, 20))).astype(np.uint8)
        >>> out = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10, (240, 200))
        >>> for k in range(6):
        ...     frame = np.full((200, 240), 128, np.uint8)
        ...     if k % 2:
        ...         frame[40:140, 20 + 10 * k:140 + 10 * k] = board
        ...     _ = out.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
        >>> out.release()
        >>> seen = screen_video(path, BoardScreen((5, 4)))
        >>> [f.index for f in seen.frames if f.found], seen.timestamps_usable, seen.stopped
        ([1, 3, 5], True, '')
    """
    start = time.perf_counter()
    reader = recording_reader(video.path, video) if isinstance(video, VideoInfo) else recording_reader(video)
    out = ScreenedVideo(reader.info, span)
    task = functools.partial(_screen_batch, screen, reader.info.size)
    try:
        with worker_pool(task, workers) as run:
            batches = prefetched(_batches(reader, span, screen.max_side, batch_size), depth=2)
            for result in run(batches, ahead=2 * workers):
                out.frames.extend(ScreenedFrame(i, t, s) for i, t, s in result)
                if progress is not None:
                    progress(len(result), sum(1 for _, _, s in result if s.found))
    finally:
        reader.close()
    out.stopped, out.length = reader.stopped, reader.length
    out.seconds = time.perf_counter() - start
    return out
