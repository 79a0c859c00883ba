"""Which views of a rig's cameras were taken at the same instant: frames matched across cameras by file name.

A rig's cameras are triggered together, and their image files carry the frame's number (``left07.jpg`` and
``right07.jpg``, ``cam0/frame_0123.png`` and ``cam1/frame_0123.png``). :func:`match_frames` pairs views by the last
number in each file's name; where names hold no number (or a camera repeats a number), frames are matched by the
files' natural order instead. A frame missing in one camera is allowed: that camera simply did not see it.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["FrameTable", "frame_number", "natural_key", "match_frames"]

_NUMBER = re.compile(r"\d+")


def frame_number(path: str) -> int | None:
    """The last number in a file's name (extension left out), or ``None``.

    Example:
        >>> frame_number("rig/left07.jpg"), frame_number("cam1/frame_0123.png"), frame_number("img.png")
        (7, 123, None)
    """
    stem = os.path.splitext(os.path.basename(path))[0]
    found = _NUMBER.findall(stem)
    return int(found[-1]) if found else None


def natural_key(path: str) -> list:
    """Sort key ordering numbers in names by value (``img2`` before ``img10``).

    Example:
        >>> sorted(["img10.png", "img2.png", "img1.png"], key=natural_key)
        ['img1.png', 'img2.png', 'img10.png']
    """
    return [(0, int(part), "") if part.isdigit() else (1, 0, part.lower()) for part in re.split(r"(\d+)", path) if part]


@dataclass
class FrameTable:
    """Frames of a rig: ``index[c][f]`` is the position of frame ``f`` in camera ``c``'s file list, ``None`` where the
    camera has no view of that frame.

    Attributes:
        labels: one name per frame (the file number, or the position in natural order).
        index: per camera, per frame, the file's position or ``None``.
        by: ``"number"`` (the last number in the file names) or ``"order"`` (natural order).
    """

    labels: list[str]
    index: list[list[int | None]]
    by: str

    @property
    def num_frames(self) -> int:
        return len(self.labels)

    def missing(self, camera: int) -> list[str]:
        """Labels of the frames camera ``camera`` has no view of."""
        return [label for label, k in zip(self.labels, self.index[camera]) if k is None]

    def files(self, paths: Sequence[Sequence[str]]) -> list[list[str | None]]:
        """Per camera, per frame, the file (``None`` where missing)."""
        return [[None if k is None else paths[c][k] for k in row] for c, row in enumerate(self.index)]


def match_frames(paths: Sequence[Sequence[str]]) -> FrameTable:
    """Match the views of ``C`` cameras into frames.

    By number when every file of every camera has a number in its name and no camera repeats one (frames: the union
    of the numbers, ascending); else by natural order (frame ``k`` is each camera's ``k``-th file).

    Args:
        paths: one list of image files per camera.

    Returns:
        :class:`FrameTable`.

    Example:
        >>> t = match_frames([["l/left01.jpg", "l/left02.jpg", "l/left03.jpg"], ["r/right03.jpg", "r/right01.jpg"]])
        >>> t.by, t.labels, t.index, t.missing(1)
        ('number', ['01', '02', '03'], [[0, 1, 2], [1, None, 0]], ['02'])
        >>> match_frames([["a/x.png", "a/y.png"], ["b/p.png", "b/q.png"]]).index
        [[0, 1], [0, 1]]
    """
    numbers = [[frame_number(p) for p in cam] for cam in paths]
    by_number = all(n is not None for cam in numbers for n in cam) and all(len(set(cam)) == len(cam) for cam in numbers)
    if by_number:
        keys = sorted({n for cam in numbers for n in cam})
        width = max((len(str(k)) for k in keys), default=1)
        digits = {}
        for cam, names in zip(numbers, paths):  # the label keeps the files' zero padding where they have one
            for n, p in zip(cam, names):
                found = _NUMBER.findall(os.path.splitext(os.path.basename(p))[0])[-1]
                digits.setdefault(n, found)
        labels = [digits.get(k, str(k).zfill(width)) for k in keys]
        where = [{n: i for i, n in enumerate(cam)} for cam in numbers]
        index = [[w.get(k) for k in keys] for w in where]
        return FrameTable(labels, index, "number")
    order = [sorted(range(len(cam)), key=lambda i, cam=cam: natural_key(os.path.basename(cam[i]))) for cam in paths]
    frames = max((len(o) for o in order), default=0)
    index = [[o[f] if f < len(o) else None for f in range(frames)] for o in order]
    return FrameTable([str(f) for f in range(frames)], index, "order")
