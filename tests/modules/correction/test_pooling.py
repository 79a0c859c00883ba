"""Tests of pooling the per-view corrections of a camera and of the correction's displacement."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.correction.pooling import (
    aggregate_corrections,
    correction_displacement,
)
from ccs_kornia.modules.correction.radial_warp import correct_points

SIZE = (640, 480)


def test_aggregate_is_robust_to_one_bad_view_and_masks():
    good = torch.tensor([1.0, 0.0, 0.25, 0.0, 0.05], dtype=torch.float64)
    views = good.expand(1, 5, 5).clone()
    views[0, 2] = torch.tensor([1.0, 0.0, -0.8, 0.0, 0.0])  # one wild view
    pooled = aggregate_corrections(views, SIZE)
    assert pooled.shape == (1, 5)
    r = torch.linspace(0, 0.62, 20, dtype=torch.float64)
    poly = lambda c: r * (c[0] + r * (c[1] + r * (c[2] + r * (c[3] + r * c[4]))))  # noqa: E731
    assert float((poly(pooled[0]) - poly(good)).abs().max()) < 1e-6  # the median ignores it
    mask = torch.tensor([[False] * 5])
    torch.testing.assert_close(aggregate_corrections(views, SIZE, mask), torch.tensor([[1.0, 0, 0, 0, 0]], dtype=torch.float64))
    with pytest.raises(ValueError, match="corrections"):
        aggregate_corrections(torch.zeros(3, 5), SIZE)
    with pytest.raises(ValueError, match="mask"):
        aggregate_corrections(views, SIZE, torch.ones(2, 5, dtype=torch.bool))


def test_correction_displacement():
    ident = torch.tensor([[1.0, 0, 0, 0, 0]])
    assert float(correction_displacement(ident, SIZE)) == 0.0
    c = torch.tensor([[1.0, 0.0, 0.2, 0.0, 0.0]], dtype=torch.float64)
    corner = torch.tensor([[[0.0, 0.0]]], dtype=torch.float64)
    moved = float((correct_points(corner, c, SIZE) - corner).norm())
    assert float(correction_displacement(c, SIZE)) == pytest.approx(moved, rel=1e-3)
