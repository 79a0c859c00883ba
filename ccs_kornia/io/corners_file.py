"""The corners file ``detect`` writes, read back: the board, the image size and each view's corners, so that a later
solve (``calibrate --corners``, ``calibrate-rig --corners``) runs on them without detecting again.

The file is ``detect``'s JSON (``docs/command_line.md``): ``{"board": [cols, rows], "images": [{"path", "found",
"corners": [[x, y] | [null, null], ...] | null, ...}], ...}``. What else a view may carry is read where present:
``timestamp`` (s, a video or bag frame), ``image_size`` ``[w, h]``, ``corner_sigma`` (each corner's measured
precision, px), ``method`` (how its board was found) and ``reason`` (why not). The file's top level may carry
``image_size``, ``charuco`` / ``aprilgrid`` (the marker board the corners are numbered on) and
``distortion_correction`` (the network's pooled lens correction).

Any file that is not such a JSON is refused in one line (:class:`~ccs_kornia.runtime.errors.UserError`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import torch

from ccs_kornia.runtime.errors import UserError

__all__ = ["CornersFile", "CornersView", "read_corners_file"]


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


def read_corners_file(path: str) -> CornersFile:
    """Read the corners JSON ``detect`` writes (module docstring).

    Args:
        path: the file.

    Returns:
        :class:`CornersFile`.

    Raises:
        UserError: the file cannot be read or is not ``detect``'s JSON (one line naming the file and what is wrong).
    """
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
