"""Work on a source's views in batches, in this process or in forked worker processes (one CPU core each).

Most of a view's detection is small tensor and numpy operations, which one process cannot spread over two cores (only
the networks' convolutions use both threads well): two processes with one thread each detect a folder about 1.5x
faster on 2 cores than one process with two threads (``docs/measurements.md``). :func:`map_batches` splits the views
into the same batches whatever the number of workers (:func:`chunks` of ``batch_size`` views, then the source's own
batches of one image size within each), so a set gives the same corners with any number of workers (the distortion
network's per-view predictions agree to 4e-6: float rounding of one thread against two). :func:`worker_pool` maps any
function over items the same way (the pipeline's model selection solves its four models at once).

Workers are forked (Linux; the model is shared, not copied or pickled) and only for CPU work; each runs one intra-op
thread. Where fork is not available, or on other devices, the work runs here, in order.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
import pickle
import signal
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import torch

from ccs_kornia.pipeline.sources import DEFAULT_MAX_BATCH_PIXELS, ViewSource, prefetched
from ccs_kornia.runtime.timing import stage, timed

__all__ = ["BatchOutput", "MAX_AUTO_WORKERS", "WORKER_STAGE", "chunks", "default_workers", "map_batches",
           "usable_cores", "worker_pool", "workers_on"]

#: worker processes at most for ``workers="auto"`` (each holds its batch and its activations)
MAX_AUTO_WORKERS = 4

#: the profile's stage (:mod:`~ccs_kornia.runtime.timing`) of the waits for the workers (their own stages are not seen)
WORKER_STAGE = "worker processes"

#: what a forked worker runs, set by :func:`worker_pool` before forking
_TASK: Callable | None = None


@dataclass
class BatchOutput:
    """One batch's result.

    Attributes:
        keys: ``(camera, view)`` of each image of the batch.
        size: ``(width, height)`` of its images (``None`` when no view of the chunk loaded).
        value: ``fn(images, keys)`` (``None`` when no view loaded).
        failed: ``((camera, view), reason)`` for views of the chunk that could not be loaded.
    """

    keys: list[tuple[int, int]] = field(default_factory=list)
    size: tuple[int, int] | None = None
    value: Any = None
    failed: list[tuple[tuple[int, int], str]] = field(default_factory=list)


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _can_fork() -> bool:
    # fork is the only start method that shares the loaded networks; macOS's is unsafe with its system libraries
    return sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()


def default_workers(device: torch.device | str = "cpu") -> int:
    """Worker processes for ``workers="auto"``: one per usable core (at most :data:`MAX_AUTO_WORKERS`) for CPU work
    where processes can be forked, else 1 (work in this process).

    Example:
        >>> 1 <= default_workers("cpu") <= MAX_AUTO_WORKERS, default_workers("cuda")
        (True, 1)
    """
    return workers_on(device, min(usable_cores(), MAX_AUTO_WORKERS) if _can_fork() else 1)


def workers_on(device: torch.device | str, workers: int) -> int:
    """``workers`` for work on ``device``: only the CPU's work is shared out (1 elsewhere).

    Example:
        >>> workers_on("cpu", 2), workers_on("cuda:0", 2)
        (2, 1)
    """
    return workers if torch.device(device).type == "cpu" else 1


def chunks(keys: Sequence, size: int) -> list[list]:
    """``keys`` in consecutive runs of ``size`` (the last one shorter).

    Example:
        >>> chunks([1, 2, 3, 4, 5], 2)
        [[1, 2], [3, 4], [5]]
    """
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}.")
    keys = list(keys)
    return [keys[i : i + size] for i in range(0, len(keys), size)]


def _single_image_batches(source: ViewSource, part: list, max_pixels: int | None) -> list[list]:
    """``part`` as one chunk per view where every view is known to hold more than half of ``max_pixels`` (each loads
    as a batch of its own anyway, so the batches are the same), else ``[part]``: a folder of ten 27 Mpx photographs
    made chunks of 8 and 2 images, and one worker process detected eight of them while the other waited."""
    if max_pixels is None or len(part) < 2:
        return [part]
    if all((px := source.pixels(*key)) is not None and 2 * px > max_pixels for key in part):
        return [[key] for key in part]
    return [part]


def _loaded(source: ViewSource, parts: Sequence[Sequence], batch_size: int, max_pixels) -> Iterator:
    for part in parts:
        yield from source.batches(part, batch_size=batch_size, max_pixels=max_pixels)


def _outputs(fn: Callable, batches: Iterator) -> Iterator[BatchOutput]:
    for batch in batches:
        if batch.images is None:
            yield BatchOutput(failed=batch.failed)
            continue
        size = (int(batch.images.shape[-1]), int(batch.images.shape[-2]))
        yield BatchOutput(batch.keys, size, fn(batch.images, batch.keys), batch.failed)


def _chunk_outputs(fn: Callable, source: ViewSource, batch_size: int, max_pixels, keys: list) -> list[BatchOutput]:
    return list(_outputs(fn, _loaded(source, [keys], batch_size, max_pixels)))


def _start_worker() -> None:
    # the parent handles Ctrl-C (and stops the pool); one intra-op thread per process (torch's thread pool is
    # rebuilt after a fork; OpenCV's own pool must be left alone: setting its size in a forked child hangs)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)


@contextmanager
def worker_pool(fn: Callable[[Any], Any], workers: int = 1) -> Iterator[Callable[[Iterable], Iterator]]:
    """A function ``run(items)`` that yields ``fn(item)`` for each item, in order, computed by ``workers`` forked
    processes (``workers=1``, or no fork available: here, one after the other).

    ``fn`` and everything it uses are inherited by the fork (a bound method or a closure will do, nothing of it is
    pickled); the items and the results are pickled (by value: tensors are copied). The processes live as long as
    the ``with`` block. ``run(items, ahead=k)`` takes ``items`` as a stream: at most ``k`` of them are handed out and
    not yet yielded (a video's frames, decoded here while the workers look at the ones before; without ``ahead`` all
    items are taken at once).

    Example:
        >>> with worker_pool(lambda x: x * x, workers=2) as run:
        ...     list(run([1, 2, 3])), list(run(iter(range(5)), ahead=2))
        ([1, 4, 9], [0, 1, 4, 9, 16])
    """
    global _TASK
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}.")
    if workers == 1 or not _can_fork():
        yield lambda items, ahead=None: (fn(item) for item in items)
        return
    if _TASK is not None:
        raise RuntimeError("worker pools cannot be nested.")
    _TASK = fn
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"), initializer=_start_worker)
    # fork every worker now, before the caller's block starts threads of its own (e.g. a file prefetcher)
    pool.submit(int).result()

    def run(items: Iterable, ahead: int | None = None) -> Iterator:
        if ahead is None:
            results = pool.map(_call, [pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL) for item in items])
        else:  # a stream (e.g. a video's frames): at most ``ahead`` items handed out and not yet yielded
            results = _streamed(pool, items, max(1, int(ahead)))
        while True:
            try:
                with stage(WORKER_STAGE):  # the workers' own stages are not seen here
                    data = next(results, None)
            except BrokenProcessPool:
                raise RuntimeError("a worker process stopped unexpectedly (out of memory?): run again with fewer "
                                   "processes (--jobs / workers) or smaller batches (--batch-size)") from None
            if data is None:
                return
            yield pickle.loads(data)

    finished = False
    try:
        yield run
        finished = True
    finally:
        _TASK = None
        if not finished:  # an error or Ctrl-C here: the workers' current items are not waited for
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                process.terminate()
        pool.shutdown(wait=True, cancel_futures=True)


def _streamed(pool: ProcessPoolExecutor, items: Iterable, ahead: int) -> Iterator[bytes]:
    """The pickled results of ``items`` in order, with at most ``ahead`` items submitted and not yet taken."""
    pending: deque = deque()
    items = iter(items)
    for item in items:
        pending.append(pool.submit(_call, pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL)))
        if len(pending) >= ahead:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


def _call(data: bytes) -> bytes:
    with torch.inference_mode():
        out = _TASK(pickle.loads(data))
    # plain pickle: tensors by value (multiprocessing's pickler would pass them through shared memory files)
    return pickle.dumps(out, protocol=pickle.HIGHEST_PROTOCOL)


def map_batches(
    fn: Callable[[torch.Tensor, list[tuple[int, int]]], Any],
    source: ViewSource,
    keys: Sequence[tuple[int, int]] | None = None,
    batch_size: int = 16,
    max_pixels: int | None = DEFAULT_MAX_BATCH_PIXELS,
    workers: int = 1,
) -> Iterator[BatchOutput]:
    """``fn(images, keys)`` of every batch of views, in order; with ``workers > 1``, computed by that many forked
    processes.

    The views are split into :func:`chunks` of ``batch_size``, each loaded in batches of one image size and at most
    ``max_pixels`` (:meth:`~ccs_kornia.pipeline.sources.ViewSource.batches`): the same batches with any ``workers``. In this
    process, decoding is prefetched in a thread (:func:`~ccs_kornia.pipeline.sources.prefetched`); a worker decodes its own.

    Args:
        fn: the work on one batch :math:`(B, 1, H, W)` of views ``keys`` (``(camera, view)`` each) on the CPU; its
            result must pickle (tensors, lists, numbers).
            Workers inherit it (and everything it uses) by fork, so it may be a bound method or a closure.
        source: the views.
        keys: ``(camera, view)`` pairs (default: every view).
        batch_size: views per chunk and at most per batch.
        max_pixels: most pixels per batch.
        workers: processes (1: this one; fewer are used when there are fewer chunks; 1 where fork is unavailable).

    Yields:
        :class:`BatchOutput` per batch, chunk by chunk in order.

    Example:
        >>> from ccs_kornia.pipeline.sources import TensorSource
        >>> src = TensorSource(torch.rand(5, 1, 8, 8))
        >>> [(o.keys, round(float(o.value), 1)) for o in map_batches(lambda x, k: x.shape[0] / 10, src, batch_size=2)]
        [([(0, 0), (0, 1)], 0.2), ([(0, 2), (0, 3)], 0.2), ([(0, 4)], 0.1)]
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}.")
    if keys is None:
        keys = [(c, v) for c, n in enumerate(source.counts) for v in range(n)]
    parts = [piece for part in chunks(keys, batch_size) for piece in _single_image_batches(source, part, max_pixels)]
    workers = min(workers, len(parts)) if _can_fork() else 1
    if workers <= 1:
        batches = _loaded(source, parts, batch_size, max_pixels)
        # files are decoded in a thread while ``fn`` works on the previous batch here
        batches = prefetched(batches) if getattr(source, "decodes", False) else batches
        yield from _outputs(fn, timed(batches, "image loading"))
        return
    with worker_pool(functools.partial(_chunk_outputs, fn, source, batch_size, max_pixels), workers) as run:
        for outputs in run(parts):
            yield from outputs
