from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.grid.missing_corners import (
    lattice_deviation,
    unconfirmed_corners,
)


class TestUnconfirmedCorners:
    def test_smoke_and_shape(self):
        out = unconfirmed_corners(torch.ones(3, 12, dtype=torch.bool), (4, 3))
        assert out.shape == (3, 12) and out.dtype == torch.bool and not bool(out.any())

    def test_what_confirms_a_corner(self):
        valid = torch.zeros(1, 5, 6, dtype=torch.bool)  # rows x cols
        valid[0, 0, 0] = True  # alone at the board's corner
        valid[0, 1, 1] = True  # its diagonal neighbour: no row or column prediction for either
        valid[0, 3, 2:5] = True  # a row of three: each end by the two beside it, the middle by both sides
        valid[0, 4, 5] = True  # below the row's end, diagonal to it: alone in its row and column
        out = unconfirmed_corners(valid.reshape(1, -1), (6, 5)).reshape(5, 6)
        assert out.nonzero().tolist() == [[0, 0], [1, 1], [4, 5]]

    def test_missing_corners_are_never_unconfirmed(self):
        assert not bool(unconfirmed_corners(torch.zeros(1, 6, dtype=torch.bool), (3, 2)).any())

    def test_a_partial_board_s_measured_part_is_confirmed(self):
        valid = torch.zeros(1, 4, 5, dtype=torch.bool)
        valid[0, 1:, 2:] = True  # a 3x3 block of a 5x4 board: every corner has two in a row or column
        assert not bool(unconfirmed_corners(valid.reshape(1, -1), (5, 4)).any())

    def test_batch_is_per_board(self):
        valid = torch.ones(2, 12, dtype=torch.bool)
        valid[1, [1, 4]] = False  # board 2: corner 0 loses its right and lower neighbours
        out = unconfirmed_corners(valid, (4, 3))
        assert not bool(out[0].any()) and out[1].nonzero().flatten().tolist() == [0]

    def test_exceptions(self):
        with pytest.raises(ValueError):
            unconfirmed_corners(torch.ones(1, 10, dtype=torch.bool), (4, 3))
        with pytest.raises(ValueError):
            unconfirmed_corners(torch.ones(12, dtype=torch.bool), (4, 3))

    def test_what_the_lattice_cannot_judge(self):
        """A corner its neighbours cannot predict gets lattice deviation 0 wherever it is: only
        :func:`unconfirmed_corners` flags it (a fit gone to the next row's corner, as on a dark foreshortened board)."""
        pts = torch.tensor([[[10.0 * i, 5.0 * j] for j in range(3) for i in range(4)]])
        off = pts.clone()
        off[0, [1, 4]] = float("nan")  # its right and lower neighbours lost
        off[0, 0] = pts[0, 4]  # and its fit on the next row's corner
        assert float(lattice_deviation(off, (4, 3))[0, 0]) == 0.0
        assert unconfirmed_corners(off.isfinite().all(-1), (4, 3))[0].nonzero().flatten().tolist() == [0]
