"""Tests of the heatmap targets."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.data.scenes.targets import gaussian_heatmaps


def test_gaussian_heatmaps():
    corners = torch.tensor([[[10.0, 8.0], [30.3, 20.6], [50.0, 5.0]], [[0.0, 0.0], [63.0, 47.0], [5.0, 5.0]]])
    valid = torch.tensor([[True, True, False], [True, True, False]])
    hm = gaussian_heatmaps(corners, valid, (64, 48), sigma=1.5)
    assert hm.shape == (2, 1, 48, 64)
    assert float(hm[0, 0, 8, 10]) == 1.0 and float(hm[1, 0, 0, 0]) == 1.0 and float(hm[1, 0, 47, 63]) == 1.0
    expected = math.exp(-(0.3**2 + 0.4**2) / (2 * 1.5**2))
    assert abs(float(hm[0, 0, 21, 30]) - expected) < 1e-6
    assert float(hm[0, 0].max()) == 1.0 and float(hm[0, 0, 5, 50]) == 0.0  # invalid corner ignored
    # equals a dense max over Gaussians (within the 3-sigma window)
    ys, xs = torch.meshgrid(torch.arange(48.0), torch.arange(64.0), indexing="ij")
    d2 = (xs[None] - corners[0, :2, 0, None, None]) ** 2 + (ys[None] - corners[0, :2, 1, None, None]) ** 2
    dense = torch.exp(-d2 / (2 * 1.5**2)).amax(0)
    window = hm[0, 0] > 0
    assert torch.allclose(hm[0, 0][window], dense[window], atol=1e-6)
    assert float(dense[~window].max()) < 0.02
    with pytest.raises(ValueError):
        gaussian_heatmaps(corners, valid[:, :2], (64, 48))
