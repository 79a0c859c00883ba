"""Circle grids: OpenCV's symmetric and asymmetric grids and ROS-Industrial's modified grid on rendered views (steep
tilts, a strong lens, dark dots and the inverse), the origin dot's order, and the centres corrected for perspective
and distortion against their exact projections."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.marker_views import (
    DIST,
    K,
    random_board_pose,
    render_marker_view,
)
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.detection.boards import CircleGrid, grid_object_points
from ccs_kornia.modules.detection.circles.centre_bias import (
    centre_bias,
    correct_centres,
)
from ccs_kornia.modules.detection.circles.circle_grid import (
    CircleGridDetector,
    detect_circle_grid,
    order_marked_origin,
)

CAMERA = Camera.from_opencv(OPENCV5, torch.tensor(K), torch.tensor(DIST), (640, 480))
BOARDS = {"symmetric": CircleGrid(7, 5, 0.03), "asymmetric": CircleGrid(4, 11, 0.02, asymmetric=True),
          "marked origin": CircleGrid(6, 6, 0.025, marked_origin=True)}


def _view(board: CircleGrid, seed: int, tilt: float = 50.0, inverted: bool = False):
    rng = np.random.default_rng(seed)
    rvec, tvec = random_board_pose(board, rng, tilt_deg=tilt)
    image, truth = render_marker_view(board, rvec, tvec, supersample=2)
    image = 255 - image if inverted else image
    return torch.from_numpy(image).float()[None, None] / 255, truth, rvec, tvec


@pytest.mark.parametrize("kind", list(BOARDS))
def test_centres_in_order_and_corrected_to_the_truth(kind):
    board = BOARDS[kind]
    image, truth, rvec, tvec = _view(board, seed=3)
    det = detect_circle_grid(image, board)
    assert bool(det.found[0]), det.reasons
    got = det.corners[0].numpy()
    raw = np.linalg.norm(got - truth, axis=-1)
    # in the board's own order (or its half-turn for a grid that looks the same turned)
    if not board.orientation_known and raw.max() > 2.0:
        got = got[::-1]
        raw = np.linalg.norm(got - truth, axis=-1)
    assert raw.max() < 1.2  # the uncorrected offset (the origin dot, twice the size, the most); the next dot is far
    bias = centre_bias(CAMERA, torch.tensor(rvec)[None], torch.tensor(tvec)[None], board.object_points(),
                       board.dot_diameters() / 2)[0].numpy()
    fixed = np.linalg.norm(got - bias - truth, axis=-1)
    assert np.sqrt((fixed ** 2).mean()) < 0.25 * np.sqrt((raw ** 2).mean())
    assert fixed.max() < 0.03


def test_light_dots_on_dark():
    board = BOARDS["marked origin"]
    image, truth, _, _ = _view(board, seed=5, inverted=True)
    det = CircleGridDetector(board)(image, board.board_size)
    assert bool(det.found[0]) and "light dots" in det.reasons[0]
    assert np.abs(det.corners[0].numpy() - truth).max() < 1.2


def test_marked_origin_order_and_refusals():
    r, c = np.meshgrid(np.arange(3), np.arange(4), indexing="ij")
    pts = np.stack([c.ravel() * 10.0, r.ravel() * 10.0], -1)
    areas = np.ones(12)
    perm, _ = order_marked_origin(pts, areas, (4, 3))
    assert perm is None
    areas[5] = 4.0  # an inner dot: not at a corner
    perm, why = order_marked_origin(pts, areas, (4, 3))
    assert perm is None and "corner" in why
    areas = np.ones(12)
    areas[3] = 4.0  # top right of the image: x runs left, y down
    perm, _ = order_marked_origin(pts, areas, (4, 3))
    assert pts[perm][1].tolist() == [20.0, 0.0] or pts[perm][1].tolist() == [30.0, 10.0]
    x, y = pts[perm][1] - pts[perm][0], pts[perm][4] - pts[perm][0]
    assert x[0] * y[1] - x[1] * y[0] < 0


def test_grid_object_points_and_shape_errors():
    g = CircleGrid(4, 11, 0.02, asymmetric=True)
    assert torch.equal(grid_object_points(g, (4, 11), 1.0), g.object_points())
    with pytest.raises(ValueError):
        CircleGrid(4, 11, 0.02, asymmetric=True, marked_origin=True)
    with pytest.raises(ValueError):
        CircleGridDetector(g)(torch.zeros(1, 1, 32, 32), (11, 4))
    assert g.orientation_known and not CircleGrid(4, 10, 0.02, asymmetric=True).orientation_known


def test_correct_centres_with_a_given_camera():
    board = BOARDS["symmetric"]
    image, truth, _, _ = _view(board, seed=11, tilt=60.0)
    det = detect_circle_grid(image, board)
    got = det.corners[0]
    if np.abs(got.numpy() - truth).max() > 2.0:
        got = got.flip(0)
    fixed = correct_centres(got[None], torch.ones(1, board.num_corners, dtype=torch.bool), CAMERA,
                            board.object_points(), board.dot_diameters() / 2)[0]
    before = np.linalg.norm(got.numpy() - truth, axis=-1).mean()
    after = np.linalg.norm(fixed.numpy() - truth, axis=-1).mean()
    assert after < 0.3 * before
