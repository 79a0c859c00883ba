"""Which chessboard an image shows (``board_size_in``) and the size several views show instead of a given one."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.modules.detection.checks.board_size import (
    board_grid_in,
    board_size_in,
    other_board_size,
)

K = torch.tensor([[520.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


@pytest.mark.parametrize("board", [(9, 6), (4, 6), (7, 5)])
def test_rendered_boards_of_every_size(board):
    views = make_calibration_set(K, board, 0.03, (640, 480), num_views=6, seed=2, supersample=1)
    images = views.images[:, 0].numpy()
    # a view may take the white card's edge for one more row of corners, or stop short: what most views show is the
    # board, float or 8-bit
    for sizes in ([board_size_in(image) for image in images],
                  [board_size_in(np.uint8(image * 255)) for image in images]):
        assert sizes.count((max(board), min(board))) >= 4 and None not in sizes
        assert other_board_size(sizes, (3, 4)) == (max(board), min(board))


def test_large_images_are_searched_downscaled():
    big = torch.tensor([[2080.0, 0.0, 1280.0], [0.0, 2080.0, 960.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    views = make_calibration_set(big, (9, 6), 0.03, (2560, 1920), num_views=2, seed=3, supersample=1)
    sizes = [board_size_in(image) for image in views.images[:, 0].numpy()]
    assert views.images.shape[-1] > 1280 and (9, 6) in sizes


def test_no_board_and_bad_input():
    rng = np.random.default_rng(0)
    assert board_size_in(np.full((240, 320), 0.5, np.float32)) is None
    assert board_size_in(rng.integers(0, 255, (240, 320), dtype=np.uint8)) is None
    with pytest.raises(ValueError, match="grey"):
        board_size_in(np.zeros((240, 320, 3), np.uint8))


def test_agrees_with_opencv_classic_detector():
    views = make_calibration_set(K, (8, 5), 0.03, (640, 480), num_views=2, seed=4, supersample=1)
    image = (views.images[0, 0].numpy() * 255).astype(np.uint8)
    size = board_size_in(image)
    assert cv2.findChessboardCorners(image, size)[0] or cv2.findChessboardCorners(image, size[::-1])[0]


def test_other_board_size():
    assert other_board_size([(9, 6)] * 3 + [None] * 3, (7, 5)) == (9, 6)  # half of the views show it
    assert other_board_size([(9, 6)] * 2 + [None] * 4, (7, 5)) is None  # too few
    assert other_board_size([(9, 6)] * 5 + [(7, 5)], (5, 7)) is None  # the given board is seen: no other size
    assert other_board_size([None] * 6, (7, 5)) is None and other_board_size([], (7, 5)) is None
    assert other_board_size([(9, 6), (8, 6), (9, 6), (9, 6)], (7, 5)) == (9, 6)


def _flat_board(squares=(10, 7), side=24, margin=40) -> np.ndarray:
    board = np.kron((np.indices(squares[::-1]).sum(0) % 2).astype(np.uint8) * 255, np.ones((side, side), np.uint8))
    return np.pad(board, margin, constant_values=255)


def test_a_grid_cut_by_the_frame_is_no_evidence_of_its_size():
    image = _flat_board()  # a 9x6 board, whole
    assert board_grid_in(image) == ((9, 6), False)
    cut = image[:, :250]  # its last column of squares cut by the frame: 8x6 corners visible
    assert board_grid_in(cut) == ((8, 6), True)
    assert board_grid_in(_flat_board((9, 7))) == ((8, 6), False)  # a whole 8x6 board
    sizes = [(8, 6)] * 6
    assert other_board_size(sizes, (9, 6), cut=[True] * 6) is None  # partial views of the 9x6 board given
    assert other_board_size(sizes, (9, 6), cut=[False] * 6) == (8, 6)  # whole views of another board
    assert other_board_size([(9, 6)] * 6, (7, 5), cut=[True] * 6) == (9, 6)  # larger than given: cut or not
