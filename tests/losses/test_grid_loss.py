"""Tests of the sampling-grid loss (paper Eq. 1)."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.data.scenes.sampling import sample_radial_distortion
from ccs_kornia.geometry.radial import (
    fit_radial_correction,
    radial_correct_points,
    radial_distort_points,
)
from ccs_kornia.losses.grid_loss import (
    GridLoss,
    grid_loss,
    grid_targets,
    normalize_distortion_scale,
    sampling_grid,
)
from ccs_kornia.modules.correction.distortion_net import correction_from_node_values

SIZE = (640, 480)


def _identity(b, dtype=torch.float64):
    c = torch.zeros(b, 5, dtype=dtype)
    c[:, 0] = 1.0
    return c


def test_sampling_grid_spans_image():
    g = sampling_grid(SIZE, 16)
    assert g.shape == (1, 256, 2)
    assert g[..., 0].min() == 0 and g[..., 0].max() == 639 and g[..., 1].max() == 479
    torch.testing.assert_close(g[0, 1] - g[0, 0], torch.tensor([639 / 15, 0.0]))
    with pytest.raises(ValueError):
        sampling_grid(SIZE, 1)


def test_targets_invert_the_distortion():
    k = torch.tensor([[1.0, -0.3, -0.05], [0.9, -0.4, -0.2]], dtype=torch.float64)
    pts, tgt, valid = grid_targets(k, SIZE, 8)
    assert pts.shape == tgt.shape == (2, 64, 2) and valid.shape == (2, 64)
    torch.testing.assert_close(radial_distort_points(tgt, k, SIZE)[valid], pts[valid], atol=1e-6, rtol=0)


def test_zero_for_exact_inverse():
    # a pure scale k0 has the exact 5-term inverse (1/k0, 0, 0, 0, 0)
    k = torch.tensor([[0.9, 0.0, 0.0], [1.2, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    c = _identity(3)
    c[:, 0] = 1.0 / k[:, 0]
    assert float(grid_loss(c, k, SIZE)) < 1e-9


@pytest.mark.parametrize("k1", [-0.1, -0.05, 0.05])
def test_near_zero_for_fitted_inverse_of_small_distortion(k1):
    k = torch.tensor([[1.0, k1, 0.0]], dtype=torch.float64)
    fit = fit_radial_correction(k, SIZE)
    assert float(grid_loss(fit, k, SIZE)) < 2e-3
    assert float(grid_loss(_identity(1), k, SIZE)) > 2.0


@pytest.mark.parametrize("level", ["level1", "severe"])
def test_fit_is_far_below_identity(level):
    gen = torch.Generator().manual_seed(0)
    k = sample_radial_distortion(32, level, SIZE, gen).double()
    fit_loss = float(grid_loss(fit_radial_correction(k, SIZE), k, SIZE))
    ident_loss = float(grid_loss(_identity(32), k, SIZE))
    assert ident_loss > 10.0
    assert fit_loss < 0.05 * ident_loss, (fit_loss, ident_loss)


def test_scale_normalised_distortion_is_the_same_image_zoomed():
    k = torch.tensor([[0.85, -0.4, -0.2], [1.15, -0.45, -0.25], [1.0, -0.3, 0.0]], dtype=torch.float64)
    kn = normalize_distortion_scale(k)
    assert torch.equal(kn[:, 0], torch.ones(3, dtype=torch.float64))
    torch.testing.assert_close(kn[2], k[2])
    pts, tgt, valid = grid_targets(k, SIZE, 12)
    _, tgt_n, valid_n = grid_targets(kn, SIZE, 12)
    assert torch.equal(valid, valid_n)
    centre = torch.tensor([319.5, 239.5], dtype=torch.float64)
    zoomed = (tgt - centre) * k[:, 0, None, None] + centre
    torch.testing.assert_close(tgt_n[valid], zoomed[valid], atol=1e-8, rtol=0)
    # a pure zoom needs no correction once normalised
    zoom_only = normalize_distortion_scale(torch.tensor([[0.8, 0.0, 0.0]], dtype=torch.float64))
    assert float(grid_loss(_identity(1), zoom_only, SIZE)) < 1e-9
    with pytest.raises(ValueError):
        normalize_distortion_scale(torch.ones(2, 5))


def test_positive_and_reductions():
    k = torch.tensor([[1.0, -0.3, -0.1], [1.0, -0.2, 0.0]], dtype=torch.float64)
    c = torch.tensor([[1.0, 0.0, 0.2, 0.0, 0.0], [1.0, 0.1, 0.0, 0.0, 0.0]], dtype=torch.float64)
    per_point = grid_loss(c, k, SIZE, grid_size=8, reduction="none")
    _, _, valid = grid_targets(k, SIZE, 8)
    assert per_point.shape == (2, 64) and (per_point >= 0).all()
    mean = grid_loss(c, k, SIZE, grid_size=8)
    assert float(mean) > 0.1
    torch.testing.assert_close(grid_loss(c, k, SIZE, grid_size=8, reduction="sum"), per_point.sum())
    torch.testing.assert_close(mean, per_point.sum() / valid.sum())
    # the loss is the L1 norm: |dx| + |dy| per point
    pts, tgt, _ = grid_targets(k, SIZE, 8)
    manual = (radial_correct_points(pts, c, SIZE) - tgt).abs().sum(-1)
    torch.testing.assert_close(per_point, manual * valid)


def test_points_beyond_the_fold_are_left_out():
    # r (1 - r^2) folds at r = 0.577 (distorted radius 0.385): the image corners (0.625) have no preimage
    k = torch.tensor([[1.0, -1.0, 0.0]], dtype=torch.float64)
    _, _, valid = grid_targets(k, SIZE, 16)
    assert (~valid).any() and valid.float().mean() > 0.5
    assert not valid[0, 0] and valid[0, 16 * 8 + 8]
    loss = grid_loss(_identity(1), k, SIZE)
    assert torch.isfinite(loss)


def test_gradcheck():
    k = torch.tensor([[1.0, -0.3, -0.1], [0.9, -0.4, -0.2]], dtype=torch.float64)
    c = torch.tensor([[1.0, 0.01, 0.3, -0.02, 0.1], [1.1, 0.02, 0.4, 0.1, 0.3]], dtype=torch.float64)
    c.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: grid_loss(x, k, (64, 48), grid_size=5), (c,))


def test_minimising_the_loss_recovers_a_correction():
    # gradient descent on the loss, in the network's node-value parameterisation, starting at the identity,
    # reaches the quality of the least-squares fit (monomial coefficients themselves are badly conditioned)
    k = torch.tensor([[1.0, -0.3, -0.08]], dtype=torch.float64)
    nodes = torch.ones(1, 5, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([nodes], lr=0.01)
    for _ in range(300):
        opt.zero_grad()
        loss = grid_loss(correction_from_node_values(nodes), k, (128, 96), grid_size=12)
        loss.backward()
        opt.step()
    final = float(loss.detach())
    fit = float(grid_loss(fit_radial_correction(k, (128, 96)), k, (128, 96), grid_size=12))
    start = float(grid_loss(_identity(1), k, (128, 96), grid_size=12))
    assert final < 0.05 * start and final < max(1.5 * fit, 0.05), (final, fit, start)


def test_module_and_exceptions():
    k = torch.tensor([[1.0, -0.2, 0.0]])
    loss = GridLoss(grid_size=8)
    ident = _identity(1, torch.float32)
    torch.testing.assert_close(loss(ident, k, SIZE), grid_loss(ident, k, SIZE, 8))
    assert "grid_size=8" in repr(loss)
    with pytest.raises(ValueError, match="correction"):
        grid_loss(torch.ones(1, 3), k, SIZE)
    with pytest.raises(ValueError, match="distortion"):
        grid_loss(torch.ones(2, 5), k, SIZE)
    with pytest.raises(ValueError, match="reduction"):
        grid_loss(torch.ones(1, 5), k, SIZE, reduction="max")
    with pytest.raises(ValueError):
        GridLoss(grid_size=1)
    with pytest.raises(ValueError):
        GridLoss(reduction="avg")
