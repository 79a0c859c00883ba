"""Tests of the distortion and pose sampling."""

from __future__ import annotations

import math

import pytest
import torch
from _render_helpers import _K, _poses

from ccs_kornia.data.render.lens import (
    opencv_fold_radius,
    project_board,
    undistort_opencv_pixels,
)
from ccs_kornia.data.scenes.sampling import (
    sample_opencv_distortion,
    sample_poses,
    sample_radial_distortion,
)
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.radial import radial_undistort_points

W, H = 160, 120


@pytest.mark.parametrize("model", ["none", "opencv", "radial"])
def test_sample_poses_keep_corners_inside(model):
    K = _K()
    gen = torch.Generator().manual_seed(8)
    dist = sample_opencv_distortion(K, (W, H), 1, gen)[0] if model == "opencv" else None
    radial = sample_radial_distortion(1, "severe", (W, H), gen)[0] if model == "radial" else None
    margin = 6.0
    r, t = sample_poses(K, (5, 4), 0.03, (W, H), 24, gen, dist=dist, radial=radial, margin=margin)
    obj = board_object_points(5, 4, 0.03).expand(24, -1, -1).double()
    pix, ok = project_board(obj, K.double().expand(24, 3, 3), r.double(), t.double(), (W, H),
                            None if dist is None else dist.double().expand(24, 5),
                            None if radial is None else radial.double().expand(24, 3))
    assert bool(ok.all())
    assert float(pix[..., 0].min()) >= margin and float(pix[..., 0].max()) <= W - 1 - margin
    assert float(pix[..., 1].min()) >= margin and float(pix[..., 1].max()) <= H - 1 - margin
    # varied poses: tilts up to 50 degrees about both axes, varied in-plane rotations and distances
    R = camera.axis_angle_to_rotation_matrix(r)
    tilt = torch.rad2deg(torch.acos(R[:, 2, 2].clamp(-1, 1)))
    assert float(tilt.max()) > 25 and float(tilt.max()) <= 50.5
    assert float(R[:, 0, 2].abs().max()) > 0.2 and float(R[:, 1, 2].abs().max()) > 0.2
    roll = torch.rad2deg(torch.atan2(R[:, 1, 0], R[:, 0, 0]))
    assert float(roll.max() - roll.min()) > 90
    assert float(t[:, 2].max() / t[:, 2].min()) > 1.3


def test_sample_poses_deterministic_and_raises():
    a = _poses(5, seed=11)
    b = _poses(5, seed=11)
    c = _poses(5, seed=12)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[0], c[0])
    with pytest.raises(RuntimeError):
        _poses(2, margin=70.0)  # impossible: margin larger than half the image height
    with pytest.raises(ValueError):
        _poses(2, fill_range=(0.0, 0.5))


def test_radial_levels():
    gen = torch.Generator().manual_seed(9)
    l1 = sample_radial_distortion(200, "level1", (640, 480), gen)
    assert bool((l1[:, 0] == 1).all()) and bool(((l1[:, 1] >= -0.35) & (l1[:, 1] <= -0.2)).all())
    assert bool(((l1[:, 2] >= -0.1) & (l1[:, 2] <= 0)).all())
    l2 = sample_radial_distortion(200, "level2", (640, 480), gen)
    assert bool(((l2[:, 0] >= 0.8) & (l2[:, 0] <= 1.2)).all()) and bool(((l2[:, 1] >= -0.5) & (l2[:, 1] <= -0.35)).all())
    assert bool(((l2[:, 2] >= -0.3) & (l2[:, 2] <= -0.1)).all())
    assert torch.equal(sample_radial_distortion(3, "none", (640, 480), gen), torch.tensor([[1.0, 0, 0]] * 3))
    sev = sample_radial_distortion(200, "severe", (640, 480), gen).double()
    # displacement of the farthest image corner: 15-25 % of its ideal radius, monotonic up to it
    rd = 0.5 * math.hypot(639, 479) / 640
    corner = torch.tensor([[[639.0, 479.0]]], dtype=torch.float64).expand(200, 1, 2)
    ideal = radial_undistort_points(corner, sev, (640, 480))
    rc = (ideal[:, 0] - torch.tensor([319.5, 239.5], dtype=torch.float64)).norm(dim=-1) / 640
    disp = 1 - rd / rc
    assert float(disp.min()) > 0.149 and float(disp.max()) < 0.251
    slope = sev[:, 0] + 3 * sev[:, 1] * rc**2 + 5 * sev[:, 2] * rc**4
    assert float(slope.min()) > 0
    anyl = sample_radial_distortion(300, "any", (640, 480), gen)
    assert bool((anyl[:, 1] < 0).all())
    with pytest.raises(ValueError):
        sample_radial_distortion(2, "extreme", (640, 480), gen)


def test_opencv_distortion_sampling_is_invertible_over_the_image():
    gen = torch.Generator().manual_seed(10)
    K = camera.intrinsics_matrix(torch.tensor([[300.0, 300.0, 319.5, 239.5], [800.0, 800.0, 319.5, 239.5]])).repeat(50, 1, 1)
    d = sample_opencv_distortion(K, (640, 480), 100, gen).double()
    assert bool(((d[:, 0] >= -0.4) & (d[:, 0] <= 0.1)).all()) and bool((d[:, 2:4].abs() <= 2e-3).all())
    # the farthest image corner must be reached before the radial factor folds
    corners = torch.tensor([[[0.0, 0.0], [639.0, 479.0]]], dtype=torch.float64).expand(100, 2, 2)
    ideal, residual = undistort_opencv_pixels(corners, K.double(), d)  # fixed point + Newton
    assert float(residual.max()) < 1e-6
    r_fold, _ = opencv_fold_radius(d)
    xn = (ideal - K[:, None, :2, 2].double()) / torch.stack([K[:, 0, 0], K[:, 1, 1]], -1)[:, None].double()
    assert bool((xn.norm(dim=-1) < r_fold[:, None]).all())
