"""Tests of the sigma outlier rejection."""

from __future__ import annotations

import pytest
import torch
from _heatmaps import board_like, nearest_error, render

from ccs_kornia.modules.detection.learned.gaussian_fit import gaussian_fit
from ccs_kornia.modules.detection.learned.peaks import heatmap_peaks
from ccs_kornia.modules.detection.learned.sigma_rejection import (
    SigmaOutlierRejection,
    sigma_outlier_rejection,
)

SIGMA = 1.5


class TestSigmaOutlierRejection:
    def test_false_peaks_with_wrong_sigma_are_rejected(self, device: torch.device, dtype: torch.dtype) -> None:
        # 48 true corners (sigma 1.5) plus blobs with the wrong sigma placed mid-cell between them
        mu = board_like(2, spacing=24.0, seed=8)
        sigma = torch.full_like(mu, SIGMA)
        false_mu = mu[:, :6] + torch.tensor([12.0, 12.0], dtype=torch.float64)
        false_sigma = torch.tensor([[0.6, 0.6], [3.0, 3.0], [0.7, 1.5], [1.5, 2.6], [0.5, 0.5], [2.8, 2.8]])
        false_sigma = false_sigma.double().expand(2, 6, 2)
        heat = render(torch.cat([mu, false_mu], 1), torch.cat([sigma, false_sigma], 1), 145, 190).to(device, dtype)
        seeds, _, mask = heatmap_peaks(heat, threshold=0.3, max_peaks=80, nms_kernel=3)
        assert mask.sum(1).tolist() == [54, 54]  # the peak finder alone cannot tell them apart
        _, sigma_fit, ok = gaussian_fit(heat, seeds, mask)
        keep = sigma_outlier_rejection(sigma_fit, mask & ok, expected_sigma=SIGMA, tolerance=0.5)
        assert keep.device.type == device.type
        seeds, mask, keep = seeds.cpu(), mask.cpu(), keep.cpu()
        assert keep.sum(1).tolist() == [48, 48]
        assert (nearest_error(seeds, mu)[keep] < 0.5).all()
        assert (nearest_error(seeds, false_mu)[mask & ~keep] < 0.5).all()

    def test_rule_and_broadcasting(self) -> None:
        sigma = torch.tensor([[[1.5, 1.5], [2.2, 1.5], [1.5, 0.76], [float("nan"), 1.5], [1.0, 2.0]]])
        mask = torch.ones(1, 5, dtype=torch.bool)
        assert sigma_outlier_rejection(sigma, mask, 1.5, 0.5)[0].tolist() == [True, True, True, False, True]
        assert sigma_outlier_rejection(sigma, mask, 1.5, 0.2)[0].tolist() == [True, False, False, False, False]
        per_axis = torch.tensor([1.0, 2.0])
        assert sigma_outlier_rejection(sigma, mask, per_axis, 0.1)[0].tolist() == [False] * 4 + [True]
        masked = sigma_outlier_rejection(sigma, torch.zeros(1, 5, dtype=torch.bool), 1.5, 0.5)
        assert not masked.any()
        module = SigmaOutlierRejection(1.5, 0.2)
        torch.testing.assert_close(module(sigma, mask), sigma_outlier_rejection(sigma, mask, 1.5, 0.2))

    def test_exceptions(self) -> None:
        sigma, mask = torch.ones(2, 4, 2), torch.ones(2, 4, dtype=torch.bool)
        with pytest.raises(ValueError, match="sigma"):
            sigma_outlier_rejection(torch.ones(2, 4), mask, 1.5)
        with pytest.raises(ValueError, match="mask"):
            sigma_outlier_rejection(sigma, mask[:, :3], 1.5)
        with pytest.raises(ValueError, match="expected_sigma"):
            sigma_outlier_rejection(sigma, mask, 0.0)
        with pytest.raises(ValueError, match="expected_sigma"):
            sigma_outlier_rejection(sigma, mask, torch.ones(3))
        with pytest.raises(ValueError, match="tolerance"):
            sigma_outlier_rejection(sigma, mask, 1.5, -0.1)
        with pytest.raises(ValueError, match="expected_sigma"):
            SigmaOutlierRejection(expected_sigma=-1.0)
