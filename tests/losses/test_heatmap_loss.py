"""Tests of the detection loss of the corner UNet."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from ccs_kornia.losses.heatmap_loss import HeatmapLoss, heatmap_loss


class TestHeatmapLoss:
    def test_zero_for_perfect_prediction(self) -> None:
        target = torch.rand(2, 1, 8, 8)
        assert heatmap_loss(target, target).item() == 0.0
        assert HeatmapLoss(pos_weight=10.0)(target, target).item() == 0.0

    def test_values_and_reductions(self) -> None:
        pred = torch.zeros(1, 1, 4, 4)
        target = torch.zeros(1, 1, 4, 4)
        target[..., 1, 1] = 1.0
        target[..., 1, 2] = 0.05  # below the default 0.1 threshold: not up-weighted
        assert heatmap_loss(pred, target, "sum").item() == pytest.approx(1.0 + 0.0025)
        assert heatmap_loss(pred, target, "mean").item() == pytest.approx((1.0 + 0.0025) / 16)
        assert heatmap_loss(pred, target, "sum", pos_weight=3.0).item() == pytest.approx(4.0 + 0.0025)
        per_pixel = HeatmapLoss("none", pos_weight=3.0)(pred, target)
        assert per_pixel.shape == (1, 1, 4, 4)
        assert per_pixel[0, 0, 1, 1].item() == pytest.approx(4.0)
        assert per_pixel[0, 0, 1, 2].item() == pytest.approx(0.0025)

    def test_matches_mse_without_weight(self) -> None:
        pred, target = torch.rand(2, 1, 9, 7), torch.rand(2, 1, 9, 7)
        torch.testing.assert_close(HeatmapLoss()(pred, target), F.mse_loss(pred, target))

    def test_gradient(self) -> None:
        pred = torch.rand(1, 1, 6, 6, dtype=torch.float64, requires_grad=True)
        target = torch.rand(1, 1, 6, 6, dtype=torch.float64)
        assert torch.autograd.gradcheck(lambda p: heatmap_loss(p, target, pos_weight=2.0), (pred,))

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match=r"target must be \(1, 1, 4, 4\) \(as pred\), got \(1, 1, 4, 5\)"):
            heatmap_loss(torch.rand(1, 1, 4, 4), torch.rand(1, 1, 4, 5))
        with pytest.raises(ValueError, match=r"pred must be \(B, C, H, W\), got \(4, 4\)"):
            heatmap_loss(torch.rand(4, 4), torch.rand(4, 4))
        with pytest.raises(ValueError, match="reduction"):
            HeatmapLoss(reduction="max")
        with pytest.raises(ValueError, match="pos_weight"):
            HeatmapLoss(pos_weight=-1.0)
