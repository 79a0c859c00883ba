"""WildChessboards (square sizes, tilt, cut boards, fisheyes, marks), board-free images and the datamodule options."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.datamodules.datamodule import DetectorDataModule, concat_batches
from ccs_kornia.data.datamodules.distortion_datamodule import DistortionDataModule
from ccs_kornia.data.render.optics import square_size_px
from ccs_kornia.data.scenes.distractors import DISTRACTOR_KINDS, board_free_images
from ccs_kornia.data.scenes.wild import WildChessboards, WildSpec

SMALL = dict(image_sizes=((240, 180),), board_cols=(5, 6), board_rows=(4, 5), supersample=1)




def _sample(n=4, seed=0, **kw):
    return WildChessboards(WildSpec(**{**SMALL, **kw})).sample(n, torch.Generator().manual_seed(seed))


def test_same_seed_same_scene_other_seed_other_scene():
    kw = dict(lenses=("pinhole", "opencv", "radial", "fisheye"), marks=("none", "aruco", "dots"),
              blur=("box", "motion"), glare_prob=0.5, shadow_prob=0.5, jpeg_prob=0.5)
    a, b, c = _sample(seed=3, **kw), _sample(seed=3, **kw), _sample(seed=4, **kw)
    assert torch.equal(a.images, b.images) and torch.equal(a.corners, b.corners)
    assert not torch.equal(a.images, c.images)


@pytest.mark.parametrize("lo,hi", [(8.0, 10.0), (25.0, 30.0)])
def test_square_size_in_pixels_follows_the_spec(lo, hi):
    batch = _sample(6, square_px=(lo, hi), max_tilt_deg=20.0, psf_sigma=(0.0, 0.0), image_sizes=((480, 360),))
    sq = square_size_px(batch.corners.double(), batch.corner_valid, batch.board_size)
    # a tilt of up to 20 degrees and perspective shrink or stretch the median spacing a little
    assert bool((sq > 0.75 * lo).all()) and bool((sq < 1.25 * hi).all())


def test_steep_views_and_cut_boards():
    steep = _sample(4, square_px=(12.0, 16.0), min_tilt_deg=60.0, max_tilt_deg=75.0)
    from ccs_kornia.geometry import camera
    R = camera.axis_angle_to_rotation_matrix(steep.rvec.double())
    tilt = torch.rad2deg(torch.acos(R[:, 2, 2].abs()))
    assert bool((tilt > 55).all()) and bool((tilt < 80).all())
    cut = _sample(4, square_px=(15.0, 25.0), cut_prob=1.0)
    n = cut.board_size[:, 0] * cut.board_size[:, 1]
    for i in range(4):
        assert bool(cut.corner_valid[i, : int(n[i])].all())  # every inner corner is inside
    # ... while the board's outer squares cross the border: some of the outermost squares' area is outside
    for i in range(4):
        c = cut.corners[i, : int(n[i])]
        sq = float(square_size_px(cut.corners[i:i + 1].double(), cut.corner_valid[i:i + 1], cut.board_size[i:i + 1])[0])
        gap = torch.minimum(c.min(0).values, torch.tensor([239.0, 179.0]) - c.max(0).values).min()
        assert float(gap) < 1.3 * sq


def test_fisheye_views_carry_their_lens_and_exact_corners():
    batch = _sample(3, image_sizes=((320, 240),), lenses=("fisheye",), fov_deg=(150.0, 200.0))
    assert batch.fisheye is not None and bool((batch.fisheye[:, 4] > math.radians(74)).all())
    obj = np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2)
    for i in range(3):
        cols, rows = (int(v) for v in batch.board_size[i])
        o = np.zeros((cols * rows, 1, 3))
        o[:, 0, 0] = np.tile(np.arange(cols), rows) * float(batch.square[i])
        o[:, 0, 1] = np.repeat(np.arange(rows), cols) * float(batch.square[i])
        ref, _ = cv2.fisheye.projectPoints(o, batch.rvec[i].double().numpy(), batch.tvec[i].double().numpy(),
                                           batch.K[i].double().numpy(), batch.fisheye[i, :4].double().numpy())
        # float32 parameters in the batch: agreement to float32 precision
        assert np.abs(ref.reshape(-1, 2) - batch.corners[i, : cols * rows].numpy()).max() < 1e-2
    del obj


def test_marks_change_the_image_not_the_corners():
    plain = _sample(2, seed=9, marks=("none",), background="plain")
    marked = _sample(2, seed=9, marks=("aruco",), background="plain")
    assert torch.equal(plain.corners, marked.corners)
    assert float((plain.images - marked.images).abs().max()) > 0.2


def test_board_free_images_have_no_board_for_opencv():
    images, kinds = board_free_images(len(DISTRACTOR_KINDS), (320, 240), torch.Generator().manual_seed(0))
    assert images.shape == (len(DISTRACTOR_KINDS), 1, 240, 320) and kinds == list(DISTRACTOR_KINDS)
    assert float(images.min()) >= 0 and float(images.max()) <= 1
    for img in (images[:, 0].numpy() * 255).astype(np.uint8):
        for board in ((9, 6), (7, 5)):
            found, _ = cv2.findChessboardCorners(img, board, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            assert not found


def test_datamodules_keep_todays_defaults_and_mix_in_wild_views():
    g = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    base = DetectorDataModule(image_size=(96, 72), batch_size=4, supersample=1, board_cols=(3, 5), board_rows=(2, 4))
    same = DetectorDataModule(image_size=(96, 72), batch_size=4, supersample=1, board_cols=(3, 5), board_rows=(2, 4),
                              wild_prob=0.0)
    a, b = base.make_batch(g()), same.make_batch(g())
    assert all(torch.equal(a[k], b[k]) for k in a)
    wild = DetectorDataModule(image_size=(96, 72), batch_size=4, supersample=1, board_cols=(3, 5), board_rows=(2, 4),
                              wild_prob=0.5, wild={**SMALL, "board_cols": [3, 4], "board_rows": [2, 3]})
    w = wild.make_batch(g())
    assert w["image"].shape == (4, 1, 72, 96) and w["heatmap"].shape == (4, 1, 72, 96)
    free = DetectorDataModule(image_size=(96, 72), batch_size=4, supersample=1, board_cols=(3, 5), board_rows=(2, 4),
                              board_free_prob=0.25).make_batch(g())
    assert float(free["heatmap"][-1].abs().max()) == 0.0 and not bool(free["valid"][-1].any())
    dist = DistortionDataModule(image_size=(96, 72), batch_size=4, supersample=1, wild_prob=0.5, board_free_prob=0.25,
                                wild={"supersample": 1})
    d = dist.make_batch(g())
    assert d["image"].shape == (4, 1, 72, 96) and d["radial"].shape == (4, 3)
    assert int((~d["valid"].any(-1)).sum()) >= 1  # the board-free view
    assert torch.equal(d["radial"][-1], torch.tensor([1.0, 0.0, 0.0]))


def test_concat_batches_pads_corners():
    a, b = _sample(1, seed=1, board_cols=(3, 3), board_rows=(2, 2)), _sample(2, seed=2)
    c = concat_batches([a, b])
    assert len(c) == 3 and c.corners.shape[1] == b.corners.shape[1] and not bool(c.corner_valid[0, 6:].any())


def test_margin_and_surround_change_the_image_not_the_corners():
    base = dict(square_px=(8.0, 10.0), psf_sigma=(0.0, 0.0), noise_sigma=(0.0, 0.0))
    plain = _sample(3, seed=11, **base)
    framed = _sample(3, seed=11, border_squares=(0.05, 0.3), surround_prob=1.0, surround_level=(0.0, 0.02),
                     surround_texture=(0.0, 0.0), **base)
    assert torch.equal(plain.corners, framed.corners) and torch.equal(plain.corner_valid, framed.corner_valid)
    assert float((plain.images - framed.images).abs().max()) > 0.2
    # the surround is flat and dark: most of a 240x180 view around a board of 8-10 px squares
    assert float((framed.images < 0.1).float().mean()) > 0.3
    with pytest.raises(ValueError, match="border_squares"):
        WildSpec(border_squares=(1.0, 0.5))


@pytest.mark.parametrize("lens", ["pinhole", "opencv", "fisheye"])
def test_unplaceable_board_falls_back_instead_of_raising(lens):
    # inner corners of a 10x7 board 5-6 px apart cannot be 30 px apart (min_square_px) in a 64x48 view, nor can
    # a cut view of 25 px squares keep them inside: the sampler used to raise "Could not place 1 board(s)"
    kw = dict(image_sizes=((64, 48),), board_cols=(10, 10), board_rows=(7, 7), lenses=(lens,), supersample=1,
              psf_sigma=(0.0, 0.0), margin=1.0)
    for extra in (dict(min_square_px=30.0, square_px=(5.0, 6.0)), dict(cut_prob=1.0, square_px=(25.0, 30.0))):
        batch = WildChessboards(WildSpec(**kw, **extra)).sample(3, torch.Generator().manual_seed(0))
        assert batch.images.shape == (3, 1, 48, 64) and bool(torch.isfinite(batch.images).all())
        # the fallback is a full view: every inner corner is inside the image and labelled valid
        assert bool(batch.corner_valid[:, :70].all())
        c = batch.corners[:, :70]
        assert bool(((c[..., 0] >= 1.0) & (c[..., 0] <= 62.0) & (c[..., 1] >= 1.0) & (c[..., 1] <= 46.0)).all())

