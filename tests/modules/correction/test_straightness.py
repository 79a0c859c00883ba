"""Tests of the straightness RMS of board rows and columns."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.correction.straightness import straightness_rms


def test_straightness_known_values_and_batch():
    cols, rows = 4, 3
    f64 = dict(dtype=torch.float64)
    j, i = torch.meshgrid(torch.arange(rows, **f64), torch.arange(cols, **f64), indexing="ij")
    grid = torch.stack([10 * i, 10 * j], -1).reshape(1, -1, 2)
    valid = torch.ones(1, cols * rows, dtype=torch.bool)
    rms, n = straightness_rms(grid, valid, (cols, rows))
    assert float(rms) == pytest.approx(0.0, abs=1e-9) and int(n) == 24
    bent = grid.clone()
    bent[0, 1, 1] += 1.0  # middle-ish point of row 0 moves off its row by 1 px
    rms1, _ = straightness_rms(bent, valid, (cols, rows))
    # row 0 (4 points): TLS residual of one point displaced by 1 on a 4-point line: 1 - 1/4 - (x-xbar)^2/Sxx
    # column 1 (3 points) is unaffected (the shift is along the column)
    sse = 1.0 - 0.25 - (10 - 15) ** 2 / 500.0
    assert float(rms1) == pytest.approx((sse / 24) ** 0.5, rel=1e-2)
    # batch with different board sizes, padding and invalid corners
    other = torch.zeros(1, cols * rows, 2, dtype=torch.float64)
    small = torch.stack([10 * i[:2, :3], 10 * j[:2, :3]], -1).reshape(1, 6, 2)
    other[:, :6] = small
    both = torch.cat([bent, other])
    v = torch.cat([valid, torch.arange(12).unsqueeze(0) < 6])
    r, m = straightness_rms(both, v, torch.tensor([[4, 3], [3, 2]]))
    assert float(r[0]) == pytest.approx(float(rms1)) and float(r[1]) == 0.0
    assert int(m[1]) == 6  # two rows of 3; columns of 2 do not count
    with pytest.raises(ValueError):
        straightness_rms(grid, valid[:, :5], (cols, rows))
    with pytest.raises(ValueError):
        straightness_rms(grid, valid, torch.tensor([[4, 3], [3, 2]]))
