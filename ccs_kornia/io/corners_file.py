"""The corners file ``detect`` writes, read back: the board, the image size and each view's corners, so that a later
solve (``calibrate --corners``, ``calibrate-rig --corners``) runs on them without detecting again.

The file is ``detect``'s JSON (``docs/command_line.md``): ``{"board": [cols, rows], "images": [{"path", "found",
"corners": [[x, y] | [null, null], ...] | null, ...}], ...}``. What else a view may carry is read where present:
``timestamp`` (s, a video or bag frame), ``image_size`` ``[w, h]``, ``corner_sigma`` (each corner's measured
precision, px), ``method`` (how its board was found) and ``reason`` (why not). The file's top level may carry
``image_size``, ``charuco`` / ``aprilgrid`` (the marker board the corners are numbered on) and
``distortion_correction`` (the network's pooled lens correction).

mrcal's ``corners.vnl`` (as mrgingham writes it) is read too (:func:`read_corners_vnl`): ``# filename x y level``, one
line per corner, the board's corners row by row, a view's lines together (``filename - -``: no board in that image).
It says neither the board nor the images' size, so the board comes from the command's board options and the size from
``--image-size``. A corner's ``level`` (the pyramid level it was found at) gives its precision as mrcal weighs it: its
weight is ``0.5 ** level`` on the residual, an inverse variance ``0.25 ** level``, so its ``sigma`` is ``2 ** level``
(relative; ``level`` ``-``: a corner left out, not seen).

Any file that is neither is refused in one line (:class:`~ccs_kornia.runtime.errors.UserError`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import torch

from ccs_kornia.runtime.errors import UserError

__all__ = ["CornersFile", "CornersView", "read_corners_file", "read_corners_vnl"]


@dataclass(frozen=True)
class CornersView:
    """One view of a corners file.

    Attributes:
        path: the view's name as ``detect`` wrote it (a file path, ``VIDEO#INDEX``, ``BAG#TOPIC#INDEX``).
        found: the board was found on it.
        corners: :math:`(N, 2)` float64 pixels in grid order, NaN where the corner was not seen (all NaN where no
            board was found).
        timestamp: the view's time (s) where it has one (video and bag frames), else ``None``.
        image_size: ``(W, H)`` of the view where the file gives it (``None``: not read, or not said).
        sigma: :math:`(N,)` float64 each corner's measured precision (px), NaN where not measured; ``None`` where the
            file gives none.
        reason: why the view has no board (``"board not found"``, ``"unreadable: ..."``) or how its board was found
            (``detect``'s ``method``); ``""`` where the file says nothing.
    """

    path: str
    found: bool
    corners: torch.Tensor
    timestamp: float | None = None
    image_size: tuple[int, int] | None = None
    sigma: torch.Tensor | None = None
    reason: str = ""

    @property
    def readable(self) -> bool:
        """The view's image was read when the corners were detected (an unreadable one has no corners to give)."""
        return not self.reason.startswith("unreadable")


@dataclass(frozen=True)
class CornersFile:
    """A corners file read back (:func:`read_corners_file`).

    Attributes:
        path: the file.
        board: ``(cols, rows)`` as the file's ``board`` gives it (inner corners; a marker board's corner grid).
        views: one :class:`CornersView` per image, in the file's order.
        image_size: ``(W, H)`` from the file's ``image_size``, else the size most of its views with a board give,
            else ``None`` (files written before ``detect`` recorded sizes).
        charuco: the file's ``charuco`` record (``None``: not a ChArUco board).
        aprilgrid: the file's ``aprilgrid`` record (``None``: not an AprilGrid).
        circles: the file's ``circles`` record (``None``: not a circle grid).
        correction: the network's pooled lens correction :math:`(5,)` where the file gives it, else ``None``.

    Example:
        >>> import json, os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "corners.json")
        >>> views = [{"path": "a.png", "found": True, "corners": [[1, 2], [3, 4], [None, None], [5, 6]]},
        ...          {"path": "b.png", "found": False, "corners": None, "timestamp": 0.5}]
        >>> with open(path, "w") as f:
        ...     json.dump({"board": [2, 2], "image_size": [64, 48], "images": views}, f)
        >>> cf = read_corners_file(path)
        >>> cf.board, cf.image_size, cf.corners.shape, cf.views[0].corners[2].isnan().all().item(), cf.timestamps
        ((2, 2), (64, 48), torch.Size([2, 4, 2]), True, [None, 0.5])
    """

    path: str
    board: tuple[int, int]
    views: list[CornersView]
    image_size: tuple[int, int] | None = None
    charuco: dict[str, Any] | None = None
    aprilgrid: dict[str, Any] | None = None
    correction: torch.Tensor | None = None
    circles: dict[str, Any] | None = None

    @property
    def corners(self) -> torch.Tensor:
        """:math:`(V, N, 2)` float64, every view's corners (NaN where not seen)."""
        n = self.board[0] * self.board[1]
        if not self.views:
            return torch.empty(0, n, 2, dtype=torch.float64)
        return torch.stack([v.corners for v in self.views])

    @property
    def timestamps(self) -> list[float | None]:
        """Every view's timestamp (s) or ``None``."""
        return [v.timestamp for v in self.views]


def _size(value: Any, where: str) -> tuple[int, int] | None:
    if value is None:
        return None
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and x == int(x) and x > 0
                       for x in value)):
        raise ValueError(f"{where} is {value!r}, not [width, height] in pixels")
    return int(value[0]), int(value[1])


def _number(value: Any) -> float:
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{value!r} is not a number")
    return float(value)


def _view(item: Any, k: int, n: int) -> CornersView:
    where = f"images[{k}]"
    if not isinstance(item, dict) or not isinstance(item.get("path"), str) or not isinstance(item.get("found"), bool):
        raise ValueError(f"{where} is not a view of detect's (an object with path, found and corners)")
    found = item["found"]
    raw = item.get("corners")
    corners = torch.full((n, 2), math.nan, dtype=torch.float64)
    if found:
        if not isinstance(raw, list) or len(raw) != n:
            got = "no corners" if not isinstance(raw, list) else f"{len(raw)} corners"
            raise ValueError(f"{where} ({item['path']}): {got} for a board of {n}")
        try:
            values = [[_number(c) for c in xy] for xy in raw]
        except (TypeError, ValueError) as err:
            raise ValueError(f"{where} ({item['path']}): a corner is not [x, y] ({err})") from None
        if any(len(xy) != 2 for xy in values):
            raise ValueError(f"{where} ({item['path']}): a corner is not [x, y]")
        corners = torch.tensor(values, dtype=torch.float64).reshape(n, 2)
        corners[~corners.isfinite().all(-1)] = math.nan
    sigma = None
    if item.get("corner_sigma") is not None:
        raw_sigma = item["corner_sigma"]
        if not isinstance(raw_sigma, list) or len(raw_sigma) != n:
            raise ValueError(f"{where} ({item['path']}): corner_sigma is not one number per corner")
        try:
            sigma = torch.tensor([_number(s) for s in raw_sigma], dtype=torch.float64)
        except ValueError as err:
            raise ValueError(f"{where} ({item['path']}): corner_sigma: {err}") from None
    timestamp = item.get("timestamp")
    if timestamp is not None and (isinstance(timestamp, bool) or not isinstance(timestamp, (int, float))
                                  or not math.isfinite(timestamp)):
        raise ValueError(f"{where} ({item['path']}): timestamp {timestamp!r} is not a number of seconds")
    reason = item.get("method") if found else item.get("reason")
    return CornersView(item["path"], found, corners, None if timestamp is None else float(timestamp),
                       _size(item.get("image_size"), f"{where}'s image_size"), sigma,
                       reason if isinstance(reason, str) else "")


def _main_size(views: list[CornersView]) -> tuple[int, int] | None:
    """The size most views with a board have (else most readable views), as a camera's image size is chosen."""
    for pick in ([v for v in views if v.found], views):
        sizes = [v.image_size for v in pick if v.image_size is not None]
        if sizes:
            return max(dict.fromkeys(sizes), key=sizes.count)
    return None


def is_vnl(path: str) -> bool:
    """The file is a vnl table (mrcal's ``corners.vnl``): its first line is a ``#`` header naming ``filename``."""
    try:
        with open(path, encoding="utf-8") as handle:
            first = handle.readline()
    except (OSError, UnicodeDecodeError):
        return False
    return first.startswith("#") and "filename" in first.split()


def _vnl_number(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{where}: {text!r} is not a finite number")
    return value


def read_corners_vnl(path: str, board: tuple[int, int]) -> CornersFile:
    """Read mrcal's ``corners.vnl`` (module docstring) for a ``board`` of ``(cols, rows)`` inner corners.

    Args:
        path: the file.
        board: ``(cols, rows)``: each view with a board has ``cols * rows`` lines, row by row of the board.

    Returns:
        :class:`CornersFile` without an image size (the file does not say it), each view's ``sigma`` ``2 ** level``.

    Raises:
        UserError: the file cannot be read, a line is not ``filename x y [level]``, or a view has another number of
            corners than the board (one line naming the file and the line).

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "corners.vnl")
        >>> rows = ["# filename x y level", "a.jpg 1 2 0", "a.jpg 3 4 1", "a.jpg 5 6 -", "a.jpg 7 8 0", "b.jpg - -"]
        >>> with open(path, "w") as f:
        ...     _ = f.write("\\n".join(rows) + "\\n")
        >>> cf = read_corners_vnl(path, (2, 2))
        >>> [v.found for v in cf.views], cf.views[0].sigma.tolist(), cf.views[0].corners[2].isnan().all().item()
        ([True, False], [1.0, 2.0, nan, 1.0], True)
    """
    cols, rows = board
    n = cols * rows
    try:
        with open(path, encoding="utf-8") as handle:
            lines = handle.read().splitlines()
    except OSError as err:
        raise UserError(f"--corners {path}: cannot read ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise UserError(f"--corners {path}: not a text file (expected mrcal's corners.vnl)") from None
    order: list[str] = []
    seen: dict[str, list[tuple[int, list[str]]]] = {}
    try:
        for k, line in enumerate(lines, 1):
            fields = line.split()
            if not fields or fields[0].startswith("#"):
                continue
            if len(fields) not in (3, 4):
                raise ValueError(f"line {k}: expected filename x y [level], got {len(fields)} fields")
            if fields[0] not in seen:
                order.append(fields[0])
                seen[fields[0]] = []
            elif order[-1] != fields[0]:
                raise ValueError(f"line {k}: the corners of {fields[0]} are not together")
            seen[fields[0]].append((k, fields[1:]))
        views = []
        for name in order:
            entries = seen[name]
            if len(entries) == 1 and entries[0][1][0] == "-":
                views.append(CornersView(name, False, torch.full((n, 2), math.nan, dtype=torch.float64),
                                         reason="board not found"))
                continue
            if len(entries) != n:
                raise ValueError(f"{name}: {len(entries)} corners for a {cols}x{rows} board of {n} (--board)")
            corners = torch.full((n, 2), math.nan, dtype=torch.float64)
            sigma = torch.full((n,), math.nan, dtype=torch.float64)
            for j, (k, values) in enumerate(entries):
                level = values[2] if len(values) == 3 else "0"
                if values[0] == "-" or level == "-":
                    continue
                corners[j, 0] = _vnl_number(values[0], f"line {k}")
                corners[j, 1] = _vnl_number(values[1], f"line {k}")
                sigma[j] = 2.0 ** _vnl_number(level, f"line {k}")
            views.append(CornersView(name, True, corners, sigma=sigma))
    except ValueError as err:
        raise UserError(f"--corners {path}: {err}") from None
    if not views:
        raise UserError(f"--corners {path}: no corners (expected mrcal's corners.vnl: filename x y level)")
    return CornersFile(path, (cols, rows), views)


def read_corners_file(path: str, board: tuple[int, int] | None = None) -> CornersFile:
    """Read the corners JSON ``detect`` writes, or mrcal's ``corners.vnl`` (module docstring).

    Args:
        path: the file.
        board: ``(cols, rows)`` of the board, which a vnl file does not say (``None``: a vnl file is refused).

    Returns:
        :class:`CornersFile`.

    Raises:
        UserError: the file cannot be read or is neither ``detect``'s JSON nor a corners vnl table (one line naming
            the file and what is wrong).
    """
    if is_vnl(path):
        if board is None:
            raise UserError(f"--corners {path}: a vnl table does not say its board: give the board options")
        return read_corners_vnl(path, board)
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except OSError as err:
        raise UserError(f"--corners {path}: cannot read ({err.strerror or err})") from None
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise UserError(f"--corners {path}: not a JSON file (expected the corners file detect writes)") from None
    try:
        if not isinstance(data, dict) or "images" not in data or "board" not in data:
            what = "a calibration, " if isinstance(data, dict) and "K" in data else ""
            raise ValueError(f"{what}not the corners file detect writes (it has no board and images)")
        board = data["board"]
        if (not isinstance(board, list) or len(board) != 2
                or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 2 for x in board)):
            raise ValueError(f"board is {board!r}, not [cols, rows]")
        images = data["images"]
        if not isinstance(images, list):
            raise ValueError("images is not a list of views")
        n = board[0] * board[1]
        views = [_view(item, k, n) for k, item in enumerate(images)]
        size = _size(data.get("image_size"), "image_size") or _main_size(views)
        correction = None
        record = data.get("distortion_correction")
        if isinstance(record, dict) and record.get("enabled") and record.get("correction") is not None:
            values = record["correction"]
            if not isinstance(values, list) or len(values) != 5:
                raise ValueError("distortion_correction.correction is not 5 numbers")
            correction = torch.tensor([_number(x) for x in values], dtype=torch.float64)
        charuco, aprilgrid, circles = data.get("charuco"), data.get("aprilgrid"), data.get("circles")
        for key, value in (("charuco", charuco), ("aprilgrid", aprilgrid), ("circles", circles)):
            if value is not None and not isinstance(value, dict):
                raise ValueError(f"{key} is not a board record")
    except ValueError as err:
        raise UserError(f"--corners {path}: {err}") from None
    return CornersFile(path, (board[0], board[1]), views, size, charuco, aprilgrid, correction, circles)
