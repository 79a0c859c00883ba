"""The rig's state: each camera's board pose from the extrinsics and the frame poses, one rig out of a batch, copies
of the batch."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.models import K1K2
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.rig.rig_state import RigState

D = torch.float64


def state(B, C, F, device="cpu"):
    g = torch.Generator().manual_seed(0)
    R = exp_so3(torch.randn(B * C, 3, generator=g, dtype=D) * 0.1).reshape(B, C, 3, 3).to(device)
    T = torch.randn(B, C, 3, generator=g, dtype=D).to(device)
    Rf = exp_so3(torch.randn(B * F, 3, generator=g, dtype=D) * 0.1).reshape(B, F, 3, 3).to(device)
    tf = torch.randn(B, F, 3, generator=g, dtype=D).to(device)
    params = [torch.randn(B, 6, generator=g, dtype=D).to(device) for _ in range(C)]
    return RigState([K1K2] * C, params, R, T, Rf, tf)


def test_board_poses(device):
    B, C, F = 2, 3, 4
    s = state(B, C, F, device)
    Rc, tc = s.board_poses()
    assert Rc.shape == (B, C, F, 3, 3) and tc.shape == (B, C, F, 3)
    assert torch.allclose(Rc[1, 2, 3], s.R[1, 2] @ s.frame_R[1, 3])
    assert torch.allclose(tc[1, 2, 3], s.R[1, 2] @ s.frame_t[1, 3] + s.T[1, 2])
    assert s.num_cameras == C and s.num_frames == F


def test_one_rig_and_copies():
    s = state(2, 2, 3)
    one = s.rig(1)
    assert one.R.shape == (1, 2, 3, 3) and torch.equal(one.frame_t[0], s.frame_t[1])
    assert all(torch.equal(p[0], q[1]) for p, q in zip(one.params, s.params))
    copies = s.repeat(3)
    assert copies.T.shape == (6, 2, 3) and copies.params[0].shape == (6, 6)
    # copy i of rig b sits at i * B + b (the held-out folds' layout)
    assert torch.equal(copies.T[2 * 2 + 1], s.T[1]) and torch.equal(copies.params[1][2], s.params[1][0])
    assert copies.models is s.models
