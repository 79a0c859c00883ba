"""The frame choice's pose coverage: the board planes from the screen's outlines, and moving frames taken where the
still frames do not cover the poses."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ccs_kornia.modules.detection.screening import Sighting
from ccs_kornia.pipeline.frame_candidates import (
    MAX_MOTION,
    MIN_TILT_SPREAD,
    choose_frames,
    outline_normals,
    plane_spread,
)

SIZE = (640, 480)
K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
CORNERS = np.array([[-0.1, -0.075, 0.0], [0.1, -0.075, 0.0], [0.1, 0.075, 0.0], [-0.1, 0.075, 0.0]])


def _outline(rx: float, ry: float, dx: float = 0.0) -> np.ndarray:
    """The outline of a 20x15 cm board 0.6 m ahead (moved ``dx`` m across), tilted by ``rx``, ``ry`` rad."""
    R, _ = cv2.Rodrigues(np.array([rx, ry, 0.0]))
    X = CORNERS @ R.T + np.array([dx, 0.0, 0.6])
    uv = X @ K.T
    return uv[:, :2] / uv[:, 2:]


def _normal(rx: float, ry: float) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.array([rx, ry, 0.0]))
    return R[:, 2]


@pytest.mark.parametrize("rx, ry", [(0.0, 0.0), (0.4, 0.0), (0.0, -0.5), (0.3, 0.3)])
def test_outline_normals_recover_the_board_plane(rx, ry):
    views = [(0.0, 0.0), (0.4, 0.1), (-0.2, 0.4), (rx, ry)]  # tilted views tell the focal length
    normals = outline_normals(np.stack([_outline(*v) for v in views]), SIZE)
    angle = math.degrees(math.acos(min(1.0, abs(float(normals[-1] @ _normal(rx, ry))))))
    assert angle < 2.0


def test_plane_spread_is_the_largest_angle_between_two_planes():
    normals = np.stack([_normal(0.0, 0.0), _normal(0.3, 0.0), _normal(-0.2, 0.0), [np.nan] * 3])
    assert plane_spread(normals) == pytest.approx(math.degrees(0.5), abs=1e-6)
    assert plane_spread(normals[:1]) == 0.0


def _recording(still_tilts, moving_tilts, moving_px):
    """Still frames (0.1 px a frame) at ``still_tilts``, then moving ones at ``moving_tilts``."""
    tilts = list(still_tilts) + list(moving_tilts)
    seen = [Sighting(True, _outline(rx, ry, 0.002 * k)) for k, (rx, ry) in enumerate(tilts)]
    motion = [0.1] * len(still_tilts) + [moving_px] * len(moving_tilts)
    return [seen], [[str(k) for k in range(len(tilts))]], [motion]


PARALLEL = [(0.02 * (k % 3), 0.01 * (k % 4)) for k in range(14)]  # still, within a few degrees
TILTED = [(0.5 * math.cos(a), 0.5 * math.sin(a)) for a in np.linspace(0.0, 2 * math.pi, 12, endpoint=False)]


def test_moving_frames_come_in_where_the_still_frames_do_not_cover_the_poses():
    moving_px = 3.0  # a frame at 640x480: three times the still gate, a third of the moving frames' limit
    assert MAX_MOTION * math.hypot(*SIZE) < moving_px
    seen, labels, motion = _recording(PARALLEL, TILTED, moving_px)
    choice = choose_frames(seen, labels, motion, [SIZE], max_frames=10)
    assert choice.still == [len(PARALLEL)] and choice.still_spread_deg[0] < MIN_TILT_SPREAD
    taken = [i for i in choice.chosen if i >= len(PARALLEL)]
    assert len(taken) >= 5 and choice.moving == taken  # the tilted poses, recorded as taken moving
    assert plane_spread(np.stack([_normal(*(PARALLEL + TILTED)[i]) for i in choice.chosen])) > 40.0


def test_moving_frames_stay_out_where_the_still_frames_cover_the_poses_or_move_too_fast():
    covering = PARALLEL[:6] + TILTED[::2]
    seen, labels, motion = _recording(covering, TILTED[1::2], 3.0)
    choice = choose_frames(seen, labels, motion, [SIZE], max_frames=10)
    assert choice.still_spread_deg[0] >= MIN_TILT_SPREAD and choice.moving == []
    assert all(choice.reasons[0][i].startswith("moving") for i in range(len(covering), len(covering) + 6))
    seen, labels, motion = _recording(PARALLEL, TILTED, 3.0)
    fast = choose_frames(seen, labels, motion, [SIZE], max_frames=10, max_moving=2.0 / math.hypot(*SIZE))
    assert fast.moving == [] and all(i < len(PARALLEL) for i in fast.chosen)
    assert fast.reasons[0][len(PARALLEL)] == "moving (3.0 px/frame)"


def test_moving_frames_that_do_not_widen_the_poses_stay_out():
    seen, labels, motion = _recording(PARALLEL, PARALLEL, 3.0)
    assert choose_frames(seen, labels, motion, [SIZE], max_frames=10).moving == []
