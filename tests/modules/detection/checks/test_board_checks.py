"""Tests of the grid checks and the canonical corner order of a detected board."""

from __future__ import annotations

import numpy as np
import pytest

from ccs_kornia.modules.detection.checks.board_checks import (
    _noise_margin,
    _sample,
    board_extends,
    canonical_corner_order,
    check_grid,
    check_saddles,
    skipped_line,
    whole_board_check,
)


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


def _checker_image(square: int = 16, size: int = 160) -> np.ndarray:
    yy, xx = np.mgrid[:size, :size]
    return ((xx // square + yy // square) % 2).astype(np.float32)  # corners at square - 0.5 + square k


def test_skipped_line_spares_a_board_and_refuses_every_other_corner():
    img = _checker_image()
    board = _lattice(5, 4, 16.0, (31.5, 31.5))
    assert skipped_line(img, board, (5, 4)) == "" and check_saddles(img, board, (5, 4)) == ""
    every_other = _lattice(4, 3, 32.0, (15.5, 15.5))  # the corners between them are saddles too
    assert "skips a row" in skipped_line(img, every_other, (4, 3))
    assert "skips" in check_saddles(img, every_other, (4, 3)), "check_saddles runs the same test first"
    # every other corner along the rows only: the midpoints along a row are corners, those down a column edges
    along_rows = _lattice(3, 4, 16.0, (31.5, 31.5))
    along_rows[:, 0] = 31.5 + 2.0 * (along_rows[:, 0] - 31.5)
    assert "skips a row" in skipped_line(img, along_rows, (3, 4))
    down_columns = _lattice(3, 4, 16.0, (31.5, 31.5))
    down_columns[:, 1] = 31.5 + 2.0 * (down_columns[:, 1] - 31.5)
    assert "skips a column" in skipped_line(img, down_columns, (3, 4))


def test_box_sample_is_the_box_mean_and_nan_outside():
    img = np.arange(100, dtype=np.float32).reshape(10, 10)
    out = _sample(img, np.array([[4.0, 5.0], [0.0, 0.0], [7.6, 2.2], [9.0, 5.0]]), 1.0)
    assert out[0] == img[4:7, 3:6].mean() and out[2] == img[1:4, 7:10].mean()
    assert np.isnan(out[1]) and np.isnan(out[3]), "a box leaving the image has no mean"


def test_skipped_line_judges_partial_boards_on_their_measured_corners():
    img = _checker_image()
    board = _lattice(5, 4, 16.0, (31.5, 31.5))
    board[7] = np.nan  # a hidden corner of a partial board
    assert skipped_line(img, board, (5, 4)) == ""
    every_other = _lattice(4, 3, 32.0, (15.5, 15.5))
    every_other[5] = np.nan
    assert "skips a row" in skipped_line(img, every_other, (4, 3))


def _charuco_image(square: int = 24, size: int = 264, fill: float = 0.6) -> np.ndarray:
    """A checker whose white squares carry a dark marker block of side ``fill`` squares (ChArUco-like)."""
    img = _checker_image(square, size)
    margin = int(round(square * (1 - fill) / 2))
    for y0 in range(0, size, square):
        for x0 in range(0, size, square):
            if img[y0, x0] > 0.5:
                img[y0 + margin:y0 + square - margin, x0 + margin:x0 + square - margin] = 0.0
    return img


def test_skipped_line_refuses_a_lattice_through_every_other_corner_of_a_marked_board():
    # bench section 6, ChArUco renders: a network missed the corners of one parity, the organiser joined the others
    # along steps (2, 0) and (1, 1) squares into an 8 x 5 board whose 20 other corners fell off the board ('hidden')
    img, s = _charuco_image(), 24
    cols, rows = 8, 5
    board = np.full((rows, cols, 2), np.nan)
    for r in range(rows):
        for c in range(cols):
            i, j = 2 * c - r - 3, r  # in squares; the lattice's corners are those on the board below
            if 0 <= i <= 8 and 0 <= j <= 8:
                board[r, c] = (s * (i + 1) - 0.5, s * (j + 1) - 0.5)
    assert 12 <= np.isfinite(board[..., 0]).sum() < cols * rows
    assert "skips a row" in skipped_line(img, board.reshape(-1, 2), (cols, rows))
    # the true partial board with the same corners hidden passes
    true = _lattice(cols, rows, float(s), (s - 0.5, s - 0.5)).reshape(rows, cols, 2)
    true[~np.isfinite(board[..., 0])] = np.nan
    assert skipped_line(img, true.reshape(-1, 2), (cols, rows)) == ""


def test_whole_board_check_runs_each_part_where_asked():
    img = _checker_image(16, 160)  # corners at 15.5 + 16 k: 9 x 9 of them, the checker runs to the image's edge
    board = _lattice(5, 4, 16.0, (31.5, 31.5))
    assert "continues past" in whole_board_check(img, board, (5, 4)), "a sub-board of the image's checker"
    assert whole_board_check(img, board, (5, 4), extends=False) == ""
    every_other = _lattice(4, 3, 32.0, (15.5, 15.5))
    assert "skips a row" in whole_board_check(img, every_other, (4, 3))
    assert whole_board_check(img, every_other, (4, 3), skipped=False, extends=False) == ""
    bent = board.copy()
    bent[7] += (4.0, 0.0)  # a quarter square off its neighbours' lattice
    assert "squares off its neighbours' lattice" in whole_board_check(img, bent, (5, 4), max_deviation=0.08)
    assert "squares off" not in whole_board_check(img, board, (5, 4), max_deviation=0.08)


def test_whole_board_check_spares_a_whole_board_and_answers_the_first_failure():
    img = np.ones((200, 260), np.float32)  # a 6 x 5-square board on a white margin, corners at 79.5 + 20 i, 59.5 + 20 j
    for r in range(5):
        for c in range(6):
            if (r + c) % 2 == 0:
                img[40 + 20 * r : 60 + 20 * r, 60 + 20 * c : 80 + 20 * c] = 0.0
    full = _lattice(5, 4, 20.0, (79.5, 59.5))
    assert whole_board_check(img, full, (5, 4), max_deviation=0.08) == ""
    sub = _lattice(4, 4, 20.0, (79.5, 59.5))
    assert whole_board_check(img, sub, (4, 4)) == "the checker pattern continues past its right side"
    sub[5] += (5.0, 0.0)
    assert "squares off" in whole_board_check(img, sub, (4, 4), max_deviation=0.08), "the lattice is judged first"


def _foreshortened(noise: float, seed: int) -> np.ndarray:
    """A dark checker foreshortened 1.8:1 (squares 18 x 10 px, contrast 0.2) with Gaussian noise."""
    yy, xx = np.mgrid[:120, :200]
    img = ((xx // 18 + yy // 10) % 2).astype(np.float32) * 0.2 + 0.1
    return img + np.random.default_rng(seed).normal(0.0, noise, img.shape).astype(np.float32)


def test_noise_margin_follows_the_image_noise():
    board = np.stack(np.meshgrid(np.arange(1, 10) * 18 - 0.5, np.arange(1, 11) * 10 - 0.5, indexing="xy"), -1)
    assert _noise_margin(_foreshortened(0.0, 0), board, 1.0) < 0.02  # the edges alone
    # two standard deviations of a strength minus an asymmetry of 3x3 box means
    assert _noise_margin(_foreshortened(0.06, 0), board, 1.0) == pytest.approx(2 * np.sqrt(3) * 0.06 / 3, rel=0.15)


def test_skipped_line_under_noise_spares_a_board_and_still_refuses_a_skipped_row():
    grid = np.stack(np.meshgrid(np.arange(1, 10) * 18 - 0.5, np.arange(1, 11) * 10 - 0.5, indexing="xy"), -1).reshape(-1, 2)
    every_other = np.stack(np.meshgrid(np.arange(1, 10) * 18 - 0.5, np.arange(1, 11, 2) * 10 - 0.5, indexing="xy"),
                           -1).reshape(-1, 2)
    for seed in range(8):
        img = _foreshortened(0.07, seed)  # noise a third of the contrast (a photograph in the dark)
        jitter = np.random.default_rng(100 + seed).uniform(-0.7, 0.7, grid.shape)  # corners as fitted in that noise
        assert skipped_line(img, grid + jitter, (9, 10)) == ""
        assert "skips a column" in skipped_line(img, every_other, (9, 5))  # a corner halfway down each column
