"""Intra-op threads for small problems: one thread where waking a second costs more than it saves.

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

from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["SINGLE_THREAD_ELEMENTS", "small_problem_threads"]

#: problems up to this many corners (cameras x views x corners) run on one intra-op thread (16 cameras of 15 views
#: of a 9x6 board: 12,960)
SINGLE_THREAD_ELEMENTS = 16384


@contextmanager
def small_problem_threads(elements: int, device: torch.device) -> Iterator[None]:
    """Run the block on one intra-op thread when ``elements <= SINGLE_THREAD_ELEMENTS`` on the CPU; the previous
    thread count is restored on exit."""
    old = torch.get_num_threads()
    if device.type != "cpu" or elements > SINGLE_THREAD_ELEMENTS or old <= 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(old)
