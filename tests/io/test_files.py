"""The atomic writer: a symbolic link is written through to its target, anything but a regular file or a new path is
refused, and images go through it too."""

from __future__ import annotations

import os
import socket
import stat

import numpy as np
import pytest

from ccs_kornia.io.files import atomic_path, write_json, write_text
from ccs_kornia.io.images import write_image
from ccs_kornia.runtime.errors import UserError


def test_a_symbolic_link_is_written_through_to_its_target(tmp_path):
    target = tmp_path / "target.json"
    target.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_json(link, {"a": 1})
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_text() == '{\n "a": 1\n}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.json", "target.json"]  # no temporary file left


def test_a_dangling_link_creates_its_target(tmp_path):
    link = tmp_path / "link.txt"
    link.symlink_to(tmp_path / "new.txt")
    write_text(link, "done")
    assert link.is_symlink() and (tmp_path / "new.txt").read_text() == "done"


def test_a_fifo_is_refused_never_replaced(tmp_path):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    with pytest.raises(UserError, match="not a regular file"):
        write_json(fifo, {"a": 1})
    link = tmp_path / "link.json"
    link.symlink_to(fifo)
    with pytest.raises(UserError, match="not a regular file"), atomic_path(link):
        pass
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.json", "pipe.json"]


def test_a_socket_is_refused(tmp_path):
    path = str(tmp_path / "s.json")
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(path)
        with pytest.raises(UserError, match="not a regular file"):
            write_text(path, "x")
        assert stat.S_ISSOCK(os.lstat(path).st_mode)


def test_an_image_goes_through_the_atomic_writer(tmp_path):
    target = tmp_path / "view.png"
    target.write_bytes(b"old")
    link = tmp_path / "link.png"
    link.symlink_to(target)
    assert write_image(link, np.full((4, 6), 0.5, np.float32))
    assert link.is_symlink() and target.read_bytes()[:4] == b"\x89PNG"
    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)
    with pytest.raises(UserError):
        write_image(fifo, np.zeros((4, 6), np.float32))
