"""Files written atomically and JSON that people can read: what every command writes goes through here.

A reader never sees a half-written file: the text goes to a temporary file in the same directory, which then
replaces the destination in one rename. JSON is strict (tensors and arrays as lists, NaN and infinities as ``null``)
and laid out one key a line, with lists of numbers and point lists on one line.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ccs_kornia.runtime.errors import UserError

__all__ = ["atomic_path", "json_line", "json_text", "text_path", "write_json", "write_text", "write_text_atomic"]


def text_path(path: str | os.PathLike) -> str:
    """A file name as text every reader accepts: bytes that are not UTF-8 (a camera or an old file system can write
    them; Python holds them as lone surrogates) written ``\\xNN``; a valid name is returned unchanged.

    The one rendering of file names in the JSON, the reports' pages and the text drawn on their figures (OpenCV's
    ``putText`` cannot take a lone surrogate, strict JSON readers refuse one).

    Example:
        >>> text_path(os.fsdecode(b"cam\\xff01.png"))
        'cam\\\\xff01.png'
        >>> text_path("left01.png")
        'left01.png'
    """
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    try:
        raw = text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:  # a surrogate no file name decodes to: shown as its code point
        return text.encode("utf-8", "backslashreplace").decode("utf-8")
    return raw.decode("utf-8", "backslashreplace")


def _json_default(obj: Any) -> Any:
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu().tolist()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return text_path(obj)
    raise TypeError(f"Object of type {type(obj).__name__} is not JSON serializable")


def _sanitize(obj: Any) -> Any:
    # JSON has no NaN/Infinity: write null instead so every JSON reader accepts the file; no lone surrogates either
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, str):  # a file name's bytes that are not UTF-8 escaped, never a lone surrogate
        return obj if obj.isascii() else text_path(obj)
    if isinstance(obj, dict):
        return {(_sanitize(k) if isinstance(k, str) else k): _sanitize(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_sanitize(v) for v in obj]
    if isinstance(obj, (torch.Tensor, np.ndarray, np.generic)):
        return _sanitize(_json_default(obj))
    return obj


def json_line(data: Any) -> str:
    """``data`` as one line of strict JSON (tensors/arrays as lists, NaN and infinities as ``null``).

    Example:
        >>> json_line({"rms": float("nan"), "K": torch.eye(2)})
        '{"rms": null, "K": [[1.0, 0.0], [0.0, 1.0]]}'
    """
    return json.dumps(_sanitize(data), default=_json_default, allow_nan=False)


def _is_flat(value: list) -> bool:
    """A list written on one line: scalars (``[fx, 0, cx]``) or lists of scalars (a point list ``[[x, y], ...]``)."""
    return all(not isinstance(v, (dict, list)) or (isinstance(v, list) and not any(isinstance(w, (dict, list))
                                                                                   for w in v)) for v in value)


def json_text(data: Any, indent: int = 1) -> str:
    """``data`` as strict JSON that people can read: objects one key a line, lists of numbers and point lists on one
    line (a view's corners ``[[x, y], ...]``), tensors and arrays as lists, NaN and infinities as ``null``.

    Example:
        >>> print(json_text({"K": torch.eye(2), "rms": float("nan")}))
        {
         "K": [[1.0, 0.0], [0.0, 1.0]],
         "rms": null
        }
    """
    def dump(value: Any, depth: int) -> str:
        pad, inner = " " * (indent * depth), " " * (indent * (depth + 1))
        if isinstance(value, dict) and value:
            items = [f"{inner}{json.dumps(str(k))}: {dump(v, depth + 1)}" for k, v in value.items()]
            return "{\n" + ",\n".join(items) + f"\n{pad}}}"
        if isinstance(value, list) and value and not _is_flat(value):
            return "[\n" + ",\n".join(inner + dump(v, depth + 1) for v in value) + f"\n{pad}]"
        return json.dumps(value, default=_json_default, allow_nan=False)

    return dump(_sanitize(data), 0)


def _file_mode() -> int:
    """The mode a new file gets under this process's umask (``0o666 & ~umask``; Linux 4.7+ reports the umask without
    it being set, elsewhere it is set and put back)."""
    try:
        with open("/proc/self/status", encoding="ascii") as handle:
            umask = next(int(line.split()[1], 8) for line in handle if line.startswith("Umask:"))
    except (OSError, ValueError, StopIteration):
        umask = os.umask(0o022)
        os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, mode: int | None = None) -> Iterator[str]:
    """A temporary path beside ``path`` to write to; on a clean exit it is renamed over ``path``, else removed.

    The one atomic writer of the package (JSON, text exports, OpenCV FileStorage files, images): a reader never sees
    a half-written file, and an existing file is only replaced once the new one is complete. A symbolic link is
    written through: its target gets the new file and the link stays. Only a regular file or a new path is written: a
    device, FIFO or socket is refused, never replaced by a file. The file gets the mode an ordinary write would give
    it: an existing file's own, else the one the umask implies (not the temporary file's private 600); ``mode``
    (e.g. ``0o644``) sets it explicitly.

    Raises:
        FileNotFoundError: the parent directory does not exist (it is not created).
        UserError: ``path`` exists and is not a regular file.

    Example:
        >>> import tempfile
        >>> target = os.path.join(tempfile.mkdtemp(), "a.txt")
        >>> with atomic_path(target) as tmp:
        ...     _ = open(tmp, "w").write("done")
        >>> open(target).read()
        'done'
    """
    path = os.path.realpath(os.fspath(path))  # through symbolic links: the rename replaces the target, not the link
    directory = os.path.dirname(path)
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"output directory does not exist: {directory}")
    if os.path.lexists(path) and not stat.S_ISREG(os.stat(path).st_mode):
        raise UserError(f"{path} exists and is not a regular file (a device, FIFO or socket is never replaced)")
    if mode is None:
        mode = os.stat(path).st_mode & 0o7777 if os.path.isfile(path) else _file_mode()
    fd, tmp = tempfile.mkstemp(prefix=".tmp_", suffix=os.path.splitext(path)[1], dir=directory)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path: str | os.PathLike, text: str, mode: int | None = None) -> None:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`)."""
    with atomic_path(path, mode) as tmp, open(tmp, "w", encoding="utf-8") as handle:
        handle.write(text)


def write_json(path: str | os.PathLike, data: Any, indent: int | None = 1, mode: int | None = None) -> None:
    """Write ``data`` as JSON atomically (:func:`atomic_path`), laid out as :func:`json_text` (``indent=None``: one
    line); tensors and arrays become lists, NaN and infinities ``null``.

    Raises:
        FileNotFoundError: the parent directory does not exist (it is not created).
    """
    text = json_line(data) if indent is None else json_text(data, indent)
    write_text(path, text + "\n", mode)


def write_text_atomic(option: str, path: str, text: str) -> None:
    """Write ``text`` to ``path`` atomically (mode 644); a file that cannot be written is a
    :class:`~ccs_kornia.runtime.errors.UserError` naming the user's ``option``."""
    try:
        write_text(path, text, mode=0o644)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot write ({err.strerror or err})") from None
