"""The hand-eye solver: exact data solved exactly (both set-ups, a batch of problems), noisy data within its stated
uncertainty and better than OpenCV's closed forms, free intrinsics, the module form, its implicit gradients, and bad
arguments."""

from __future__ import annotations

import math

import pytest
import torch
from _hand_eye_scenes import batch, camera, scene

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.hand_eye import HandEyeSetup, HandEyeSolver, calibrate_hand_eye


def _err(X, truth):
    t = 1000 * float((X[:3, 3] - truth[:3, 3]).norm())
    r = math.degrees(float(log_so3(X[:3, :3] @ truth[:3, :3].T).norm()))
    return t, r


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_exact_data_gives_the_true_x_and_board(setup):
    s = scene(setup, views=8, seed=0)
    out = calibrate_hand_eye(*batch(s), camera(s), setup, robot_noise=None, heldout=False)
    assert out.success.tolist() == [True] and out.setup is HandEyeSetup.parse(setup)
    torch.testing.assert_close(out.X[0], s.X, atol=1e-8, rtol=0)
    torch.testing.assert_close(out.Z[0], s.Z, atol=1e-8, rtol=0)
    assert float(out.rms[0]) < 1e-6 and out.start[0] in out.start_names


def test_a_batch_of_problems_is_each_problem_alone():
    s1, s2 = scene("eye_to_hand", views=10, seed=4, noise_px=0.2), scene("eye_to_hand", views=10, seed=5, noise_px=0.2)
    both = calibrate_hand_eye(torch.stack([s1.corners, s2.corners]), torch.stack([s1.valid, s2.valid]),
                              s1.object_points, torch.stack([s1.robot_poses, s2.robot_poses]),
                              Camera.cat([camera(s1), Camera.from_opencv(K1K2, s2.K, s2.dist)]), "eye_to_hand", robot_noise=None)
    alone = calibrate_hand_eye(*batch(s2), camera(s2), "eye_to_hand", robot_noise=None)
    assert both.X.shape == (2, 4, 4) and both.heldout_rms_px.shape == (2, 10)
    torch.testing.assert_close(both.X[1], alone.X[0], atol=1e-9, rtol=0)
    torch.testing.assert_close(both.heldout_rms_px[1], alone.heldout_rms_px[0], atol=1e-6, rtol=0)


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_noisy_data_within_a_millimetre_with_its_uncertainty_and_heldout_figures(setup):
    s = scene(setup, views=15, seed=6, noise_px=0.2, joint_noise_deg=0.01)
    out = calibrate_hand_eye(*batch(s), camera(s), setup)
    t, r = _err(out.X[0], s.X)
    assert bool(out.success[0]) and t < 1.0 and r < 0.2
    # 1-sigma of the right size: neither a hundred times too small nor too large
    assert 0.05 < 1000 * float(out.X_translation_std[0]) < 3.0 and out.std_source == ["leave-one-pose-out"]
    assert out.used[0].all() and bool(out.heldout_rms_px[0].isfinite().all())
    assert 0.1 < float(out.heldout_rms[0]) < 2.0 and 0.0 < float(out.heldout_distance[0]) < 0.002
    assert out.robot_noise.shape == (1, 2) and 0.0 < float(out.pixel_sigma[0]) < 1.0
    assert out.verdict[0] in ("good", "usable")


def test_views_without_a_board_or_a_pose_are_left_out():
    s = scene("eye_in_hand", views=10, seed=7, noise_px=0.1)
    corners, valid, obj, T = batch(s)
    valid = valid.clone()
    valid[0, 3] = False  # no board
    T = T.clone()
    T[0, 5] = float("nan")  # no pose
    out = calibrate_hand_eye(corners, valid, obj, T, camera(s), "eye_in_hand", robot_noise=None)
    assert out.used[0].tolist() == [k not in (3, 5) for k in range(10)]
    assert bool(out.heldout_rms_px[0, 3].isnan()) and bool(out.view_rms[0, 5].isnan())
    assert _err(out.X[0], s.X)[0] < 0.5


def test_free_intrinsics_recover_a_wrong_focal_length():
    s = scene("eye_to_hand", views=20, seed=8, noise_px=0.1)
    K = s.K.clone()
    K[0, 0] *= 1.01
    K[1, 1] *= 1.01
    out = calibrate_hand_eye(*batch(s), Camera.from_opencv(K1K2, K, s.dist), "eye_to_hand", free_intrinsics=["fx", "fy"],
                             robot_noise=None, heldout=False)
    assert abs(float(out.camera.params[0, 0]) - float(s.K[0, 0])) < 1.0
    assert float(out.intrinsics_std[0, 0]) > 0 and float(out.intrinsics_std[0, 2]) == 0.0


def test_module_form_and_implicit_gradients():
    s = scene("eye_to_hand", views=6, seed=9, noise_px=0.3)
    solver = HandEyeSolver("eye_to_hand", robot_noise=None, heldout=False)
    corners = s.corners[None].clone().requires_grad_()
    out = solver(corners, s.valid[None], s.object_points, s.robot_poses[None], camera(s))
    (out.X[0, :3, 3].sum() + out.Z[0, 0, 3]).backward()
    g = corners.grad
    assert g.shape == corners.shape and bool(g.isfinite().all()) and float(g.abs().max()) > 0
    # the gradient is the optimum's derivative: a central difference on one corner
    eps, (v, n, k) = 1e-5, (2, 10, 0)
    f = []
    for sign in (1, -1):
        c = s.corners[None].clone()
        c[0, v, n, k] += sign * eps
        o = solver(c, s.valid[None], s.object_points, s.robot_poses[None], camera(s))
        f.append(float(o.X[0, :3, 3].sum() + o.Z[0, 0, 3]))
    assert abs((f[0] - f[1]) / (2 * eps) - float(g[0, v, n, k])) < 0.02 * abs(float(g[0, v, n, k])) + 1e-9


def test_bad_arguments():
    s = scene("eye_in_hand", views=8, seed=0)
    c, v, o, T = batch(s)
    with pytest.raises(ValueError, match="corners must be"):
        calibrate_hand_eye(c[0], v, o, T, camera(s))
    with pytest.raises(ValueError, match="robot_poses must be"):
        calibrate_hand_eye(c, v, o, T[:, :4], camera(s))
    with pytest.raises(ValueError, match="object_points"):
        calibrate_hand_eye(c, v, o[:5], T, camera(s))
    with pytest.raises(ValueError, match="unknown hand-eye set-up"):
        calibrate_hand_eye(c, v, o, T, camera(s), "eye_on_table")
    with pytest.raises(ValueError, match="robot_noise"):
        calibrate_hand_eye(c, v, o, T, camera(s), robot_noise="sometimes")


def test_a_symmetric_board_numbered_both_ways_is_agreed_through_the_robot():
    s = scene("eye_in_hand", views=10, seed=10, noise_px=0.1)
    corners = s.corners.clone()
    flipped = [2, 5, 6]
    corners[flipped] = corners[flipped].flip(1)  # a 9x6 grid turned by 180 degrees: the order reversed
    args = (corners[None], s.valid[None], s.object_points, s.robot_poses[None], camera(s), "eye_in_hand")
    out = calibrate_hand_eye(*args, robot_noise=None, heldout=False, align_orders=True)
    assert out.board_order[0].tolist() == [int(k in flipped) for k in range(10)]
    assert bool(out.success[0]) and _err(out.X[0], s.X)[0] < 0.5
    torch.testing.assert_close(out.corners[0, 2], s.corners[2])
    refused = calibrate_hand_eye(*args, robot_noise=None, heldout=False)  # without the agreement: views disagree
    assert not bool(refused.success[0]) and "disagree" in [i["check"] for i in refused.issues[0]]
