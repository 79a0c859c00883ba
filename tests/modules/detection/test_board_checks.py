"""Tests of the grid checks and the canonical corner order of a detected board."""

from __future__ import annotations

import numpy as np

from ccs_kornia.modules.detection.board_checks import board_extends, canonical_corner_order, check_grid


def _lattice(cols: int, rows: int, step: float = 20.0, origin=(50.0, 40.0)) -> np.ndarray:
    j, i = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return np.stack([origin[0] + step * i.ravel(), origin[1] + step * j.ravel()], -1).astype(np.float64)


def test_order_convention_is_applied_to_any_input():
    grid = _lattice(4, 3)
    rev = grid[::-1].copy()
    np.testing.assert_allclose(canonical_corner_order(rev, (4, 3)), grid)
    # square boards: the four rotations collapse to one
    square = _lattice(3, 3)
    rot = np.rot90(square.reshape(3, 3, 2), 1, axes=(0, 1)).reshape(-1, 2)
    np.testing.assert_allclose(canonical_corner_order(rot, (3, 3)), square)


def test_check_grid():
    good = _lattice(5, 4)
    assert check_grid(good, (5, 4), (640, 480)) == ""
    assert "expected 20 corners" in check_grid(good[:-1], (5, 4))
    folded = good.copy().reshape(4, 5, 2)
    folded[:, [1, 2]] = folded[:, [2, 1]]
    assert check_grid(folded.reshape(-1, 2), (5, 4)) != ""
    jump = good.copy().reshape(4, 5, 2)
    jump[:, 4, 0] += 60.0
    assert "jumps" in check_grid(jump.reshape(-1, 2), (5, 4))
    assert "outside" in check_grid(good + 600.0, (5, 4), (640, 480))


def test_board_extends_on_synthetic_image():
    # a 6x5-square board (5x4 inner corners) with a white margin
    img = np.ones((200, 260), np.float32)
    for r in range(5):
        for c in range(6):
            if (r + c) % 2 == 0:
                img[40 + 20 * r : 60 + 20 * r, 60 + 20 * c : 80 + 20 * c] = 0.0
    # inner corners sit at x = 79.5 + 20 i, y = 59.5 + 20 j
    full = _lattice(5, 4, 20.0, (79.5, 59.5))
    assert board_extends(img, full, (5, 4)) == ""
    sub = _lattice(4, 4, 20.0, (79.5, 59.5))
    assert board_extends(img, sub, (4, 4)) == "right"
