"""The cause a hand-eye verdict names: a camera that does not fit its images (not the robot), a board given at the
wrong size (refused with the size the robot sees), and data that fits (no cause named); rendered robots with exact
truth."""

from __future__ import annotations

import math

import torch
from _hand_eye_scenes import batch, camera, scene

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.modules.hand_eye import calibrate_hand_eye
from ccs_kornia.modules.hand_eye.target_scale import board_scale


def test_a_board_given_at_the_wrong_size_is_refused_with_its_size():
    s = scene("eye_in_hand", views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)  # the scene other tests use
    corners, valid, obj, T = batch(s)
    res = calibrate_hand_eye(corners, valid, obj * 1.03, T, camera(s), "eye_in_hand", heldout=False)
    assert not bool(res.success[0])
    found = [i for i in res.issues[0] if i["check"] == "board_scale"]
    assert found and "times the size it was given" in res.reasons[0]
    assert abs(found[0]["scale"] - 1 / 1.03) < 0.004
    ok = calibrate_hand_eye(corners, valid, obj, T, camera(s), "eye_in_hand", heldout=False)
    assert bool(ok.success[0]) and not any(i["check"] == "board_scale" for i in ok.issues[0])


def test_board_scale_is_one_on_agreeing_data():
    s = scene("eye_in_hand", views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)  # the scene other tests use
    corners, valid, obj, T = batch(s)
    res = calibrate_hand_eye(corners, valid, obj, T, camera(s), "eye_in_hand", heldout=False)
    A = torch.linalg.inv(T)  # eye-in-hand: the chain is the flange pose's inverse
    ratio, se = board_scale(A, res.board_poses, res.used, res.X[:, :3, :3], res.Z[:, :3, :3])
    assert abs(float(ratio[0]) - 1.0) < 3 * float(se[0]) + 1e-3 and math.isfinite(float(se[0]))


def test_a_camera_that_does_not_fit_is_named_not_the_robot():
    s = scene("eye_in_hand", views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)  # the scene other tests use
    corners, valid, obj, T = batch(s)
    # the lens given the wrong way round (k1 +0.4 where the scene's lens has k1 about -0.1)
    wrong = Camera.from_opencv(K1K2, s.K, torch.tensor([0.4, 0.0], dtype=torch.float64))
    res = calibrate_hand_eye(corners, valid, obj, T, wrong, "eye_in_hand")
    good = calibrate_hand_eye(corners, valid, obj, T, camera(s), "eye_in_hand", heldout=False)
    if bool(res.success[0]):
        assert res.verdict[0].startswith("not reliable: the given camera does not fit these images"), res.verdict[0]
        assert "check the robot's pose" not in res.verdict[0]
    else:  # refused outright: the fit is far off, and the reason says the camera is not the robot
        assert "camera" in res.reasons[0]
    assert "camera does not fit" not in good.verdict[0]
