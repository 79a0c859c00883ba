"""Intra-op threads: one thread where waking a second costs more than it saves.

Two rules. :func:`small_problem_threads`: the solver's small problems run on one thread whatever the wait policy.
:func:`light_stages_single_thread`: under passive waits the detector's light stages (scale estimate, peaks,
organiser, the level's refinement: many small ops) run on one thread and only the network's convolutions and the
full-resolution refinement (:func:`full_threads`) on all, faster on 2 idle cores with
``OMP_WAIT_POLICY=PASSIVE``; with spinning waits two threads stay faster, so nothing changes there.

The solver's tensors are small (a camera is 15 views x 54 corners): every op is a few microseconds of work, and on
2 cores a second intra-op thread mostly adds the cost of waking it, the more so under ``OMP_WAIT_POLICY=PASSIVE``
(which the command line sets so idle threads do not spin): one thread is faster for the problems of up to
:data:`SINGLE_THREAD_ELEMENTS` corners. The figures of both rules: ``docs/measurements.md``.

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
