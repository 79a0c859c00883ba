"""The early stop of a wrong ``--board``: whole views of another board stop the run, partial views of the board given
(cut by the frame) never do."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ccs_kornia.commands._wrong_board import WrongBoardWatch
from ccs_kornia.io.images import write_image
from ccs_kornia.runtime.errors import NoResult


def _views(tmp_path, squares, crop=None) -> list[str]:
    side, margin = 24, 40
    board = np.kron((np.indices(squares[::-1]).sum(0) % 2).astype(np.float32), np.ones((side, side), np.float32))
    image = np.pad(board, margin, constant_values=1.0)
    files = []
    for k in range(6):
        shifted = np.roll(image, 2 * k, axis=0)
        path = tmp_path / f"view{k}.png"
        assert write_image(path, shifted if crop is None else shifted[:, :crop])
        files.append(str(path))
    return files


def _watch(files, board):
    watch = WrongBoardWatch([files], board)
    watch([(0, v) for v in range(len(files))], torch.zeros(len(files), dtype=torch.bool))


def test_partial_views_of_the_right_board_do_not_stop_the_run(tmp_path):
    files = _views(tmp_path, (10, 7), crop=250)  # a 9x6 board whose last column of squares the frame cuts
    _watch(files, (9, 6))  # no stop: the 8x6 corners seen may be the 9x6 board's


def test_whole_views_of_another_board_stop_the_run(tmp_path):
    files = _views(tmp_path, (9, 7))  # a whole 8x6 board
    with pytest.raises(NoResult, match="board 9x6 not found in the first 6 images, but a 8x6 board is in 6 of them"):
        _watch(files, (9, 6))
