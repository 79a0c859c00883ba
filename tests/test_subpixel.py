"""Tests of the heatmap peak finder, the batched Gaussian surface fit and the sigma outlier rejection."""

from __future__ import annotations

import pytest
import torch
from kornia.geometry.subpix import render_gaussian2d

from ccs_kornia.modules.detection.gaussian_fit import GaussianFit, gaussian_fit
from ccs_kornia.modules.detection.peaks import HeatmapPeaks, heatmap_peaks
from ccs_kornia.modules.detection.sigma_rejection import SigmaOutlierRejection, sigma_outlier_rejection

SIGMA = 1.5


def render(mu: torch.Tensor, sigma: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Unit-peak Gaussians at ``mu`` (B,N,2) with ``sigma`` (B,N,2), max-combined into a (B,1,H,W) heatmap."""
    dtype = mu.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype), indexing="ij")
    dx = xs - mu[..., 0, None, None]
    dy = ys - mu[..., 1, None, None]
    exponent = dx**2 / (2 * sigma[..., 0, None, None] ** 2) + dy**2 / (2 * sigma[..., 1, None, None] ** 2)
    return torch.exp(-exponent).amax(1, keepdim=True)


def board_like(batch: int, cols: int = 8, rows: int = 6, spacing: float = 14.0, seed: int = 0) -> torch.Tensor:
    """(B, cols*rows, 2) float64 corner positions: a grid with random sub-pixel offsets in [0, 3)."""
    gen = torch.Generator().manual_seed(seed)
    gx, gy = torch.meshgrid(torch.arange(cols), torch.arange(rows), indexing="xy")
    grid = torch.stack([gx, gy], -1).reshape(-1, 2).double() * spacing + 10.0
    return grid[None] + 3.0 * torch.rand(batch, cols * rows, 2, generator=gen, dtype=torch.float64)


def nearest_error(found: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Distance from each found point (B,M,2) to its nearest true point (B,N,2), exact (no cdist matmul trick)."""
    return (found[:, :, None].double() - truth[:, None]).norm(dim=-1).min(-1).values


class TestHeatmapPeaks:
    def test_finds_every_corner(self) -> None:
        mu = board_like(2)
        heat = render(mu, torch.full_like(mu, SIGMA), 100, 130).float()
        seeds, scores, mask = heatmap_peaks(heat, max_peaks=64)
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
        with pytest.raises(ValueError, match="shape"):
            heatmap_peaks(torch.rand(1, 20, 20))
        with pytest.raises(ValueError, match="shape"):
            heatmap_peaks(torch.rand(1, 2, 20, 20))
        with pytest.raises(ValueError, match="nms_kernel"):
            heatmap_peaks(torch.rand(1, 1, 20, 20), nms_kernel=4)
        with pytest.raises(ValueError, match="max_peaks"):
            heatmap_peaks(torch.rand(1, 1, 20, 20), max_peaks=0)
        with pytest.raises(ValueError, match="floating"):
            heatmap_peaks(torch.ones(1, 1, 20, 20, dtype=torch.uint8))


class TestGaussianFit:
    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_exact_on_clean_heatmaps(self, dtype: torch.dtype) -> None:
        mu = board_like(3, seed=1)
        heat = render(mu, torch.full_like(mu, SIGMA), 100, 130).to(dtype)
        gen = torch.Generator().manual_seed(2)
        seeds = (mu + 0.8 * (torch.rand(mu.shape, generator=gen, dtype=torch.float64) - 0.5)).to(dtype)
        mu_fit, sigma_fit, ok = gaussian_fit(heat, seeds)
        assert mu_fit.dtype == dtype and sigma_fit.dtype == dtype and ok.dtype == torch.bool
        assert ok.all()
        assert (mu_fit.double() - mu).norm(dim=-1).max() < 0.01
        assert ((sigma_fit.double() - SIGMA).abs() / SIGMA).max() < 0.02
        if dtype == torch.float64:  # the log-linear model is exact for a Gaussian: only rounding is left
            assert (mu_fit - mu).abs().max() < 1e-9
            assert (sigma_fit - SIGMA).abs().max() < 1e-9

    def test_anisotropic_sigma_and_amplitude(self) -> None:
        # kornia's render_gaussian2d draws a normalised pdf (peak << 1): the fit does not depend on the amplitude
        mean = torch.tensor([[17.3, 11.8], [6.55, 20.2]], dtype=torch.float64)
        std = torch.tensor([[1.2, 2.0], [1.5, 1.5]], dtype=torch.float64)
        heat = render_gaussian2d(mean, std, (32, 28), normalized_coordinates=False).amax(0)[None, None]
        mu_fit, sigma_fit, ok = gaussian_fit(heat, mean[None].round(), window=9)
        assert ok.all()
        torch.testing.assert_close(mu_fit[0], mean, atol=1e-8, rtol=0)
        torch.testing.assert_close(sigma_fit[0], std, atol=1e-8, rtol=0)

    def test_mild_noise(self) -> None:
        mu = board_like(4, seed=3)
        clean = render(mu, torch.full_like(mu, SIGMA), 100, 130).float()
        gen = torch.Generator().manual_seed(4)
        noisy = (clean + 0.01 * torch.randn(clean.shape, generator=gen)).clamp(0, 1)
        seeds, _, mask = heatmap_peaks(noisy, max_peaks=64)
        assert mask.sum().item() == 4 * 48
        mu_fit, sigma_fit, ok = gaussian_fit(noisy, seeds, mask)
        assert (ok == mask).all()
        error = nearest_error(mu_fit, mu)[ok]
        # measured: mean 0.011 px, max 0.026 px; sigma within 1.9 %
        assert error.mean() < 0.02 and error.max() < 0.06
        assert ((sigma_fit[ok] - SIGMA).abs() / SIGMA).max() < 0.04

    def test_batch_consistency(self) -> None:
        mu = board_like(3, seed=5)
        heat = render(mu, torch.full_like(mu, SIGMA), 100, 130).float()
        heat = heat + 0.02 * torch.rand(heat.shape, generator=torch.Generator().manual_seed(6))
        seeds = mu.float().round()
        mask = torch.rand(3, 48, generator=torch.Generator().manual_seed(7)) > 0.2
        batched = gaussian_fit(heat, seeds, mask)
        for i in range(3):
            single = gaussian_fit(heat[i : i + 1], seeds[i : i + 1], mask[i : i + 1])
            for a, b in zip(batched, single):
                torch.testing.assert_close(a[i : i + 1], b)
        assert (batched[2] == mask).all()

    def test_degenerate_fits_are_flagged(self) -> None:
        ys, xs = torch.meshgrid(torch.arange(30.0), torch.arange(30.0), indexing="ij")
        flat = torch.full((1, 1, 30, 30), 0.5)
        valley = (1.0 - torch.exp(-((xs - 15) ** 2 + (ys - 15) ** 2) / 4.5))[None, None]
        empty = torch.zeros(1, 1, 30, 30)
        seeds = torch.tensor([[[15.0, 15.0], [-5.0, 3.0], [float("nan"), 2.0]]])
        for heat in (flat, valley, empty):
            mu, sigma, ok = gaussian_fit(heat, seeds)
            assert not ok.any()
            assert torch.isfinite(mu[0, :2]).all() and (sigma == 0).all()
            torch.testing.assert_close(mu[0, :2], seeds[0, :2])  # failed fits keep their seed
        # a real peak whose seed is masked out is not fitted
        blob = torch.exp(-((xs - 15.2) ** 2 + (ys - 14.9) ** 2) / 4.5)[None, None]
        _, _, ok = gaussian_fit(blob, seeds[:, :1], torch.tensor([[False]]))
        assert not ok.any()

    def test_centre_outside_window_is_flagged(self) -> None:
        # a seed 4 px from a wide blob: the fitted centre lies outside the 5x5 window
        ys, xs = torch.meshgrid(torch.arange(40.0).double(), torch.arange(40.0).double(), indexing="ij")
        blob = torch.exp(-((xs - 20.0) ** 2 + (ys - 20.0) ** 2) / (2 * 4.0**2))[None, None]
        _, _, ok = gaussian_fit(blob, torch.tensor([[[16.0, 20.0], [19.0, 20.0]]], dtype=torch.float64), window=5)
        assert ok[0].tolist() == [False, True]

    def test_gradcheck(self) -> None:
        mu = torch.tensor([[[5.3, 6.8], [11.6, 4.2]]], dtype=torch.float64)
        heat = render(mu, torch.full_like(mu, SIGMA), 12, 16) + 0.01
        heat.requires_grad_(True)
        seeds = mu.round()

        def fit(h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            mu_fit, sigma_fit, _ = gaussian_fit(h, seeds, window=5)
            return mu_fit, sigma_fit

        assert torch.autograd.gradcheck(fit, (heat,), eps=1e-7, atol=1e-5)

    def test_module_matches_function(self) -> None:
        mu = board_like(1)
        heat = render(mu, torch.full_like(mu, SIGMA), 100, 130)
        seeds = mu.round()
        for a, b in zip(GaussianFit(window=5)(heat, seeds), gaussian_fit(heat, seeds, window=5)):
            torch.testing.assert_close(a, b)

    def test_exceptions(self) -> None:
        heat = torch.rand(2, 1, 20, 20)
        with pytest.raises(ValueError, match="seeds"):
            gaussian_fit(heat, torch.rand(2, 5, 3))
        with pytest.raises(ValueError, match="seeds"):
            gaussian_fit(heat, torch.rand(1, 5, 2))
        with pytest.raises(ValueError, match="mask"):
            gaussian_fit(heat, torch.rand(2, 5, 2), torch.ones(2, 4, dtype=torch.bool))
        with pytest.raises(ValueError, match="window"):
            gaussian_fit(heat, torch.rand(2, 5, 2), window=6)
        with pytest.raises(ValueError, match="heatmap"):
            gaussian_fit(torch.rand(2, 20, 20), torch.rand(2, 5, 2))
        with pytest.raises(ValueError, match="window"):
            GaussianFit(window=1)


class TestSigmaOutlierRejection:
    def test_false_peaks_with_wrong_sigma_are_rejected(self) -> None:
        # 48 true corners (sigma 1.5) plus blobs with the wrong sigma placed mid-cell between them
        mu = board_like(2, spacing=24.0, seed=8)
        sigma = torch.full_like(mu, SIGMA)
        false_mu = mu[:, :6] + torch.tensor([12.0, 12.0], dtype=torch.float64)
        false_sigma = torch.tensor([[0.6, 0.6], [3.0, 3.0], [0.7, 1.5], [1.5, 2.6], [0.5, 0.5], [2.8, 2.8]])
        false_sigma = false_sigma.double().expand(2, 6, 2)
        heat = render(torch.cat([mu, false_mu], 1), torch.cat([sigma, false_sigma], 1), 145, 190).float()
        seeds, _, mask = heatmap_peaks(heat, threshold=0.3, max_peaks=80, nms_kernel=3)
        assert mask.sum(1).tolist() == [54, 54]  # the peak finder alone cannot tell them apart
        _, sigma_fit, ok = gaussian_fit(heat, seeds, mask)
        keep = sigma_outlier_rejection(sigma_fit, mask & ok, expected_sigma=SIGMA, tolerance=0.5)
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


def test_unet_to_subpixel_chain() -> None:
    """Shapes and dtypes flow from the UNet through the three stages (untrained net: no accuracy claim)."""
    from ccs_kornia.modules.detection.heatmap_unet import CornerUNet

    torch.manual_seed(0)
    net = CornerUNet(base_channels=4, depth=2).eval()
    with torch.no_grad():
        heat = net(torch.rand(2, 1, 40, 50))
    seeds, scores, mask = HeatmapPeaks(threshold=0.0, max_peaks=32)(heat)
    mu, sigma, ok = GaussianFit()(heat, seeds, mask)
    keep = SigmaOutlierRejection(1.5, 0.5)(sigma, mask & ok)
    assert mu.shape == (2, 32, 2) and sigma.shape == (2, 32, 2) and keep.shape == (2, 32)
    assert not (keep & ~mask).any()
    assert torch.isfinite(mu).all() and torch.isfinite(sigma).all()
