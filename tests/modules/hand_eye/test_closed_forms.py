"""Closed-form hand-eye estimates: exact on exact data (batched, views masked), OpenCV's Park and Andreff agree."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.hand_eye.closed_forms import (
    andreff,
    board_in_robot,
    closed_form_candidates,
    park_martin,
    robot_world,
)
from ccs_kornia.modules.hand_eye.setup import HandEyeSetup, invert_transforms


def _pose(w, t):
    T = torch.zeros(*w.shape[:-1], 4, 4, dtype=w.dtype, device=w.device)
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = exp_so3(w), t, 1.0
    return T


def _data(B=3, V=7, seed=0, device="cpu", dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g, dtype=torch.float64)
    X, Z = _pose(0.5 * r(B, 3), 0.2 * r(B, 3)), _pose(2.0 * r(B, 3), r(B, 3))
    A = _pose(r(B, V, 3), 0.5 * r(B, V, 3))
    M = invert_transforms(X)[:, None] @ A @ Z[:, None]
    return tuple(x.to(device=device, dtype=dtype) for x in (X, Z, A, M))


@pytest.mark.parametrize("fn", [park_martin, andreff, lambda A, M, v: robot_world(A, M, v)[0]])
def test_exact_data_exact_answer(fn, device):
    X, _, A, M = _data(device=device)
    valid = torch.ones(A.shape[:2], dtype=torch.bool, device=device)
    valid[1, 2] = False
    M[1, 2] = float("nan")  # a view without a board: masked, its NaN never read
    out = fn(A, M, valid)
    assert out.shape == (3, 4, 4)
    torch.testing.assert_close(out, X, atol=1e-9, rtol=0)


def test_board_pose_and_candidates(device):
    X, Z, A, M = _data(device=device)
    valid = torch.ones(A.shape[:2], dtype=torch.bool, device=device)
    torch.testing.assert_close(board_in_robot(A, M, valid, X), Z, atol=1e-9, rtol=0)
    torch.testing.assert_close(robot_world(A, M, valid)[1], Z, atol=1e-9, rtol=0)
    names, Xs, _ = closed_form_candidates(A, M, valid)
    assert names == ["park_martin", "andreff", "robot_world"] and Xs.shape == (3, 3, 4, 4)
    torch.testing.assert_close(Xs, X[:, None].expand_as(Xs), atol=1e-9, rtol=0)


def test_float32(dtype):
    X, _, A, M = _data(dtype=dtype)
    out = park_martin(A, M, torch.ones(A.shape[:2], dtype=torch.bool))
    assert out.dtype == dtype
    torch.testing.assert_close(out, X, atol=1e-3 if dtype == torch.float32 else 1e-9, rtol=0)


@pytest.mark.parametrize("ours,flag", [(park_martin, cv2.CALIB_HAND_EYE_PARK), (andreff, cv2.CALIB_HAND_EYE_ANDREFF)])
def test_agrees_with_opencv_on_noisy_motions(ours, flag):
    _, _, A, M = _data(B=1, V=12, seed=4)
    g = torch.Generator().manual_seed(5)
    M = M @ _pose(0.002 * torch.randn(1, 12, 3, generator=g, dtype=torch.float64),
                  0.002 * torch.randn(1, 12, 3, generator=g, dtype=torch.float64))
    T = HandEyeSetup.EYE_IN_HAND.chain(A)[0].numpy()  # eye-in-hand: A = T^-1
    R, t = cv2.calibrateHandEye(list(T[:, :3, :3]), list(T[:, :3, 3]), list(M[0, :, :3, :3].numpy()),
                                list(M[0, :, :3, 3].numpy()), method=flag)
    mine = ours(A, M, torch.ones(1, 12, dtype=torch.bool))[0].numpy()
    assert np.linalg.norm(mine[:3, 3] - t.ravel()) < 0.02 * np.linalg.norm(t)
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(mine[:3, :3] @ R.T)[0])) < 0.5
