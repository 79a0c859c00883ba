"""Intra-op threads: one thread where waking a second costs more than it saves.

Two rules. :func:`small_problem_threads`: the solver's small problems run on one thread whatever the wait policy.
:func:`light_stages_single_thread`: under passive waits the detector's light stages (scale estimate, peaks,
organiser, the level's refinement: many small ops) run on one thread and only the network's convolutions and the
full-resolution refinement (:func:`full_threads`) on all; measured on 2 idle cores at 640x480 with
``OMP_WAIT_POLICY=PASSIVE``: 12.5 -> 14.1 img/s at batch 1, 19.6 -> 20.9 at batch 16 (with the full-resolution
refinement's larger regions on both threads: 12.9 -> 13.4 and 18.7 -> 20.8); with spinning waits two
threads stay faster (refinement of 16 images 76 ms on two threads, 125 on one), so nothing changes there.

The solver's tensors are small (a camera is 15 views x 54 corners): every op is a few microseconds of work, and on
2 cores a second intra-op thread mostly adds the cost of waking it, the more so under ``OMP_WAIT_POLICY=PASSIVE``
(which the command line sets so idle threads do not spin). Measured with ``CalibrationSolver``, 15 views of a 9x6
board, 2 cores, passive waits: 1 camera 94 (1 thread) vs 65 (2 threads) calibrations/s, 16 cameras 396 vs 335,
64 cameras 407 vs 337, 256 cameras 313 vs 479; with the default (spinning) waits 1 camera 105 vs 98, 16 cameras
400 vs 362, 64 cameras 379 vs 655.

Example:
    >>> with small_problem_threads(1000, torch.device("cpu")):
    ...     torch.get_num_threads()
    1
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["SINGLE_THREAD_ELEMENTS", "full_threads", "light_stages_single_thread", "passive_waits", "small_problem_threads"]

#: problems up to this many corners (cameras x views x corners) run on one intra-op thread (16 cameras of 15 views
#: of a 9x6 board: 12,960)
SINGLE_THREAD_ELEMENTS = 16384


@contextmanager
def _num_threads(n: int) -> Iterator[None]:
    """The block on ``n`` intra-op threads; the previous count restored on exit."""
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


@contextmanager
def small_problem_threads(elements: int, device: torch.device) -> Iterator[None]:
    """Run the block on one intra-op thread when ``elements <= SINGLE_THREAD_ELEMENTS`` on the CPU; the previous
    thread count is restored on exit."""
    if device.type != "cpu" or elements > SINGLE_THREAD_ELEMENTS or torch.get_num_threads() <= 1:
        yield
        return
    with _num_threads(1):
        yield


def passive_waits() -> bool:
    """Whether OpenMP's idle threads sleep (``OMP_WAIT_POLICY=PASSIVE``, as the command line sets it)."""
    return os.environ.get("OMP_WAIT_POLICY", "").strip().upper() == "PASSIVE"


#: thread counts replaced by the active :func:`light_stages_single_thread` blocks (innermost last)
_FULL: list[int] = []


@contextmanager
def light_stages_single_thread(device: torch.device) -> Iterator[None]:
    """Under passive waits on the CPU, run the block on one intra-op thread; :func:`full_threads` inside it gives
    the heavy ops (the networks' convolutions) the full count back. Without passive waits nothing changes."""
    old = torch.get_num_threads()
    if device.type != "cpu" or old <= 1 or not passive_waits():
        yield
        return
    _FULL.append(old)
    try:
        with _num_threads(1):
            yield
    finally:
        _FULL.pop()


@contextmanager
def full_threads() -> Iterator[None]:
    """Inside :func:`light_stages_single_thread`: the thread count it replaced, for this block."""
    if not _FULL:
        yield
        return
    with _num_threads(_FULL[-1]):
        yield
