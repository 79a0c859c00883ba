"""Which views of a rig's cameras were taken at the same instant: frames matched across cameras by file name, by
timestamp, by frame index or by a timestamps table.

A rig's cameras are triggered together, and their image files carry the frame's number (``left07.jpg`` and
``right07.jpg``, ``cam0/frame_0123.png`` and ``cam1/frame_0123.png``). :func:`match_frames` pairs views by the last
number in each file's name; where names hold no number (or a camera repeats a number), frames are matched by the
files' natural order instead. A frame missing in one camera is allowed: that camera simply did not see it.

Videos pair by time: :func:`match_by_time` groups the cameras' frames whose timestamps lie within a tolerance (half
the shortest frame period by default), whatever the cameras' rates and lengths; :func:`match_by_index` pairs frames of
one index where the videos carry no usable timestamps; :func:`match_by_table` follows a timestamps table
(:mod:`~ccs_kornia.io.timestamps`, caliscope's layout), the way to pair recordings started at different moments.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass

from ccs_kornia.io.timestamps import TimestampRow

__all__ = ["FrameTable", "frame_number", "natural_key", "match_by_index", "match_by_table", "match_by_time",
           "match_frames"]

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
        labels: one name per frame (the file number, the position in natural order, a video frame's index or
            time, a table's ``sync_index``).
        index: per camera, per frame, the file's position or ``None``.
        by: ``"number"`` (the last number in the file names), ``"order"`` (natural order), ``"time"``
            (timestamps), ``"index"`` (video frame indices), ``"table"`` (a timestamps table's ``frame_index``) or
            ``"table order"`` (a timestamps table's rows in time order, as caliscope reads them).
        times: per camera, per frame, the time (s) it was matched by (``None`` where missing; ``None`` for files).
    """

    labels: list[str]
    index: list[list[int | None]]
    by: str
    times: list[list[float | None]] | None = None

    def spread(self) -> list[float | None]:
        """Per frame, the time between its earliest and latest camera (``None``: fewer than two cameras, or no
        times)."""
        if self.times is None:
            return [None] * self.num_frames
        out: list[float | None] = []
        for f in range(self.num_frames):
            t = [row[f] for row in self.times if row[f] is not None]
            out.append(max(t) - min(t) if len(t) > 1 else None)
        return out

    def largest_spread(self) -> float | None:
        """The largest time spread of a frame paired between two cameras or more (``None``: none)."""
        spread = [s for s in self.spread() if s is not None]
        return max(spread) if spread else None

    def contributed(self, camera: int) -> int:
        """Frames that camera ``camera`` has a view of."""
        return sum(1 for k in self.index[camera] if k is not None)

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


def match_by_time(times: Sequence[Sequence[float]], tolerance: float) -> FrameTable:
    """Pair the frames of ``C`` videos by timestamp: a frame is the earliest frame not yet paired and every other
    camera's next frame within ``tolerance`` seconds of it (one per camera; a camera's second frame in the window
    starts the next one). Frame rates and lengths may differ: frames with no partner are frames of their camera alone.

    Args:
        times: per camera, the timestamps (s) of its frames, ascending.
        tolerance: largest time between the first and any other frame of a pair (s, >= 0).

    Returns:
        :class:`FrameTable` (``by="time"``; labels: the first frame's time, ``times``: each frame's own).

    Example:
        >>> t = match_by_time([[0.0, 0.1, 0.2, 0.3], [0.004, 0.204, 0.404]], tolerance=0.05)
        >>> t.labels, t.index, round(t.largest_spread(), 3)
        (['0.000', '0.100', '0.200', '0.300', '0.404'], [[0, 1, 2, 3, None], [0, None, 1, None, 2]], 0.004)
    """
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0 s, got {tolerance}.")
    c = len(times)
    events = sorted((float(t), cam, k) for cam, row in enumerate(times) for k, t in enumerate(row))
    index: list[list[int | None]] = [[] for _ in range(c)]
    stamps: list[list[float | None]] = [[] for _ in range(c)]
    labels: list[str] = []
    i = 0
    while i < len(events):
        anchor = events[i][0]
        group: dict[int, tuple[float, int]] = {}
        j = i
        while j < len(events) and events[j][0] - anchor <= tolerance + 1e-9 and events[j][1] not in group:
            group[events[j][1]] = (events[j][0], events[j][2])
            j += 1
        labels.append(f"{anchor:.3f}")
        for cam in range(c):
            t, k = group.get(cam, (None, None))
            index[cam].append(k)
            stamps[cam].append(t)
        i = j
    return FrameTable(labels, index, "time", stamps)


def match_by_index(indices: Sequence[Sequence[int]], times: Sequence[Sequence[float]] | None = None) -> FrameTable:
    """Pair the frames of ``C`` videos that carry no usable timestamps by their index in the video.

    Args:
        indices: per camera, the video frame indices of its frames, ascending.
        times: per camera, their timestamps (kept in the table, not used to pair).

    Example:
        >>> match_by_index([[0, 2, 4], [0, 2]]).index
        [[0, 1, 2], [0, 1, None]]
    """
    keys = sorted({int(i) for row in indices for i in row})
    where = [{int(i): k for k, i in enumerate(row)} for row in indices]
    index = [[w.get(key) for key in keys] for w in where]
    stamps = None if times is None else [[None if k is None else float(times[c][k]) for k in row]
                                         for c, row in enumerate(index)]
    return FrameTable([str(k) for k in keys], index, "index", stamps)


def match_by_table(rows: Sequence[TimestampRow], indices: Sequence[Sequence[int]],
                   frame_counts: Sequence[int | None], source: str = "the timestamps table") -> FrameTable:
    """Pair the frames of ``C`` videos as a timestamps table says (:func:`~ccs_kornia.io.timestamps.read_timestamps`).

    Args:
        rows: the table's rows (``cam_id``: the camera's position, 0-based).
        indices: per camera, the video frame indices of the frames at hand (screened), ascending.
        frame_counts: per camera, the frames its video decodes (``None``: not known, e.g. when read up to ``--end``).
        source: the table's name in messages.

    Returns:
        :class:`FrameTable` (labels: ``sync_index``, ``times``: ``frame_time``). Instants none of whose frames is at
        hand are left out. ``by="table"``: a frame is its row's ``frame_index``; ``by="table order"``: each camera's
        rows in order of ``frame_time`` are its video's frames, as caliscope reads its tables (its writer no longer
        writes ``frame_index``, and older tables count it from the recording's start, not the video's first frame):
        where the table has no ``frame_index``, or one past the end of a video while every camera has a row per
        frame.

    Raises:
        ValueError: the table does not match the videos (a camera it names is not given, a camera has no row, an
            instant names a camera twice, a frame past the end of its video, rows that cannot be the video's frames
            in order): one line.

    Example:
        >>> rows = [TimestampRow(7, 0, None, 1.0), TimestampRow(7, 1, None, 1.01), TimestampRow(8, 0, None, 1.5)]
        >>> t = match_by_table(rows, [[0, 1], [0]], [2, 1])
        >>> t.labels, t.index
        (['7', '8'], [[0, 1], [0, None]])
    """
    c = len(indices)
    cams = sorted({r.cam_id for r in rows})
    if cams[-1] >= c:
        raise ValueError(f"{source} names camera {cams[-1]} but {c} videos were given (cam_id is the video's position "
                         f"on the command line, 0 to {c - 1})")
    per_cam = {k: [r for r in rows if r.cam_id == k] for k in range(c)}
    empty = [k for k in range(c) if not per_cam[k]]
    if empty:
        raise ValueError(f"{source} has no row for camera {empty[0]} (cam_id {empty[0]}: video {empty[0] + 1} on the "
                         "command line)")
    by_order = rows[0].frame_index is None
    if not by_order:  # a frame_index past the end of a video counts from the recording's start: caliscope's reading
        past = [(k, max(r.frame_index for r in per_cam[k])) for k in range(c) if frame_counts[k] is not None and
                max(r.frame_index for r in per_cam[k]) >= frame_counts[k]]
        if past:
            short = [k for k in range(c) if frame_counts[k] is not None and len(per_cam[k]) != frame_counts[k]]
            if short:
                k, last = past[0]
                raise ValueError(f"{source}: frame_index {last} of camera {k} is past the end of its video "
                                 f"({frame_counts[k]} frames), and the rows cannot be read as caliscope reads them "
                                 f"(each camera's rows in time order as its video's frames): camera {short[0]} has "
                                 f"{len(per_cam[short[0]])} rows for {frame_counts[short[0]]} frames")
            by_order = True
    frame_of: dict[tuple[int, int], tuple[int, float]] = {}
    for k in range(c):
        cam_rows = per_cam[k]
        if by_order:  # the camera's rows are its frames in time order (caliscope's reading)
            count = frame_counts[k]
            if count is not None and len(cam_rows) != count:
                raise ValueError(f"{source} has {len(cam_rows)} rows for camera {k} but its video has {count} frames: "
                                 "without a frame_index column the rows must be the video's frames, one each")
            ordered = sorted(cam_rows, key=lambda r: r.frame_time)
            numbered = [(r, f) for f, r in enumerate(ordered)]
        else:
            numbered = [(r, int(r.frame_index)) for r in cam_rows]
        for r, f in numbered:
            key = (r.sync_index, k)
            if key in frame_of:
                raise ValueError(f"{source}: sync_index {r.sync_index} names camera {k} twice")
            frame_of[key] = (f, r.frame_time)
    where = [{int(i): p for p, i in enumerate(row)} for row in indices]
    labels: list[str] = []
    index: list[list[int | None]] = [[] for _ in range(c)]
    stamps: list[list[float | None]] = [[] for _ in range(c)]
    for sync in sorted({r.sync_index for r in rows}):
        picks = []
        for k in range(c):
            f, t = frame_of.get((sync, k), (None, None))
            position = None if f is None else where[k].get(f)
            picks.append((position, None if position is None else t))
        if all(p is None for p, _ in picks):
            continue
        labels.append(str(sync))
        for k, (p, t) in enumerate(picks):
            index[k].append(p)
            stamps[k].append(t)
    return FrameTable(labels, index, "table order" if by_order else "table", stamps)
