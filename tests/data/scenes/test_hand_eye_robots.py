"""Rendered robots with a real arm's kinematic errors: the true arm's joint offsets and link lengths off the kinematics
it reports with (one draw per scene, so each pose's error depends on the pose), and the reported pose lagging the
image while the arm moves on; the scene is otherwise the one drawn without them."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.data.scenes.robots import PANDA_DH, panda_flange_poses, render_hand_eye

SCENE = dict(views=4, seed=3, noise_px=0.0, joint_noise_deg=0.0)


@pytest.fixture(scope="module")
def scenes():
    plain = render_hand_eye("eye_to_hand", **SCENE)
    arm = render_hand_eye("eye_to_hand", **SCENE, joint_offset_deg=0.05, link_error_mm=0.3, time_offset_s=0.01,
                          move_s=2.0)
    return plain, arm


def test_the_errors_are_drawn_after_the_scene(scenes):
    plain, arm = scenes
    assert plain.joint_offsets is None and plain.link_errors is None and plain.time_offset_s == 0.0
    torch.testing.assert_close(plain.robot_poses, plain.true_poses)
    torch.testing.assert_close(arm.joints, plain.joints)  # the same views reached, the same camera and board
    torch.testing.assert_close(arm.X, plain.X)


def test_the_images_come_from_the_true_arm_the_poses_from_the_published_one(scenes):
    _, s = scenes
    assert s.joint_offsets.shape == (7,) and s.link_errors.shape == (len(PANDA_DH), 2) and s.time_offset_s == 0.01
    torch.testing.assert_close(s.true_poses, panda_flange_poses(s.joints, s.joint_offsets, s.link_errors))
    # the reported pose: the published kinematics at the joints the arm had 10 ms before the image, moving on to the
    # next view in 2 s (the last view keeps the motion it came with)
    velocity = torch.cat([s.joints[1:] - s.joints[:-1], s.joints[-1:] - s.joints[-2:-1]]) / 2.0
    torch.testing.assert_close(s.robot_poses, panda_flange_poses(s.joints - 0.01 * velocity))
    err = 1000 * (s.robot_poses[:, :3, 3] - s.true_poses[:, :3, 3]).norm(dim=-1)
    assert float(err.min()) > 0.05 and float(err.max()) < 20.0 and float(err.std()) > 0.05  # pose-dependent
    cam = torch.linalg.inv(s.X) @ s.true_poses @ s.Z
    xc = s.object_points @ cam[:, :3, :3].transpose(-1, -2) + cam[:, None, :3, 3]
    torch.testing.assert_close(s.camera.project(xc[None])[0], s.corners)
