from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.refine.image_noise import (
    NOISY,
    noise_sigma,
    noise_to_contrast,
)


def _checker(h: int = 96, w: int = 128, square: int = 16, lo: float = 0.2, hi: float = 0.8) -> tuple[torch.Tensor, torch.Tensor]:
    """A checker image (1, 1, H, W) and its inner corners (1, N, 2) in grid order."""
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    img = torch.where(((xx // square + yy // square) % 2) == 0, lo, hi).float()[None, None]
    cols, rows = w // square - 1, h // square - 1
    pts = torch.tensor([[square * (i + 1) - 0.5, square * (j + 1) - 0.5] for j in range(rows) for i in range(cols)])
    return img, pts[None]


class TestNoiseSigma:
    def test_smoke_and_shape(self):
        out = noise_sigma(torch.rand(3, 1, 20, 30))
        assert out.shape == (3,) and out.dtype == torch.float32

    @pytest.mark.parametrize("sigma", [0.01, 0.05])
    def test_white_noise_on_a_ramp(self, sigma):
        ramp = torch.linspace(0.2, 0.8, 200)[None, :].expand(150, 200)  # planar: the filter cancels it
        g = torch.Generator().manual_seed(0)
        img = (ramp + sigma * torch.randn(150, 200, generator=g))[None, None]
        assert float(noise_sigma(img)) == pytest.approx(sigma, rel=0.05)

    def test_a_noise_free_plane_is_zero(self):
        yy, xx = torch.meshgrid(torch.arange(40.0), torch.arange(50.0), indexing="ij")
        assert float(noise_sigma((0.01 * xx + 0.002 * yy)[None, None])) == pytest.approx(0.0, abs=1e-6)

    def test_batch_is_per_image(self):
        g = torch.Generator().manual_seed(1)
        imgs = torch.stack([0.5 + s * torch.randn(1, 64, 64, generator=g) for s in (0.01, 0.03)])
        batch = noise_sigma(imgs)
        assert torch.allclose(batch, torch.cat([noise_sigma(imgs[i : i + 1]) for i in range(2)]))
        assert float(batch[1]) > 2.5 * float(batch[0])

    def test_exceptions(self):
        with pytest.raises((ValueError, TypeError)):
            noise_sigma(torch.rand(1, 20, 20))
        with pytest.raises(ValueError, match="at least"):
            noise_sigma(torch.rand(1, 1, 2, 20))

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_dtype_and_device(self, dtype, device):
        g = torch.Generator().manual_seed(2)
        img = (0.5 + 0.02 * torch.randn(1, 1, 64, 64, generator=g)).to(device, dtype)
        out = noise_sigma(img)
        assert out.device == img.device and float(out) == pytest.approx(0.02, rel=0.1)


class TestNoiseToContrast:
    def test_a_clean_board_is_below_the_bar_a_dark_noisy_one_above(self):
        img, pts = _checker()
        assert float(noise_to_contrast(img, pts, (7, 5))) < 0.25 * NOISY  # the edges alone: a little above zero
        g = torch.Generator().manual_seed(3)
        dark = 0.12 * img + 0.01 * torch.randn(img.shape, generator=g)  # contrast 0.072, noise 0.01: 0.14
        assert float(noise_to_contrast(dark, pts, (7, 5))) == pytest.approx(0.01 / 0.072, rel=0.15)

    def test_batch(self):
        img, pts = _checker()
        g = torch.Generator().manual_seed(4)
        imgs = torch.cat([img, img + 0.05 * torch.randn(img.shape, generator=g)])
        out = noise_to_contrast(imgs, pts.expand(2, -1, -1), (7, 5))
        assert out.shape == (2,) and float(out[0]) < NOISY < float(out[1])
