"""Where a pipeline run reads its views from: tensors already in memory, image files or video frames streamed from
disk.

A :class:`ViewSource` holds ``C`` cameras, each with its own list of views (ragged: cameras may have
different numbers of views and image sizes). :meth:`ViewSource.batches` loads the views asked for in batches of
one image size, bounded in number and in pixels, so that a folder of 24 Mpx photographs never sits in memory at
once; :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` reads every view through it, whether the caller handed it
a tensor (:class:`TensorSource`), file names (:class:`FileSource`) or frames of videos (:class:`VideoSource`).
"""

from __future__ import annotations

import os
import queue
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["LoadedBatch", "ViewSource", "TensorSource", "FileSource", "VideoFrameRef", "VideoSource", "prefetched",
           "DEFAULT_MAX_BATCH_PIXELS", "SIZE_TOLERANCE_PX"]

#: pixels loaded at most in one batch (16 Mpx = 64 MB of float32 grey images): bounds the detector's
#: activations too, which are a few times the input per image
DEFAULT_MAX_BATCH_PIXELS = 1 << 24

#: views whose size differs from their camera's by at most this many pixels per side are used (cropping or
#: rounding by a pixel moves no pixel's coordinates: the origin is the top-left pixel's centre)
SIZE_TOLERANCE_PX = 2


@dataclass
class LoadedBatch:
    """Views of one image size loaded together, and the views of this chunk that failed to load.

    Attributes:
        keys: ``(camera, view)`` of each image, in the order of ``images``.
        images: :math:`(B, 1, H, W)` float in ``[0, 1]``, or ``None`` when no view of the chunk loaded.
        failed: ``((camera, view), reason)`` for views that could not be loaded.
    """

    keys: list[tuple[int, int]] = field(default_factory=list)
    images: torch.Tensor | None = None
    failed: list[tuple[tuple[int, int], str]] = field(default_factory=list)


def prefetched(items: Iterable, depth: int = 1) -> Iterator:
    """Iterate over ``items`` while a background thread produces the next ``depth`` of them.

    Image decoding (OpenCV releases the GIL) then overlaps the work done on the previous batch. Exceptions raised
    while producing an item are raised here, at that item; closing the iterator early stops the thread.

    Example:
        >>> list(prefetched(iter(range(4))))
        [0, 1, 2, 3]
    """
    slots: queue.Queue = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()
    end = object()

    def put(entry) -> bool:
        while not stop.is_set():
            try:
                slots.put(entry, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for item in items:
                if not put((True, item)):
                    return
            put((True, end))
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            put((False, err))

    thread = threading.Thread(target=work, name="ccs_kornia-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            ok, item = slots.get()
            if not ok:
                raise item
            if item is end:
                return
            yield item
    finally:
        stop.set()
        thread.join()


def _ordered_map(fn: Callable, items: Sequence, workers: int) -> Iterator:
    """``fn`` of every item, in order, computed by ``workers`` threads at most ``workers`` items ahead of the consumer
    (OpenCV's decoders release the GIL, so two threads decode two files at once; memory: one decoded 24 Mpx photo more
    than one thread at a time, 96 MB)."""
    if workers <= 1 or len(items) <= 1:
        yield from (fn(item) for item in items)
        return
    with ThreadPoolExecutor(workers, thread_name_prefix="ccs_kornia-decode") as pool:
        ahead: deque = deque()
        for item in items:
            ahead.append(pool.submit(fn, item))
            if len(ahead) >= workers:
                yield ahead.popleft().result()
        while ahead:
            yield ahead.popleft().result()


class ViewSource:
    """``C`` cameras of views, loaded on demand (subclasses implement :meth:`_load`).

    Args:
        counts: number of views of each camera.
        names: a name per camera (default ``camera0``, ``camera1``, ...).
    """

    #: threads that load views at once (:class:`FileSource`: two decoders)
    decode_workers = 1

    def __init__(self, counts: Sequence[int], names: Sequence[str] | None = None) -> None:
        self.counts = [int(c) for c in counts]
        if any(c < 0 for c in self.counts):
            raise ValueError(f"view counts must be >= 0, got {self.counts}.")
        self.names = list(names) if names is not None else [f"camera{c}" for c in range(len(self.counts))]
        if len(self.names) != len(self.counts):
            raise ValueError(f"{len(self.names)} names for {len(self.counts)} cameras.")

    @property
    def num_cameras(self) -> int:
        return len(self.counts)

    @property
    def max_views(self) -> int:
        return max(self.counts, default=0)

    def describe(self, camera: int, view: int) -> str:
        """A human name of one view (a file path, or ``"view 3"``)."""
        return f"view {view}"

    def label(self, camera: int, view: int) -> str:
        """One view in a sentence (``near copy of IMG_0412.jpg``): its file's name, a video's ``frame 412``."""
        return os.path.basename(self.describe(camera, view))

    def speed(self, camera: int, view: int) -> float | None:
        """How fast the board moves in the image around this view (px/s), where the source knows (a recording's
        screening measures it between neighbouring frames); ``None``: not known (a photo)."""
        return None

    def _load(self, camera: int, view: int) -> tuple[torch.Tensor | None, str]:
        """One view as :math:`(1, H, W)` float in ``[0, 1]``, or ``(None, reason)``."""
        raise NotImplementedError

    def pixels(self, camera: int, view: int) -> int | None:
        """Pixels of one view without loading it, where cheaply known (``None``: unknown)."""
        return None

    def given_detections(self, board_size: tuple[int, int], device: torch.device | str = "cpu"):
        """The views' detections where the source gives them instead of images (corners detected before:
        :class:`~ccs_kornia.pipeline.corners_input.CornersSource`), as the pipeline's first look's result; ``None``
        (every source of images): the pipeline detects."""
        return None

    def batches(
        self,
        keys: Sequence[tuple[int, int]] | None = None,
        batch_size: int = 16,
        max_pixels: int | None = DEFAULT_MAX_BATCH_PIXELS,
    ) -> Iterator[LoadedBatch]:
        """Load views in batches of one size.

        Args:
            keys: ``(camera, view)`` pairs to load (default: every view of every camera, in order).
            batch_size: most images per batch (>= 1).
            max_pixels: most pixels per batch (``None``: no limit); a batch always holds at least one image.

        Yields:
            :class:`LoadedBatch` items; every key appears exactly once, in ``keys`` or ``failed``.
        """
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}.")
        if keys is None:
            keys = [(c, v) for c, n in enumerate(self.counts) for v in range(n)]
        pending: dict[tuple[int, int], list[tuple[tuple[int, int], torch.Tensor]]] = {}
        failed: list[tuple[tuple[int, int], str]] = []

        def make(items: list[tuple[tuple[int, int], torch.Tensor]]) -> LoadedBatch:
            nonlocal failed
            batch = LoadedBatch([k for k, _ in items], torch.stack([im for _, im in items]), failed)
            failed = []
            return batch

        for key, (image, reason) in zip(keys, _ordered_map(lambda k: self._load(*k), keys, self.decode_workers)):
            if image is None:
                failed.append((key, reason))
                continue
            size = (int(image.shape[-1]), int(image.shape[-2]))
            limit = batch_size if max_pixels is None else max(1, min(batch_size, max_pixels // (size[0] * size[1])))
            pending.setdefault(size, []).append((key, image))
            if len(pending[size]) >= limit:
                yield make(pending.pop(size))
        for size in list(pending):
            yield make(pending.pop(size))
        if failed:
            yield LoadedBatch([], None, failed)


class TensorSource(ViewSource):
    """Views already in memory: :math:`(V, 1, H, W)`, :math:`(C, V, 1, H, W)` or a list of :math:`(V_c, 1, H_c, W_c)`.

    Example:
        >>> src = TensorSource(torch.zeros(2, 3, 1, 8, 10))
        >>> src.num_cameras, src.counts, [b.images.shape for b in src.batches(batch_size=4)]
        (2, [3, 3], [torch.Size([4, 1, 8, 10]), torch.Size([2, 1, 8, 10])])
    """

    def __init__(self, images: torch.Tensor | Sequence[torch.Tensor], names: Sequence[str] | None = None) -> None:
        if isinstance(images, torch.Tensor):
            check_tensor(images, "images", ["V", "1", "H", "W"], ["C", "V", "1", "H", "W"], what="grey images")
            cams = [images] if images.dim() == 4 else list(images.unbind(0))
        else:
            cams = list(images)
            for k, t in enumerate(cams):
                check_tensor(t, f"camera {k}'s images", ["V", "1", "H", "W"], what="grey images")
        self.images = cams
        super().__init__([t.shape[0] for t in cams], names)

    def pixels(self, camera: int, view: int) -> int | None:
        return int(self.images[camera].shape[-1] * self.images[camera].shape[-2])

    def _load(self, camera: int, view: int) -> tuple[torch.Tensor | None, str]:
        image = self.images[camera][view]
        return (image if image.is_floating_point() else image.float() / 255.0), ""


class FileSource(ViewSource):
    """Image files, one list of paths per camera, decoded when their batch is loaded (8/16-bit, colour -> grey).

    The pipeline reads a ``FileSource`` through :func:`prefetched` (``decodes = True``): the next batch is decoded
    while the current one is processed.

    Example:
        >>> FileSource([["a.png", "b.png"], ["c.png"]]).counts
        [2, 1]
    """

    decodes = True
    decode_workers = 2

    def __init__(self, paths: Sequence[Sequence[str]], names: Sequence[str] | None = None) -> None:
        self.paths = [list(p) for p in paths]
        super().__init__([len(p) for p in self.paths], names)

    def describe(self, camera: int, view: int) -> str:
        return self.paths[camera][view]

    def pixels(self, camera: int, view: int) -> int | None:
        from ccs_kornia.io.images import image_pixels
        return image_pixels(self.paths[camera][view])  # PNG and JPEG headers

    def _load(self, camera: int, view: int) -> tuple[torch.Tensor | None, str]:
        from ccs_kornia.io.images import load_image_gray
        image, reason = load_image_gray(self.paths[camera][view])
        if image is None:
            return None, reason
        return torch.from_numpy(image)[None], ""


#: the decoders a forked worker inherited from its parent, kept (a worker ends without freeing them)
_INHERITED_DECODERS: list = []


@dataclass(frozen=True)
class VideoFrameRef:
    """One frame of a video as a view: the video's path, the frame's index, its timestamp (s) as the first pass
    over the video saw it and the board's speed there (px/s, between neighbouring frames; ``None``: not known)."""

    video: str
    index: int
    timestamp: float | None = None
    speed: float | None = None

    @property
    def name(self) -> str:
        """``VIDEO#INDEX``, the frame's name in every output."""
        from ccs_kornia.io.video import frame_name
        return frame_name(self.video, self.index)


class VideoSource(ViewSource):
    """Frames of videos, one list per camera (a camera's frames may come from several videos), decoded when their
    batch is loaded.

    Each process (the pipeline's forked workers included) opens its own decoder per video and reads a chunk's frames
    forward (:class:`~ccs_kornia.io.video.VideoReader`: decoding on to a frame not far ahead, else a seek checked
    against the frame's timestamp), so the same batches come out of any number of workers. ``decodes = True``: the
    pipeline decodes the next batch in a thread while the current one is detected.

    Example:
        >>> src = VideoSource([[VideoFrameRef("cam0.mp4", 3, 0.1), VideoFrameRef("cam0.mp4", 9, 0.3)]])
        >>> src.counts, src.describe(0, 1)
        ([2], 'cam0.mp4#9')
    """

    decodes = True

    def __init__(self, frames: Sequence[Sequence[VideoFrameRef]], names: Sequence[str] | None = None,
                 sizes: dict[str, tuple[int, int]] | None = None) -> None:
        self.frames = [list(f) for f in frames]
        self.sizes = dict(sizes or {})
        self._readers: dict[str, object] = {}
        self._pid = os.getpid()
        super().__init__([len(f) for f in self.frames], names)

    def describe(self, camera: int, view: int) -> str:
        return self.frames[camera][view].name

    def timestamp(self, camera: int, view: int) -> float | None:
        return self.frames[camera][view].timestamp

    def label(self, camera: int, view: int) -> str:
        ref = self.frames[camera][view]
        if len({r.video for r in self.frames[camera]}) > 1:
            return f"frame {os.path.basename(ref.video)}#{ref.index}"
        return f"frame {ref.index}"

    def speed(self, camera: int, view: int) -> float | None:
        return self.frames[camera][view].speed

    def pixels(self, camera: int, view: int) -> int | None:
        size = self.sizes.get(self.frames[camera][view].video)
        return None if size is None else int(size[0] * size[1])

    def _reader(self, video: str):
        from ccs_kornia.io.recordings import recording_reader

        if self._pid != os.getpid():  # a forked worker: the parent's decoders are the parent's, never touched here
            _INHERITED_DECODERS.append(self._readers)  # (freeing one waits for decoding threads only the parent has)
            self._readers, self._pid = {}, os.getpid()
        if video not in self._readers:
            self._readers[video] = recording_reader(video)
        return self._readers[video]

    def _load(self, camera: int, view: int) -> tuple[torch.Tensor | None, str]:
        ref = self.frames[camera][view]
        try:
            frame = self._reader(ref.video).read(ref.index, ref.timestamp)
        except ValueError as err:
            return None, str(err)
        if frame is None:
            return None, f"frame {ref.index} could not be decoded"
        return torch.from_numpy(frame.image).float().div_(255.0)[None], ""

    def close(self) -> None:
        """Release this process's decoders."""
        for reader in self._readers.values():
            reader.close()
        self._readers = {}
