"""Tests of the Gaussian surface fit (paper Sec. III-B) and the heatmap -> sub-pixel chain."""

from __future__ import annotations

import pytest
import torch
from _heatmaps import board_like, nearest_error, render
from kornia.geometry.subpix import render_gaussian2d

from ccs_kornia.modules.detection.learned.gaussian_fit import GaussianFit, gaussian_fit
from ccs_kornia.modules.detection.learned.peaks import HeatmapPeaks, heatmap_peaks
from ccs_kornia.modules.detection.learned.sigma_rejection import SigmaOutlierRejection

SIGMA = 1.5


class TestGaussianFit:
    def test_exact_on_clean_heatmaps(self, device: torch.device, dtype: torch.dtype) -> None:
        mu = board_like(3, seed=1)
        heat = render(mu, torch.full_like(mu, SIGMA), 100, 130).to(device, dtype)
        gen = torch.Generator().manual_seed(2)
        seeds = (mu + 0.8 * (torch.rand(mu.shape, generator=gen, dtype=torch.float64) - 0.5)).to(device, dtype)
        mu_fit, sigma_fit, ok = gaussian_fit(heat, seeds)
        assert mu_fit.dtype == dtype and sigma_fit.dtype == dtype and ok.dtype == torch.bool
        assert mu_fit.device.type == device.type
        mu_fit, sigma_fit, ok = mu_fit.cpu(), sigma_fit.cpu(), ok.cpu()
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


def test_unet_to_subpixel_chain() -> None:
    """Shapes and dtypes flow from the UNet through the three stages (untrained net: no accuracy claim)."""
    from ccs_kornia.modules.detection.learned.heatmap_unet import CornerUNet

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
