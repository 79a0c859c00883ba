"""The commands' output paths, checked before any work: a file or folder that could not be written, or two outputs
naming one path, stop the command at once with one line (exit status 2), instead of after the whole calibration."""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Sequence

from ccs_kornia.runtime.errors import UserError

__all__ = ["check_outputs", "make_dir"]

#: ``(option, path)`` pairs; a ``None`` or empty path is an output not asked for
Outputs = Sequence[tuple[str, "str | None"]]


def _try_write_in(option: str, path: str, directory: str) -> None:
    """Create and remove a temporary file in ``directory``: the only sure test that files can be written there
    (``os.access`` says yes for root in ``/proc`` or on a read-only mount)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".ccs_write_test_", dir=directory)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot write in {directory} ({err.strerror or err})") from None
    os.close(fd)
    os.unlink(probe)


def _check_file(option: str, path: str) -> None:
    """Refuse an output file that could not be written: a directory, a missing parent directory (not created, so a
    mistyped path fails at once), a directory where no file can be created, an existing file that is not writable,
    or something that is not a regular file (a FIFO, a device). A symbolic link is written through, to its target."""
    target = os.path.realpath(path)
    directory = os.path.dirname(target)
    if os.path.isdir(target):
        raise UserError(f"{option} {path} is a directory; give a file name")
    if not os.path.isdir(directory):
        raise UserError(f"{option} {path}: output directory {directory} does not exist (create it first)")
    if not os.access(directory, os.W_OK):
        raise UserError(f"{option} {path}: output directory {directory} is not writable")
    if os.path.lexists(target):
        if not stat.S_ISREG(os.stat(target).st_mode):
            raise UserError(f"{option} {path} exists and is not a regular file (a device, FIFO or socket is never "
                            "replaced); give a file name")
        if not os.access(target, os.W_OK):
            raise UserError(f"{option} {path}: the existing file is not writable")
    _try_write_in(option, path, directory)


def _check_dir(option: str, path: str) -> None:
    """Refuse an output directory that could not be made or written, without creating it (a run that fails leaves no
    empty directory behind; :func:`make_dir` creates it once there is something to write)."""
    target = os.path.abspath(path)
    if os.path.exists(target) and not os.path.isdir(target):
        raise UserError(f"{option} {path} exists and is not a directory")
    existing = target
    while not os.path.isdir(existing):  # the nearest existing ancestor is where the first directory gets created
        parent = os.path.dirname(existing)
        if os.path.exists(existing) or parent == existing:
            raise UserError(f"{option} {path}: cannot create directory ({existing} is not a directory)")
        existing = parent
    _try_write_in(option, path, existing)


def check_outputs(files: Outputs = (), dirs: Outputs = ()) -> None:
    """The one check of a command's outputs, before any work: every output file (``files``) and directory (``dirs``)
    can be written, and no two outputs name the same path (through symbolic links too): one would replace the other.

    Raises:
        UserError: one line naming the option (exit status 2); nothing has been written.
    """
    seen: dict[str, str] = {}
    for kind, outputs in (("file", files), ("dir", dirs)):
        for option, path in outputs:
            if not path:
                continue
            key = os.path.realpath(path)
            if key in seen:
                raise UserError(f"{seen[key]} and {option} name the same path {path}: one would replace the other; "
                                "give each output its own")
            seen[key] = option
            (_check_file if kind == "file" else _check_dir)(option, path)


def make_dir(option: str, path: str) -> None:
    """Create the output directory of ``option`` (and its parents); one line where it cannot be made."""
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot create directory ({err.strerror or err})") from None
    if not os.path.isdir(path):
        raise UserError(f"{option} {path} exists and is not a directory")
