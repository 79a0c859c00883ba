"""Degenerate or disagreeing hand-eye data is refused, naming the poses: too few poses, tiny rotations, one axis only,
a mispairing (shifted or swapped poses), millimetres read as metres and back, inverted poses."""

from __future__ import annotations

import pytest
import torch
from _hand_eye_scenes import batch, camera, scene

from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.hand_eye.degeneracy import hand_eye_issues, rotation_spread
from ccs_kornia.modules.hand_eye.setup import invert_transforms
from ccs_kornia.modules.hand_eye.solver import calibrate_hand_eye

NAMES = [[f"img{k}.png" for k in range(10)]]


def _refusal(setup, T, s=None):
    s = s or scene(setup, views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)
    c, v, o, TT = batch(s, T)
    out = calibrate_hand_eye(c, v, o, TT, camera(s), setup, heldout=False, names=NAMES)
    errors = [i for i in out.issues[0] if i["severity"] == "error"]
    return out, errors


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_good_data_passes(setup):
    s = scene(setup, views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)
    out, errors = _refusal(setup, s.robot_poses)
    assert bool(out.success[0]) and not errors and out.reasons == [""]


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_images_shifted_against_their_poses(setup):
    s = scene(setup, views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)
    out, errors = _refusal(setup, torch.roll(s.robot_poses, 1, 0))
    assert not bool(out.success[0]) and errors[0]["check"] == "disagree" and len(errors[0]["poses"]) == 10
    assert "each pose belongs to its image" in out.reasons[0]


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_two_swapped_poses_are_named(setup):
    s = scene(setup, views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)
    out, errors = _refusal(setup, s.robot_poses[[0, 1, 2, 3, 4, 5, 6, 8, 7, 9]])
    assert errors[0]["check"] == "disagree" and errors[0]["poses"] == [7, 8]
    assert out.reasons[0].startswith("img7.png, img8.png")


@pytest.mark.parametrize("factor,phrase", [(1000.0, "--pose-units mm"), (0.001, "--pose-units m")])
def test_a_pose_file_in_the_wrong_unit(factor, phrase):
    s = scene("eye_in_hand", views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)
    T = s.robot_poses.clone()
    T[:, :3, 3] *= factor
    out, errors = _refusal("eye_in_hand", T)
    assert errors[0]["check"] == "scale" and phrase in out.reasons[0]


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_inverted_poses_or_the_other_setup(setup):
    s = scene(setup, views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)
    out, errors = _refusal(setup, invert_transforms(s.robot_poses))
    assert errors and "the poses look like the base in the flange frame" in out.reasons[0]
    other = "eye_to_hand" if setup == "eye_in_hand" else "eye_in_hand"
    out, errors = _refusal(other, s.robot_poses, s)
    assert errors and "--eye-in-hand / --eye-to-hand" in out.reasons[0]


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_tiny_rotations_and_too_few_poses(setup):
    s = scene(setup, views=8, seed=2, noise_px=0.2, max_tilt_deg=0.5)
    out = calibrate_hand_eye(*batch(s), camera(s), setup, heldout=False)
    assert not bool(out.success[0]) and out.issues[0][0]["check"] == "tiny_rotation"
    s = scene(setup, views=2, seed=3)
    out = calibrate_hand_eye(*batch(s), camera(s), setup, heldout=False)
    assert out.issues[0][0]["check"] == "too_few_poses" and "at least 3" in out.reasons[0]


def test_rotations_about_one_axis_only():
    # flange rotations about one axis (z), translations anywhere: the translation along z is not determined
    V = 8
    T = torch.eye(4, dtype=torch.float64).repeat(1, V, 1, 1)
    angles = torch.linspace(-0.6, 0.6, V, dtype=torch.float64)
    T[0, :, :3, :3] = exp_so3(torch.stack([0 * angles, 0 * angles, angles], -1))
    T[0, :, :3, 3] = torch.randn(V, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.1
    issues = hand_eye_issues(T, T, torch.ones(1, V, dtype=torch.bool), [[f"p{k}" for k in range(V)]])[0]
    assert [i["check"] for i in issues] == ["one_axis"] and "p0, p1" in issues[0]["message"]
    spread, axes = rotation_spread(T[..., :3, :3], torch.ones(1, V, dtype=torch.bool))
    assert float(spread[0, 1]) < 1e-9 and abs(float(axes[0, 2, 0])) > 0.999
