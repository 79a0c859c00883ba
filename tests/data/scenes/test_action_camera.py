"""Rendered action-camera photographs of a large ChArUco board: shapes, the truth in the image and on the print,
the same view from the same seed, the lens one to one over the frame, the board filling the frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ccs_kornia.data.scenes.action_camera import (
    ACTION_DIST,
    ACTION_K,
    ACTION_SIZE,
    MIN_VISIBLE,
    SPAN,
    action_board_pose,
    field_radius,
    render_action_view,
)
from ccs_kornia.modules.detection.boards import CharucoBoard

BOARD = CharucoBoard(19, 10, 0.04, 0.03, "DICT_4X4_250", legacy=False)


@pytest.fixture(scope="module")
def views():
    return [render_action_view(BOARD, np.random.default_rng(seed), supersample=1) for seed in range(3)]


def test_shapes_and_truth_inside(views):
    w, h = ACTION_SIZE
    for img, truth in views:
        assert img.shape == (h, w) and img.dtype == np.uint8
        assert truth.shape == (BOARD.num_corners, 2)
        seen = np.isfinite(truth).all(-1)
        assert seen.mean() >= MIN_VISIBLE
        assert (truth[seen] >= 0).all() and (truth[seen, 0] <= w - 1).all() and (truth[seen, 1] <= h - 1).all()


def test_truth_on_the_print(views):
    # a true corner is where two black squares meet: its diagonal neighbourhood alternates dark and light
    for img, truth in views:
        blurred = cv2.GaussianBlur(img.astype(np.float64), (0, 0), 1.0)
        seen = np.flatnonzero(np.isfinite(truth).all(-1))
        pts = truth[seen]
        inner = (pts[:, 0] > 10) & (pts[:, 0] < ACTION_SIZE[0] - 11) & (pts[:, 1] > 10) & (pts[:, 1] < ACTION_SIZE[1] - 11)
        x, y = np.round(pts[inner]).astype(int).T
        d = 3
        a = blurred[y - d, x - d] + blurred[y + d, x + d]
        b = blurred[y - d, x + d] + blurred[y + d, x - d]
        # the two diagonals differ by far more than the noise on most corners (the print's contrast is >= 120)
        assert np.mean(np.abs(a - b) > 40) > 0.9


def test_same_seed_same_view():
    a = render_action_view(BOARD, np.random.default_rng(7), supersample=1)
    b = render_action_view(BOARD, np.random.default_rng(7), supersample=1)
    c = render_action_view(BOARD, np.random.default_rng(8), supersample=1)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1], equal_nan=True)
    assert not np.array_equal(a[0], c[0])


def test_lens_one_to_one_over_the_frame():
    w, h = ACTION_SIZE
    ys, xs = np.mgrid[0:h:8, 0:w:8].astype(np.float64)
    pix = np.stack([xs, ys], -1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pix, ACTION_K, ACTION_DIST,
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)).reshape(-1, 2)
    back, _ = cv2.projectPoints(np.concatenate([rays, np.ones((len(rays), 1))], -1), np.zeros(3), np.zeros(3),
                                ACTION_K, ACTION_DIST)
    assert np.abs(back.reshape(-1, 2) - pix.reshape(-1, 2)).max() < 1e-3
    # a strongly bent lens: the frame's corners see far wider than a pinhole of the same focal length
    corner = np.hypot(w / 2, h / 2) / ACTION_K[0, 0]
    assert field_radius() > 1.3 * corner


def test_board_fills_the_frame():
    obj = BOARD.object_points().numpy()
    extent = obj[:, :2].max(0) - obj[:, :2].min(0)
    for seed in range(5):
        _, tvec = action_board_pose(BOARD, np.random.default_rng(seed))
        span = ACTION_K[0, 0] * float(extent.max()) / float(tvec[2]) / ACTION_SIZE[0]
        assert 0.8 * SPAN[0] < span < 1.6 * SPAN[1]
