"""Tests of BoardScreen: the quick first look at a frame (chessboards, ChArUco boards, AprilGrids)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard
from ccs_kornia.modules.detection.screening import BoardScreen, Sighting, grid_outline


def _chessboard_frame(size=(640, 480), at=(100, 80), px=40, board=(7, 5)) -> np.ndarray:
    squares = (np.indices((board[1] + 1, board[0] + 1)).sum(0) % 2) * 255
    pattern = np.kron(squares, np.ones((px, px))).astype(np.uint8)
    frame = np.full((size[1], size[0]), 128, np.uint8)
    frame[at[1]:at[1] + pattern.shape[0], at[0]:at[0] + pattern.shape[1]] = pattern
    return frame


def test_chessboard_outline_in_full_size_pixels():
    frame = _chessboard_frame()
    seen = BoardScreen((7, 5), max_side=320)(frame)  # looked at on a half-size copy
    assert seen.found and seen.points == 35
    # the inner-corner grid's extreme corners: (100 + 40 - 0.5, 80 + 40 - 0.5) ... (100 + 280 - 0.5, 80 + 200 - 0.5)
    expected = np.array([[139.5, 119.5], [379.5, 119.5], [379.5, 279.5], [139.5, 279.5]])
    got = seen.outline
    best = min(np.abs(np.roll(got, r, axis=0) - expected).max() for r in range(4))
    assert best < 1.5


def test_shrunk_copy_with_full_size_gives_the_same_outline():
    frame = _chessboard_frame()
    screen = BoardScreen((7, 5), max_side=320)
    direct = screen(frame)
    shrunk = screen(screen.shrink(frame), full_size=(640, 480))
    assert np.allclose(direct.outline, shrunk.outline)
    assert screen.scale((640, 480)) == 0.5 and screen.scale((200, 100)) == 1.0


def test_no_board_and_wrong_board():
    blank = np.full((240, 320), 128, np.uint8)
    assert BoardScreen((7, 5))(blank) == Sighting(False)
    assert not BoardScreen((9, 6))(_chessboard_frame()).found


def test_charuco_markers_outline_plain_inverted_and_mirrored():
    board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
    image = board.render(60, margin=60)
    screen = BoardScreen(board.board_size, board, max_side=image.shape[1])
    plain = screen(image)
    assert plain.found and plain.points == 17
    # the first inner corner is at one square from the board's corner: (60 + 60 - 0.5, 60 + 60 - 0.5)
    assert np.allclose(plain.outline[0], [119.5, 119.5], atol=1.0)
    assert np.allclose(plain.outline[2], [60 + 4 * 60 - 0.5, 60 + 6 * 60 - 0.5], atol=1.0)
    inverted = screen(255 - image)
    assert inverted.found and np.allclose(inverted.outline, plain.outline, atol=1.0)
    mirrored = screen(cv2.flip(image, 1))  # a two-sided board's back
    assert mirrored.found and mirrored.points == 17


def test_partial_charuco_view_still_has_an_outline():
    board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
    image = board.render(60, margin=60)[:260]  # only the top rows of markers
    seen = BoardScreen(board.board_size, board, max_side=image.shape[1])(image)
    assert seen.found and 2 <= seen.points < 17
    assert seen.outline[2, 1] > image.shape[0]  # the grid's far corner lies outside the view
    # a marker board's partial views are seen, a chessboard's are not (its test needs the whole board)
    assert BoardScreen(board.board_size, board).sees_partial_boards
    assert not BoardScreen((9, 6)).sees_partial_boards


def test_aprilgrid_tags():
    grid = AprilGrid(4, 3, 0.05, 0.3)
    image = grid.render(6)
    seen = BoardScreen(grid.board_size, grid, max_side=max(image.shape))(image)
    assert seen.found and seen.points == 12 and seen.outline.shape == (4, 2)


def test_grid_outline_order():
    corners = np.arange(24, dtype=float).reshape(12, 2)
    assert grid_outline(corners, (4, 3)).tolist() == [corners[0].tolist(), corners[3].tolist(), corners[11].tolist(),
                                                      corners[8].tolist()]


@pytest.mark.parametrize("kwargs, phrase", [({"board_size": (1, 5)}, "board_size"),
                                            ({"board_size": (5, 4), "max_side": 32}, "max_side")])
def test_bad_arguments(kwargs, phrase):
    with pytest.raises(ValueError, match=phrase):
        BoardScreen(**kwargs)
