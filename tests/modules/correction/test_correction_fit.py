"""Tests of fitting radial correction coefficients to point correspondences."""

from __future__ import annotations

import torch

from ccs_kornia.modules.correction.correction_fit import fit_correction_to_points
from ccs_kornia.modules.correction.radial_warp import correct_points

SIZE = (640, 480)


def test_fit_correction_to_points_recovers_coefficients_and_fixes_k0():
    g = torch.Generator().manual_seed(0)
    c = torch.tensor([[1.0, 0.05, 0.3, -0.1, 0.2], [1.0, 0.0, -0.1, 0.0, 0.0]], dtype=torch.float64)
    p = torch.rand(2, 80, 2, generator=g, dtype=torch.float64) * torch.tensor([639.0, 479.0], dtype=torch.float64)
    torch.testing.assert_close(fit_correction_to_points(p, correct_points(p, c, SIZE), SIZE), c)
    zoomed = c.clone()
    zoomed[:, 0] = 1.1
    free = fit_correction_to_points(p, correct_points(p, zoomed, SIZE), SIZE, fix_k0=False)
    torch.testing.assert_close(free, zoomed)
    assert bool((fit_correction_to_points(p, correct_points(p, zoomed, SIZE), SIZE)[:, 0] == 1).all())
