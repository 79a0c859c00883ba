from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.grid.missing_corners import lattice_deviation, unconfirmed_corners


class TestUnconfirmedCorners:
    def test_smoke_and_shape(self):
        out = unconfirmed_corners(torch.ones(3, 12, dtype=torch.bool), (4, 3))
        assert out.shape == (3, 12) and out.dtype == torch.bool and not bool(out.any())

    def test_a_lone_corner_and_a_lone_pair(self):
        valid = torch.zeros(1, 4, 5, dtype=torch.bool)  # rows x cols
        valid[0, 0, 0] = True  # alone at the board's corner: its three neighbours missing
        valid[0, 2, 2] = valid[0, 3, 3] = True  # two diagonal neighbours confirm each other
        out = unconfirmed_corners(valid.reshape(1, -1), (5, 4)).reshape(4, 5)
        assert out.nonzero().tolist() == [[0, 0]]

    def test_missing_corners_are_never_unconfirmed(self):
        valid = torch.zeros(1, 6, dtype=torch.bool)
        assert not bool(unconfirmed_corners(valid, (3, 2)).any())

    def test_batch_is_per_board(self):
        valid = torch.ones(2, 9, dtype=torch.bool)
        valid[1] = torch.tensor([True, False, False, False, False, False, False, False, True])
        out = unconfirmed_corners(valid, (3, 3))
        assert not bool(out[0].any()) and out[1].tolist() == valid[1].tolist()

    def test_exceptions(self):
        with pytest.raises(ValueError):
            unconfirmed_corners(torch.ones(1, 10, dtype=torch.bool), (4, 3))
        with pytest.raises(ValueError):
            unconfirmed_corners(torch.ones(12, dtype=torch.bool), (4, 3))

    def test_what_the_lattice_cannot_judge(self):
        """A lone corner gets lattice deviation 0 wherever it is: only :func:`unconfirmed_corners` flags it."""
        pts = torch.tensor([[[10.0 * i, 10.0 * j] for j in range(3) for i in range(3)]])
        lone = torch.full_like(pts, float("nan"))
        lone[0, 0] = torch.tensor([7.0, 5.0])  # half a square off, onto nothing
        lone[0, 8] = pts[0, 8]
        lone[0, 7] = pts[0, 7]
        assert float(lattice_deviation(lone, (3, 3))[0, 0]) == 0.0
        assert unconfirmed_corners(lone.isfinite().all(-1), (3, 3))[0].nonzero().flatten().tolist() == [0]
