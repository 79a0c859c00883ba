"""Tests of the paper's calibration metrics (E_FL, E_PP, E_IP)."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.metrics import e_fl, e_ip, e_pp, per_view_rms, rms


def test_metrics():
    K = torch.tensor([[502.0, 0, 321], [0, 497, 238], [0, 0, 1]])
    K_true = torch.tensor([500.0, 500.0, 320.0, 240.0])
    assert e_fl(K, K_true) == 5 and e_pp(K, K_true) == 3 and e_ip(K, K_true) == 4
    assert e_ip(K[None].expand(3, 3, 3), K_true).shape == (3,)
    proj = torch.zeros(2, 4, 2)
    obs = torch.zeros(2, 4, 2)
    obs[0, 0] = torch.tensor([3.0, 4.0])
    obs[1, 3] = float("nan")
    valid = torch.ones(2, 4, dtype=torch.bool)
    valid[1, 3] = False
    assert torch.isclose(rms(proj, obs, valid), torch.tensor((25 / 7) ** 0.5))
    assert torch.allclose(per_view_rms(proj, obs, valid), torch.tensor([2.5, 0.0]))
    with pytest.raises(ValueError):
        e_ip(torch.zeros(3), K_true)
