"""Tests of the heatmap peak seeds."""

from __future__ import annotations

import pytest
import torch
from _heatmaps import board_like, nearest_error, render

from ccs_kornia.modules.detection.learned.gaussian_fit import gaussian_fit
from ccs_kornia.modules.detection.learned.peaks import HeatmapPeaks, heatmap_peaks

SIGMA = 1.5


class TestHeatmapPeaks:
    def test_finds_every_corner(self, device: torch.device, dtype: torch.dtype) -> None:
        mu = board_like(2)
        heat = render(mu, torch.full_like(mu, SIGMA), 100, 130).to(device, dtype)
        seeds, scores, mask = heatmap_peaks(heat, max_peaks=64)
        assert seeds.device.type == device.type and seeds.dtype == dtype
        seeds, scores, mask = seeds.cpu(), scores.cpu(), mask.cpu()
        assert seeds.shape == (2, 64, 2) and scores.shape == (2, 64) and mask.shape == (2, 64)
        assert mask.sum(1).tolist() == [48, 48]
        assert (nearest_error(seeds, mu)[mask] < 0.3).all()
        assert (scores[mask] > 0.6).all() and (scores[~mask] == 0).all()
        # real peaks first, sorted by score
        assert mask[:, :48].all()
        assert (scores[:, :47] >= scores[:, 1:48]).all()

    def test_threshold_and_max_peaks(self) -> None:
        mu = torch.tensor([[[10.2, 10.7], [30.0, 12.4], [20.5, 30.1]]], dtype=torch.float64)
        amplitude = torch.tensor([1.0, 0.5, 0.2], dtype=torch.float64)[None, :, None, None]
        ys, xs = torch.meshgrid(torch.arange(40.0).double(), torch.arange(45.0).double(), indexing="ij")
        blobs = amplitude * torch.exp(-((xs - mu[..., 0, None, None]) ** 2 + (ys - mu[..., 1, None, None]) ** 2) / 4.5)
        heat = blobs.amax(1, keepdim=True)
        _, scores, mask = heatmap_peaks(heat, threshold=0.3, max_peaks=5)
        assert mask[0].tolist() == [True, True, False, False, False]
        _, _, mask = heatmap_peaks(heat, threshold=0.1, max_peaks=2)
        assert mask.shape == (1, 2) and mask.all()

    def test_corner_at_border_and_tiny_map(self) -> None:
        mu = torch.tensor([[[0.8, 1.3]]], dtype=torch.float64)
        heat = render(mu, torch.full_like(mu, SIGMA), 20, 20)
        seeds, _, mask = heatmap_peaks(heat, max_peaks=3)
        assert mask[0].tolist() == [True, False, False]
        mu_fit, _, ok = gaussian_fit(heat, seeds, mask)
        assert ok[0, 0]
        assert (mu_fit[0, 0] - mu[0, 0]).abs().max() < 1e-6  # zero-padded pixels are ignored, the fit stays exact
        seeds, _, mask = heatmap_peaks(torch.zeros(1, 1, 2, 3), max_peaks=10)  # fewer pixels than slots
        assert seeds.shape == (1, 10, 2) and not mask.any()

    def test_module_matches_function(self) -> None:
        heat = torch.rand(2, 1, 30, 40)
        out_module = HeatmapPeaks(threshold=0.5, max_peaks=16, nms_kernel=3, refine_window=3)(heat)
        out_function = heatmap_peaks(heat, 0.5, 16, 3, 3)
        for a, b in zip(out_module, out_function):
            torch.testing.assert_close(a, b)

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match=r"heatmap must be \(B, 1, H, W\), got \(1, 20, 20\)"):
            heatmap_peaks(torch.rand(1, 20, 20))
        with pytest.raises(ValueError, match=r"heatmap must be \(B, 1, H, W\), got \(1, 2, 20, 20\)"):
            heatmap_peaks(torch.rand(1, 2, 20, 20))
        with pytest.raises(ValueError, match="nms_kernel"):
            heatmap_peaks(torch.rand(1, 1, 20, 20), nms_kernel=4)
        with pytest.raises(ValueError, match="max_peaks"):
            heatmap_peaks(torch.rand(1, 1, 20, 20), max_peaks=0)
        with pytest.raises(ValueError, match="floating"):
            heatmap_peaks(torch.ones(1, 1, 20, 20, dtype=torch.uint8))
