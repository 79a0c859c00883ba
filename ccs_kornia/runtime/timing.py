"""Per-stage wall time of a run, for the benchmark's profile (off, and almost free, unless a recorder is active).

The stages mark themselves with :func:`stage`; a :class:`StageProfile` used as a context manager collects the time
spent in each, *exclusive* of the stages nested inside (so the shares add up to the whole). With ``sync=True`` every
boundary waits for the GPU, so asynchronous CUDA work is charged to the stage that queued it.

Example:
    >>> import time
    >>> with StageProfile() as prof:
    ...     with stage("outer"):
    ...         with stage("inner"):
    ...             time.sleep(0.01)
    >>> sorted(prof.seconds), prof.calls["inner"], prof.seconds["inner"] >= 0.01 > prof.seconds["outer"]
    (['inner', 'outer'], 1, True)
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterable, Iterator

import torch

__all__ = ["stage", "timed", "StageProfile"]

_ACTIVE: list[StageProfile] = []


class StageProfile:
    """Collects the exclusive wall time of every :func:`stage` entered while it is active.

    Args:
        sync: synchronise CUDA at every stage boundary (exact attribution on a GPU; a no-op on CPU).

    Attributes:
        seconds: stage name -> exclusive seconds.
        calls: stage name -> times entered.
        wall: seconds between entering and leaving the recorder.
    """

    def __init__(self, sync: bool = True) -> None:
        self.sync = bool(sync)
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.wall = 0.0
        self._stack: list[list[float]] = []  # [start, time spent in nested stages]
        self._t0 = 0.0

    def _now(self) -> float:
        if self.sync and torch.cuda.is_available() and torch.cuda.is_initialized():
            torch.cuda.synchronize()
        return time.perf_counter()

    def __enter__(self) -> StageProfile:
        _ACTIVE.append(self)
        self._t0 = self._now()
        return self

    def __exit__(self, *exc) -> None:
        self.wall += self._now() - self._t0
        _ACTIVE.remove(self)

    def table(self) -> list[tuple[str, float, float, int]]:
        """``(stage, seconds, share of the wall time, calls)`` rows, slowest first, with ``other`` (unmarked time)."""
        rows = sorted(((k, v, self.calls[k]) for k, v in self.seconds.items()), key=lambda r: -r[1])
        other = self.wall - sum(self.seconds.values())
        rows.append(("other (unmarked)", max(other, 0.0), 0))
        wall = max(self.wall, 1e-12)
        return [(k, v, v / wall, n) for k, v, n in rows]


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Mark a stage for an active :class:`StageProfile` (nothing happens when none is active)."""
    if not _ACTIVE:
        yield
        return
    rec = _ACTIVE[-1]
    start = rec._now()
    rec._stack.append([start, 0.0])
    try:
        yield
    finally:
        end = rec._now()
        begun, nested = rec._stack.pop()
        total = end - begun
        rec.seconds[name] += total - nested
        rec.calls[name] += 1
        if rec._stack:
            rec._stack[-1][1] += total


def timed(items: Iterable, name: str) -> Iterator:
    """Iterate over ``items``, charging the time spent producing each item to the stage ``name`` (e.g. the image
    loading of a batch iterator; the work done on an item between two steps is not included).

    Example:
        >>> with StageProfile() as prof:
        ...     total = sum(timed(iter(range(3)), "produce"))
        >>> total, prof.calls["produce"]
        (3, 4)
    """
    it = iter(items)
    while True:
        with stage(name):
            item = next(it, _END)
        if item is _END:
            return
        yield item


_END = object()
