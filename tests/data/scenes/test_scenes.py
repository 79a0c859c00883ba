"""Tests of the calibration sets and the random training scenes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.render import augment
from ccs_kornia.data.scenes.scenes import (
    SyntheticBatch,
    SyntheticChessboards,
    make_calibration_set,
)
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.board_points import board_object_points


def test_make_calibration_set():
    K = torch.tensor([[250.0, 0.0, 99.5], [0.0, 250.0, 74.5], [0.0, 0.0, 1.0]])
    b = make_calibration_set(K, (6, 4), 0.025, (200, 150), num_views=3, condition="blur_noise", seed=3, supersample=1)
    assert isinstance(b, SyntheticBatch) and len(b) == 3
    assert b.images.shape == (3, 1, 150, 200) and b.corners.shape == (3, 24, 2)
    assert bool(b.corner_valid.all()) and b.image_size == (200, 150)
    assert torch.equal(b.K, K.expand(3, 3, 3)) and torch.equal(b.board_size, torch.tensor([[6, 4]] * 3))
    assert bool((b.dist == 0).all()) and torch.equal(b.radial, torch.tensor([[1.0, 0, 0]] * 3))
    assert bool((b.condition == augment.CONDITIONS.index("blur_noise")).all())
    again = make_calibration_set(K, (6, 4), 0.025, (200, 150), num_views=3, condition="blur_noise", seed=3, supersample=1)
    assert torch.equal(b.images, again.images) and torch.equal(b.corners, again.corners)
    other = make_calibration_set(K, (6, 4), 0.025, (200, 150), num_views=3, condition="blur_noise", seed=4, supersample=1)
    assert not torch.equal(b.corners, other.corners)
    # ground truth is the forward projection of the stored parameters
    obj = board_object_points(6, 4, 0.025).expand(3, -1, -1)
    proj = camera.project_points(obj, b.K, b.dist, b.rvec, b.tvec)
    assert float((proj - b.corners).abs().max()) < 1e-3
    moved = b.to("cpu")
    assert torch.equal(moved.images, b.images) and moved.image_size == b.image_size
    with pytest.raises(ValueError):
        make_calibration_set(K, condition="foggy")
    with pytest.raises(ValueError):
        make_calibration_set(K.expand(2, 3, 3))


def test_synthetic_chessboards_sample():
    data = SyntheticChessboards(image_size=(128, 96), board_cols=(4, 6), board_rows=(3, 5), fx_range=(120, 200),
                                partial_prob=0.5, supersample=2)
    gen = torch.Generator().manual_seed(0)
    b = data.sample(6, gen)
    assert b.images.shape == (6, 1, 96, 128) and b.corners.shape == (6, 30, 2) == (6, data.max_corners, 2)
    assert float(b.images.min()) >= 0 and float(b.images.max()) <= 1
    cols, rows = b.board_size[:, 0], b.board_size[:, 1]
    assert bool(((cols >= 4) & (cols <= 6) & (rows >= 3) & (rows <= 5)).all())
    n = torch.arange(30)
    exists = n[None] < (cols * rows)[:, None]
    assert not bool((b.corner_valid & ~exists).any())
    v = b.corners[b.corner_valid]
    assert float(v[:, 0].min()) >= data.margin and float(v[:, 0].max()) <= 127 - data.margin
    # each view keeps at least 30 % of its corners
    assert bool((b.corner_valid.sum(1) >= 0.3 * (cols * rows)).all())
    # radial views carry (k0, k1, k2), OpenCV views k1.., the rest identity coefficients
    assert b.dist.shape == (6, 5) and b.radial.shape == (6, 3) and b.condition.shape == (6,)
    # same generator seed, same batch
    b2 = data.sample(6, torch.Generator().manual_seed(0))
    assert torch.equal(b.images, b2.images) and torch.equal(b.corners, b2.corners)


def test_synthetic_chessboards_ground_truth_matches_render():
    """Ground truth of random scenes (all distortion modes) agrees with cornerSubPix on the rendered image."""
    data = SyntheticChessboards(image_size=(200, 150), board_cols=(5, 6), board_rows=(4, 5), fx_range=(180, 260),
                                conditions=("clean",), supersample=3, max_roll_deg=30.0, fill_range=(0.6, 0.9))
    b = data.sample(6, torch.Generator().manual_seed(2))
    errs = []
    for i in range(6):
        im = cv2.GaussianBlur(b.images[i, 0].numpy(), (0, 0), 1.0)
        c = b.corners[i][b.corner_valid[i]].numpy()
        out = cv2.cornerSubPix(im, c.reshape(-1, 1, 2).copy() + 0.4, (3, 3), (-1, -1), (3, 50, 1e-5))
        errs.append(np.linalg.norm(out.reshape(-1, 2) - c, axis=1))
    assert np.concatenate(errs).mean() < 0.06


def test_synthetic_chessboards_options():
    with pytest.raises(ValueError):
        SyntheticChessboards(distortion="fisheye")
    with pytest.raises(ValueError):
        SyntheticChessboards(conditions=("rain",))
    with pytest.raises(ValueError):
        SyntheticChessboards(board_cols=(5, 3))
    data = SyntheticChessboards(image_size=(96, 72), board_cols=(3, 4), board_rows=(3, 3), fx_range=(90, 120),
                                distortion="radial", radial_level="severe", supersample=1)
    b = data.sample(3, torch.Generator().manual_seed(1))
    assert bool((b.radial[:, 1] < 0).all()) and bool((b.dist == 0).all())
    data = SyntheticChessboards(image_size=(96, 72), board_cols=(3, 4), board_rows=(3, 3), fx_range=(90, 120),
                                distortion=("none",), supersample=1)
    b = data.sample(2, torch.Generator().manual_seed(1))
    assert bool((b.dist == 0).all()) and torch.equal(b.radial, torch.tensor([[1.0, 0, 0]] * 2))
