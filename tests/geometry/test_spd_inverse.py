"""spd_inverse / pseudo_inverse: exact on SPD matrices, finite on singular ones, NaN (never a crash) on broken ones."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.spd_inverse import pseudo_inverse, spd_inverse


def test_inverses(device):
    g = torch.Generator().manual_seed(0)
    B = torch.randn(3, 4, 4, generator=g, dtype=torch.float64)
    A = (B @ B.transpose(-1, -2) + 0.1 * torch.eye(4, dtype=torch.float64)).to(device)
    eye = torch.eye(4, dtype=torch.float64, device=device)
    assert torch.allclose(spd_inverse(A) @ A, eye.expand(3, 4, 4), atol=1e-8)
    assert torch.allclose(pseudo_inverse(A) @ A, eye.expand(3, 4, 4), atol=1e-8)
    singular = A.clone()
    singular[1, 2, :] = singular[1, :, 2] = 0.0  # a parameter without information
    assert bool(spd_inverse(singular)[1].isnan().all()) and bool(spd_inverse(singular)[0].isfinite().all())
    assert bool(pseudo_inverse(singular).isfinite().all())
    broken = A.clone()
    broken[2, 0, 0] = float("inf")
    broken[0, 1, 1] = float("nan")
    out = pseudo_inverse(broken)
    assert bool(out[0].isnan().all()) and bool(out[2].isnan().all()) and bool(out[1].isfinite().all())
