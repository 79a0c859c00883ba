"""Per-corner precision of detected corners and the solver weights it gives."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.refine.corner_uncertainty import (
    CornerUncertainty,
    corner_uncertainty,
    corner_weights,
)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def _checker(square: int = 12, n: int = 5, noise: float = 0.0, seed: int = 0):
    size = square * (n + 1)
    y, x = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    img = ((x // square + y // square) % 2).float()
    if noise:
        img = img + noise * torch.randn(img.shape, generator=torch.Generator().manual_seed(seed))
    g = torch.arange(1, n + 1) * float(square) - 0.5
    corners = torch.stack(torch.meshgrid(g, g, indexing="xy"), -1).reshape(1, n * n, 2)
    return img[None, None], corners


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_precision_grows_with_noise(device, dtype):
    clean, corners = _checker()
    noisy, _ = _checker(noise=0.05)
    noisier, _ = _checker(noise=0.2)
    ok = torch.ones(1, 25, dtype=torch.bool, device=device)
    s = [corner_uncertainty(i.to(device, dtype), corners.to(device, dtype), ok, (5, 5)) for i in (clean, noisy, noisier)]
    assert s[0].shape == (1, 25) and s[0].dtype == torch.float32 and s[0].device.type == device
    assert float(s[0].max()) < 1e-4, "an exact corner is perfectly point-symmetric"
    assert float(s[1].median()) > 10 * float(s[0].median()) and float(s[2].median()) > 2 * float(s[1].median())


def test_batch_invalid_and_module():
    img, corners = _checker(noise=0.05)
    flat = torch.full_like(img, 0.5)
    valid = torch.ones(2, 25, dtype=torch.bool)
    valid[0, 3] = False
    s = corner_uncertainty(torch.cat([img, flat]), corners.expand(2, -1, -1), valid, (5, 5))
    one = corner_uncertainty(img, corners, valid[:1], (5, 5))
    torch.testing.assert_close(s[:1], one, equal_nan=True)
    assert bool(s[0, 3].isnan()) and not bool(s[0, 4].isnan())
    assert bool(s[1].isnan().all()), "a flat image has no corner to measure"
    torch.testing.assert_close(CornerUncertainty()(img, corners, valid[:1], (5, 5)), one, equal_nan=True)


def test_exceptions():
    img, corners = _checker()
    ok = torch.ones(1, 25, dtype=torch.bool)
    with pytest.raises(ValueError, match="images"):
        corner_uncertainty(img[0], corners, ok, (5, 5))
    with pytest.raises(ValueError, match="corners"):
        corner_uncertainty(img, corners[0], ok, (5, 5))
    with pytest.raises(ValueError, match="valid"):
        corner_uncertainty(img, corners, ok[:, :3], (5, 5))
    with pytest.raises(ValueError, match="clip"):
        corner_weights(torch.ones(1, 3), torch.ones(1, 3, dtype=torch.bool), clip=0.5)
    with pytest.raises(ValueError, match=r"sigma must be \(1, 4\) \(as valid\), got \(1, 3\)"):
        corner_weights(torch.ones(1, 3), torch.ones(1, 4, dtype=torch.bool))


def test_weights_relative_to_each_cameras_median():
    sigma = torch.tensor([[[1.0, 2.0], [4.0, float("nan")]], [[10.0, 10.0], [0.1, 10.0]]])
    valid = torch.tensor([[[True, True], [True, True]], [[True, True], [True, False]]])
    w = corner_weights(sigma, valid, clip=10.0)
    # camera 0: median 2 -> (2 / s)^2 ; NaN -> 1 ; camera 1: median of the three valid corners (10)
    torch.testing.assert_close(w[0], torch.tensor([[4.0, 1.0], [0.25, 1.0]], dtype=torch.float64))
    torch.testing.assert_close(w[1], torch.tensor([[1.0, 1.0], [10.0, 0.0]], dtype=torch.float64))
    assert torch.equal(corner_weights(sigma, valid, clip=1.0), valid.double())
