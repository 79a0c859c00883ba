"""Rendered hand-eye scenes shared by the hand-eye tests (cached: inverse kinematics takes a moment)."""

from __future__ import annotations

import functools

import torch

from ccs_kornia.data.scenes.robots import render_hand_eye
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import K1K2


@functools.lru_cache(maxsize=16)
def scene(setup: str, views: int = 10, seed: int = 0, noise_px: float = 0.0, joint_noise_deg: float = 0.0,
          max_tilt_deg: float = 30.0):
    return render_hand_eye(setup, views=views, seed=seed, noise_px=noise_px, joint_noise_deg=joint_noise_deg,
                           max_tilt_deg=max_tilt_deg)


def camera(s) -> Camera:
    return Camera.from_opencv(K1K2, s.K, s.dist)


def batch(s, robot_poses: torch.Tensor | None = None):
    """``(corners, valid, object_points, robot_poses)`` of one problem, batched (B = 1)."""
    T = s.robot_poses if robot_poses is None else robot_poses
    return s.corners[None], s.valid[None], s.object_points, T[None]
