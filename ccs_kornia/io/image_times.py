"""A table of image files and the times they were taken: ``calibrate-imu``'s ``--timestamps`` for a folder of images
whose names are not their times.

Two columns, in either order: the file's name (as in the folder, or a path ending in it) and its timestamp. EuRoC's
``data.csv`` (``#timestamp [ns],filename``) reads as it is. The unit is the header's (``[ns]``, ``[us]``, ``[ms]``,
``[s]``) where it names one; otherwise nanoseconds where neighbouring images are more than 1e5 apart (no camera takes
a frame a day), else seconds.
"""

from __future__ import annotations

import csv
import math
import os
import re
import statistics

__all__ = ["read_image_times"]

_UNITS = {"ns": 1e-9, "us": 1e-6, "ms": 1e-3, "s": 1.0}


def _float(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def read_image_times(path: str | os.PathLike) -> dict[str, float]:
    """The table's images by file name (the last path component) and their timestamps in seconds.

    Raises:
        ValueError: one line: the file cannot be read, a row is not a name and a number, a name repeats, no row.

    Example:
        >>> import tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "data.csv")
        >>> _ = open(path, "w").write("#timestamp [ns],filename\\n1403636579763555584,a.png\\n1403636579813555456,b.png\\n")
        >>> round(read_image_times(path)["b.png"] - read_image_times(path)["a.png"], 6)
        0.05
    """
    path = os.fspath(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            lines = list(csv.reader(handle))
    except OSError as err:
        raise ValueError(f"cannot read {path} ({err.strerror or err})") from None
    except (UnicodeDecodeError, csv.Error) as err:
        raise ValueError(f"{path} is not a CSV text file ({err})") from None
    scale, rows = None, []
    for number, fields in enumerate(lines, start=1):
        fields = [f.strip() for f in fields if f.strip()]
        if not fields:
            continue
        values = [_float(f) for f in fields]
        if number == 1 and (fields[0].startswith("#") or all(v is None for v in values)):
            unit = re.search(r"\[(ns|us|ms|s)\]", ",".join(fields))
            scale = _UNITS[unit.group(1)] if unit else None
            continue
        if len(fields) != 2 or (values[0] is None) == (values[1] is None):
            raise ValueError(f"{path} line {number}: expected an image's file name and its timestamp, got "
                             f"{','.join(fields)!r}")
        t, name = (values[0], fields[1]) if values[0] is not None else (values[1], fields[0])
        rows.append((os.path.basename(name.replace("\\", "/")), t))
    if not rows:
        raise ValueError(f"{path} has no rows")
    names = [n for n, _ in rows]
    if len(set(names)) < len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"{path}: {twice} is listed twice")
    if scale is None:
        times = sorted(t for _, t in rows)
        gaps = [b - a for a, b in zip(times, times[1:]) if b > a]
        scale = 1e-9 if gaps and statistics.median(gaps) > 1e5 else 1.0
    return {n: t * scale for n, t in rows}
