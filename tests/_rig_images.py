"""Rendered image sets of a stereo rig for the rig tests: two cameras seeing the same board poses.

Camera 0's board poses come from :func:`~ccs_kornia.data.scenes.scenes.make_calibration_set` (the board inside its image);
camera 1 sees each board through the rig's extrinsics ``x_1 = R x_0 + T`` and is rendered with its own camera matrix
and image size. Only frames where camera 1 sees the whole board are kept, so both cameras find every board.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch

from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.camera import (
    axis_angle_to_rotation_matrix,
    rotation_matrix_to_axis_angle,
)
from ccs_kornia.io.images import write_image

BOARD = (6, 4)
SQUARE = 0.025
K0 = torch.tensor([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
K1 = torch.tensor([[330.0, 0.0, 176.0], [0.0, 330.0, 132.0], [0.0, 0.0, 1.0]])
SIZES = [(320, 240), (352, 264)]
#: camera 1 sits 4 cm to the right of camera 0, turned 2 degrees about the vertical axis (towards camera 0's view)
ANGLE_DEG = 2.0
R_REL = axis_angle_to_rotation_matrix(torch.tensor([[0.0, -math.radians(ANGLE_DEG), 0.0]]))[0]
T_REL = torch.tensor([-0.04, 0.0, 0.0])


@dataclass
class StereoImages:
    images: list[torch.Tensor]  # per camera (F, 1, H, W)
    R: torch.Tensor
    T: torch.Tensor


#: a third camera for three-camera rigs: 3 cm below camera 0, turned 3 degrees about the horizontal axis
R_THIRD = axis_angle_to_rotation_matrix(torch.tensor([[math.radians(3.0), 0.0, 0.0]]))[0]
T_THIRD = torch.tensor([0.0, -0.03, 0.0])


def render_stereo(frames: int = 8, seed: int = 3, size1: tuple[int, int] = SIZES[1], third: bool = False,
                  max_tilt_deg: float = 35.0) -> StereoImages:
    """Two cameras (three with ``third``: camera 0's matrix and size at ``R_THIRD``, ``T_THIRD``), ``frames`` frames
    of the same board poses (every camera sees every board whole); camera 1's images are ``size1``; the boards are
    tilted by at most ``max_tilt_deg`` to camera 0."""
    first = make_calibration_set(K0, BOARD, SQUARE, SIZES[0], num_views=4 * frames, seed=seed, supersample=1,
                                 fill_range=(0.3, 0.5), max_tilt_deg=max_tilt_deg)
    R0 = axis_angle_to_rotation_matrix(first.rvec.float())
    others = [(K1, size1, R_REL, T_REL)] + ([(K0, SIZES[0], R_THIRD, T_THIRD)] if third else [])
    images, inside = [first.images], torch.ones(len(R0), dtype=torch.bool)
    for K, size, R, T in others:
        rvec = rotation_matrix_to_axis_angle(R @ R0)
        t = (R @ first.tvec.float()[..., None])[..., 0] + T
        image, corners = render_chessboard(K.expand(len(t), 3, 3), rvec, t, BOARD, SQUARE, size, supersample=1)
        w, h = size
        inside &= ((corners[..., 0] > 12) & (corners[..., 0] < w - 13) & (corners[..., 1] > 12)
                   & (corners[..., 1] < h - 13)).all(-1)
        images.append(image)
    keep = inside.nonzero().flatten()[:frames]
    assert keep.numel() == frames, f"only {keep.numel()} frames seen whole by every camera"
    return StereoImages([im[keep] for im in images], R_REL, T_REL)


def write_stereo(stereo: StereoImages, folder: Path, names=("left", "right"), pattern="{name}{k:02d}.png",
                 frames: list[list[int]] | None = None) -> list[Path]:
    """One folder per camera; ``frames[c]``: which frames camera ``c`` gets (default all); returns the folders."""
    dirs = []
    for c, name in enumerate(names):
        d = folder / name
        d.mkdir(parents=True, exist_ok=True)
        picks = range(stereo.images[c].shape[0]) if frames is None else frames[c]
        for k in picks:
            assert write_image(d / pattern.format(name=name, k=k + 1), stereo.images[c][k, 0])
        dirs.append(d)
    return dirs
