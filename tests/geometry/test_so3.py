"""The solver's lean SO(3) maps against kornia's conversions, at and near 0 and pi."""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.camera import (
    axis_angle_to_rotation_matrix,
    rotation_matrix_to_axis_angle,
)
from ccs_kornia.geometry.so3 import exp_so3, log_so3

F64 = torch.float64


def _rotation_vectors(n=400, seed=0):
    g = torch.Generator().manual_seed(seed)
    axis = torch.nn.functional.normalize(torch.randn(4 * n, 3, generator=g, dtype=F64), dim=-1)
    angle = torch.cat([torch.rand(n, generator=g, dtype=F64) * math.pi, math.pi - torch.logspace(-12, -1, n, dtype=F64),
                       torch.logspace(-14, -2, n, dtype=F64), torch.full((n,), math.pi, dtype=F64)])
    return axis * angle[:, None], angle


def test_exp_matches_kornia_and_is_a_rotation(device):
    w, _ = _rotation_vectors()
    R = exp_so3(w.to(device)).cpu()
    torch.testing.assert_close(R, axis_angle_to_rotation_matrix(w), atol=2e-15, rtol=0)
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=F64).expand_as(R), atol=5e-15, rtol=0)
    assert exp_so3(torch.zeros(2, 5, 3, dtype=F64)).shape == (2, 5, 3, 3)


def test_log_inverts_exp_up_to_pi(device):
    w, angle = _rotation_vectors()
    R = axis_angle_to_rotation_matrix(w)
    v = log_so3(R.to(device)).cpu()
    torch.testing.assert_close(exp_so3(v), R, atol=5e-15, rtol=0)  # the same rotation everywhere
    below = angle < math.pi - 1e-6  # (at pi, w and -w are the same rotation)
    torch.testing.assert_close(v[below], w[below], atol=1e-14, rtol=0)
    torch.testing.assert_close(v[below], rotation_matrix_to_axis_angle(R[below]), atol=1e-14, rtol=0)
    assert torch.equal(log_so3(torch.eye(3, dtype=F64)[None]), torch.zeros(1, 3, dtype=F64))
