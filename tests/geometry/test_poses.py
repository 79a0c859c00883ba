"""Relative poses of a rig's cameras: composition and inverse."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.poses import pair_pose
from ccs_kornia.geometry.so3 import exp_so3


def test_pair_pose_maps_points_between_cameras(device, dtype):
    g = torch.Generator().manual_seed(0)
    R = exp_so3(0.3 * torch.randn(3, 3, generator=g, dtype=torch.float64)).to(device, dtype)
    T = torch.randn(3, 3, generator=g, dtype=torch.float64).to(device, dtype)
    x0 = torch.tensor([0.3, -0.2, 2.0], dtype=dtype, device=device)
    x = [R[c] @ x0 + T[c] for c in range(3)]
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for i, j in [(0, 1), (1, 2), (2, 0), (1, 1)]:
        Rij, Tij = pair_pose(R, T, i, j)
        assert torch.allclose(Rij @ x[i] + Tij, x[j], atol=tol)
    R12, T12 = pair_pose(R, T, 1, 2)
    R21, T21 = pair_pose(R, T, 2, 1)
    assert torch.allclose(R21, R12.T, atol=tol) and torch.allclose(T21, -R12.T @ T12, atol=tol)
