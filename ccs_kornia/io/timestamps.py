"""A rig recording's timestamps table: which frame of each camera's video belongs to which synchronised instant.

The layout is caliscope's ``timestamps.csv``: one row per camera and instant, ``sync_index,cam_id,frame_index,
frame_time`` (``frame_time`` in seconds, any origin shared by the cameras). ``cam_id`` is the camera's position on
the command line (0 for the first video). ``frame_index`` may be left out, as caliscope's own recordings do: a
camera's rows are then its video's frames in order of ``frame_time``, one row per frame (caliscope's reading, also
used where an older table's ``frame_index`` counts from the recording's start and runs past the end of a video:
:func:`~ccs_kornia.pipeline.frame_matching.match_by_table`).
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass

__all__ = ["TIMESTAMP_COLUMNS", "TimestampRow", "read_timestamps"]

#: the columns a table must have (``frame_index`` is optional)
TIMESTAMP_COLUMNS = ("sync_index", "cam_id", "frame_time")


@dataclass(frozen=True)
class TimestampRow:
    """One row: instant ``sync_index``, camera ``cam_id``, its frame ``frame_index`` (``None``: not given) taken at
    ``frame_time`` seconds."""

    sync_index: int
    cam_id: int
    frame_index: int | None
    frame_time: float


def _number(text: str, kind: type, column: str, line: int, path: str):
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{path} line {line}: {column} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{path} line {line}: {column} {text!r} is not a finite number")
    if kind is int:
        if value != int(value) or value < 0:
            raise ValueError(f"{path} line {line}: {column} {text!r} is not a whole number >= 0")
        return int(value)
    return value


def read_timestamps(path: str | os.PathLike) -> list[TimestampRow]:
    """The rows of a timestamps table, as written.

    Args:
        path: the CSV file (a header line naming the columns, in any order; other columns are ignored).

    Returns:
        The rows, in the file's order.

    Raises:
        ValueError: the file cannot be read, lacks a column, has a value that is not a number, or has no row (one
            line naming the file and the line).

    Example:
        >>> import tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "timestamps.csv")
        >>> _ = open(path, "w").write("sync_index,cam_id,frame_time\\n0,0,10.0\\n0,1,10.004\\n")
        >>> read_timestamps(path)[1]
        TimestampRow(sync_index=0, cam_id=1, frame_index=None, frame_time=10.004)
    """
    path = os.fspath(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            columns = [c.strip() for c in (reader.fieldnames or [])]
            missing = [c for c in TIMESTAMP_COLUMNS if c not in columns]
            if missing:
                raise ValueError(f"{path}: no column {', '.join(missing)} (a timestamps table has a header line "
                                 "sync_index,cam_id,frame_index,frame_time; frame_index may be left out)")
            rows = []
            for line, raw in enumerate(reader, start=2):
                row = {str(k).strip(): (v or "").strip() for k, v in raw.items() if k is not None}
                if not any(row.values()):
                    continue
                index = row.get("frame_index", "")
                rows.append(TimestampRow(
                    _number(row["sync_index"], int, "sync_index", line, path),
                    _number(row["cam_id"], int, "cam_id", line, path),
                    _number(index, int, "frame_index", line, path) if index != "" else None,
                    _number(row["frame_time"], float, "frame_time", line, path),
                ))
    except OSError as err:
        raise ValueError(f"cannot read {path} ({err.strerror or err})") from None
    except (UnicodeDecodeError, csv.Error) as err:
        raise ValueError(f"{path} is not a CSV text file ({err})") from None
    if not rows:
        raise ValueError(f"{path} has no rows")
    given = {r.frame_index is not None for r in rows}
    if len(given) > 1:
        raise ValueError(f"{path}: frame_index is given on some rows and not on others")
    return rows
