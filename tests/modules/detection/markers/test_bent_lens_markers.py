"""Marker boards seen through a strongly bent lens (an action camera's): every marker on the lattice, every corner
placed within the clear band by the markers touching it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ccs_kornia.data.scenes.action_camera import (
    ACTION_DIST,
    ACTION_K,
    ACTION_SIZE,
    action_board_pose,
    field_radius,
)
from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.modules.detection.markers.charuco import (
    CharucoMarkers,
    _initial_corners,
    _touching_corners,
    board_markers,
)
from ccs_kornia.modules.detection.markers.marker_board import consistent_markers

BOARD = CharucoBoard(19, 10, 0.04, 0.03, "DICT_4X4_250", legacy=False)


def _projected_markers(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The board's markers seen in full by the action camera in a random pose: ids, image corners (M, 4, 2), board
    corners (M, 4, 2) in squares, and the pose."""
    layout = board_markers(BOARD, False)
    ids = np.array(sorted(layout))
    obj = np.stack([layout[i] for i in ids])
    rvec, tvec = action_board_pose(BOARD, np.random.default_rng(seed))
    pts3 = np.concatenate([obj.reshape(-1, 2) * BOARD.square, np.zeros((obj.size // 2, 1))], -1)
    cam = pts3 @ cv2.Rodrigues(rvec)[0].T + tvec
    img, _ = cv2.projectPoints(pts3, rvec, tvec, ACTION_K, ACTION_DIST)
    img = img.reshape(-1, 4, 2)
    radius = np.linalg.norm(cam[:, :2] / cam[:, 2:], axis=-1).reshape(-1, 4)
    w, h = ACTION_SIZE
    seen = ((img >= 0) & (img <= [w - 1, h - 1])).all(-1).all(-1) & (radius < field_radius()).all(-1)
    return ids[seen], img[seen], obj[seen], (rvec, tvec)


@pytest.mark.parametrize("seed", [1, 8, 18, 30])
def test_every_marker_near_the_frame_is_on_the_lattice(seed):
    # poses where a homography of a marker's neighbours on one side bends its far corners by more than a quarter unit
    _, img, obj, _ = _projected_markers(seed)
    assert len(img) > 50
    assert consistent_markers(img, obj).all()


def test_a_wrong_id_stays_off_the_lattice():
    _, img, obj, _ = _projected_markers(8)
    wrong = obj.copy()
    wrong[[10, 40]] = obj[[40, 10]]  # two markers read as each other
    keep = consistent_markers(img, wrong)
    assert not keep[[10, 40]].any() and keep.sum() == len(img) - 2


@pytest.mark.parametrize("seed", [0, 4, 8, 14])
def test_initial_corners_within_the_clear_band(seed):
    ids, img, obj, (rvec, tvec) = _projected_markers(seed)
    markers = CharucoMarkers(img, ids, obj)
    cid, ring, spacing = _initial_corners(markers, BOARD, ACTION_SIZE)
    pts = _touching_corners(markers, BOARD, cid, ring)
    truth, _ = cv2.projectPoints(BOARD.object_points().numpy()[cid], rvec, tvec, ACTION_K, ACTION_DIST)
    err = np.linalg.norm(pts - truth.reshape(-1, 2), axis=-1) / spacing
    band = 0.5 * (BOARD.square - BOARD.marker) / BOARD.square
    # the markers touching a corner put it less than half the clear band off, even at the frame's edge (a homography
    # of the markers within 1.6 squares put some corners more than half of it off on each of these poses)
    assert len(cid) > 100 and err.max() < 0.45 * band
