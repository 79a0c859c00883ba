"""The lattice path of marker boards: every corner of the network's lattice named by the few markers that can be read.

Zero wrong ids where one or two markers decode (the others painted over): lattices symmetric under a half turn,
mirrored and inverted prints, boards cut by the frame, a marker that disputes the others; strong blur that OpenCV's
detector cannot read; both boards; the merge of the two paths.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard
from ccs_kornia.modules.detection.markers.aprilgrid import aprilgrid_paths, board_tags
from ccs_kornia.modules.detection.markers.charuco import (
    board_markers,
    charuco_paths,
    detect_charuco,
)
from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths

CHARUCO = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250", legacy=False)
SYMMETRIC = CharucoBoard(5, 5, 0.04, 0.02, "DICT_6X6_250", legacy=False)  # 4 x 4 corners, 5 x 5 squares
GRID = AprilGrid(5, 5, 0.05, 0.3)


def _view(board, keep: set[int] | None, homography: np.ndarray, size=(640, 480), blur: float = 0.0,
          paint: dict[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A ``uint8`` view of ``board`` through ``homography`` (from the texture's pixels to the image) and the true
    corners ``(N, 2)`` (NaN outside the image). Markers not in ``keep`` are painted over (a ChArUco marker with the
    white of its square, a tag's bits scrambled); ``paint``: marker id -> the id whose code is
    drawn in its place."""
    if isinstance(board, CharucoBoard):
        art, a = board.texture(100)
        where = board_markers(board, False)
        unit = float(board.square)
    else:
        art, a = board.texture(10)
        where = board_tags(board)
        unit = float(board.tag_size)
    art = art.copy()
    original = art.copy()
    rng = np.random.default_rng(0)
    for mid, corners in where.items():
        quad = (np.c_[corners * unit, np.ones(4)] @ a.T).astype(np.float32)
        if keep is not None and mid not in keep:
            lo, hi = quad.min(0), quad.max(0)
            if isinstance(board, CharucoBoard):  # the marker painted over: a plain white square
                x0, y0 = np.floor(lo - 0.02 * (hi - lo)).astype(int)
                x1, y1 = np.ceil(hi + 0.02 * (hi - lo)).astype(int)
                art[y0:y1 + 1, x0:x1 + 1] = 255
            else:  # a tag's bits scrambled, its black border kept (the corners are the border's)
                x0, y0 = np.rint(lo + 0.2 * (hi - lo)).astype(int)
                x1, y1 = np.rint(hi - 0.2 * (hi - lo)).astype(int)
                bits = (rng.random((6, 6)) < 0.5).astype(np.uint8) * 255
                art[y0:y1, x0:x1] = cv2.resize(bits, (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
        if paint and mid in paint:  # another marker's code in this marker's place, same orientation
            src = (np.c_[where[paint[mid]] * unit, np.ones(4)] @ a.T).astype(np.float32)
            h = cv2.getPerspectiveTransform(src, quad)
            warped = cv2.warpPerspective(original, h, art.shape[::-1], flags=cv2.INTER_NEAREST)
            mask = np.zeros(art.shape, np.uint8)
            cv2.fillConvexPoly(mask, np.rint(quad).astype(np.int32), 1)
            art[mask > 0] = warped[mask > 0]
    obj = board.object_points().numpy()[:, :2]
    tex = np.c_[obj, np.ones(len(obj))] @ a.T
    scale = np.sqrt(abs(np.linalg.det(homography[:2, :2])))
    smooth = cv2.GaussianBlur(art.astype(np.float32), (0, 0), max(0.5 / scale, 0.3))
    img = cv2.warpPerspective(smooth, homography, size, flags=cv2.INTER_LINEAR, borderValue=128.0)
    if blur:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    truth = cv2.perspectiveTransform(tex[None].astype(np.float64), homography)[0]
    w, h = size
    truth[(truth[:, 0] < 0) | (truth[:, 1] < 0) | (truth[:, 0] > w - 1) | (truth[:, 1] > h - 1)] = np.nan
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), truth


def _homography(scale: float, angle_deg: float = 0.0, shift=(60.0, 40.0), tilt: float = 2e-4) -> np.ndarray:
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    h = np.array([[scale * c, -scale * s, shift[0]], [scale * s, scale * c, shift[1]], [tilt, 0.5 * tilt, 1.0]])
    return h


def _tensor(*images: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.stack(images)).float()[:, None] / 255.0


def _check(corners: torch.Tensor, truth: np.ndarray) -> tuple[int, int]:
    """(right, wrong) corners of one view: wrong = more than 3 px from its id's true corner, or not in the image."""
    c = corners.double().numpy()
    seen = np.isfinite(c).all(-1)
    err = np.linalg.norm(c - np.nan_to_num(truth, nan=-1e9), axis=-1)
    wrong = seen & (~np.isfinite(truth).all(-1) | (err > 3.0))
    return int((seen & ~wrong).sum()), int(wrong.sum())


def _near_centre(board, truth: np.ndarray, count: int) -> set[int]:
    """The ``count`` markers nearest the middle of the view (their ids)."""
    where = board_markers(board, False) if isinstance(board, CharucoBoard) else board_tags(board)
    obj = board.object_points().numpy()[:, :2]
    unit = float(board.square) if isinstance(board, CharucoBoard) else float(board.tag_size)
    centre = obj.mean(0) / unit
    return set(sorted(where, key=lambda m: np.linalg.norm(where[m].mean(0) - centre))[:count])


@pytest.mark.parametrize("markers", [1, 2])
def test_one_or_two_markers_name_every_corner(markers):
    full, truth = _view(CHARUCO, None, _homography(0.45))
    keep = _near_centre(CHARUCO, truth, markers)
    image, truth = _view(CHARUCO, keep, _homography(0.45))
    out = charuco_paths(_tensor(image), CHARUCO)
    right, wrong = _check(out[MarkerPaths.BOTH].corners[0], truth)
    assert wrong == 0 and right == int(np.isfinite(truth).all(-1).sum()) == 24
    # the marker path needs two consistent markers and places only the corners beside them
    assert int(out[MarkerPaths.MARKERS].valid.sum()) < 24
    assert "lattice:" in out[MarkerPaths.BOTH].reasons[0]


@pytest.mark.parametrize("turn", [0.0, 90.0, 180.0, 270.0])
def test_a_half_turn_symmetric_lattice_takes_its_turn_from_the_markers(turn):
    # 4 x 4 corners: the bare lattice is the same under every quarter turn; one marker's code fixes it
    shift = {0.0: (150.0, 60.0), 90.0: (480.0, 60.0), 180.0: (480.0, 420.0), 270.0: (150.0, 420.0)}[turn]
    h = _homography(0.6, turn, shift, tilt=0.0)
    _, truth = _view(SYMMETRIC, None, h)
    keep = _near_centre(SYMMETRIC, truth, 1)
    image, truth = _view(SYMMETRIC, keep, h)
    assert np.isfinite(truth).all()
    out = detect_charuco(_tensor(image), SYMMETRIC, paths=MarkerPaths.LATTICE)
    right, wrong = _check(out.corners[0], truth)
    assert wrong == 0 and right == 16


@pytest.mark.parametrize("variant", ["inverted", "mirrored", "mirrored inverted"])
def test_mirrored_and_inverted_prints_with_two_markers(variant):
    h = _homography(0.45)
    _, truth = _view(CHARUCO, None, h)
    keep = _near_centre(CHARUCO, truth, 2)
    image, truth = _view(CHARUCO, keep, h)
    if variant.startswith("mirrored"):
        image = np.ascontiguousarray(image[:, ::-1])
        truth = truth.copy()
        truth[:, 0] = image.shape[1] - 1 - truth[:, 0]
    if variant.endswith("inverted"):
        image = 255 - image
    out = detect_charuco(_tensor(image), CHARUCO)
    right, wrong = _check(out.corners[0], truth)
    assert wrong == 0 and right == 24
    assert variant in out.reasons[0] or "lattice" in out.reasons[0]


def _marker_centres(board: CharucoBoard, homography: np.ndarray) -> dict[int, np.ndarray]:
    """Each marker's centre in the view (px)."""
    a = board.texture(100)[1]
    where = board_markers(board, False)
    centres = np.stack([c.mean(0) * float(board.square) for c in where.values()])
    tex = np.c_[centres, np.ones(len(centres))] @ a.T
    img = cv2.perspectiveTransform(tex[None].astype(np.float64), homography)[0]
    return dict(zip(where, img))


def test_a_board_cut_by_the_frame_names_the_corners_it_shows():
    h = _homography(0.55, 10.0, (470.0, 40.0))  # the board's right part leaves the image
    _, truth = _view(CHARUCO, None, h)
    visible = int(np.isfinite(truth).all(-1).sum())
    assert 6 < visible < 24
    inside = [m for m, c in _marker_centres(CHARUCO, h).items() if 40 < c[0] < 600 and 40 < c[1] < 440]
    image, truth = _view(CHARUCO, set(inside[:1]), h)
    out = detect_charuco(_tensor(image), CHARUCO)
    right, wrong = _check(out.corners[0], truth)
    assert wrong == 0 and right >= visible - 2  # corners whose refinement window leaves the image are dropped


def test_a_marker_that_disputes_the_lattice_loses_its_corners_not_the_board():
    h = _homography(0.45)
    _, truth = _view(CHARUCO, None, h)
    # one square shows another marker's code (a misprint, or a marker of another board taped on)
    image, truth = _view(CHARUCO, None, h, blur=2.5, paint={8: 3})
    out = detect_charuco(_tensor(image), CHARUCO, paths=MarkerPaths.LATTICE)
    right, wrong = _check(out.corners[0], truth)
    assert wrong == 0 and 16 <= right < 24  # the disputed square's corners are dropped
    where = board_markers(CHARUCO, False)[8].mean(0)  # the four corners around marker 8
    around = [r * 4 + c for r in range(6) for c in range(4) if np.abs(np.array([c + 1, r + 1]) - where).max() < 1]
    assert not out.corners[0, around].isfinite().all(-1).any()


def test_strong_blur_that_opencv_cannot_read():
    image, truth = _view(CHARUCO, None, _homography(0.45), blur=3.0)
    out = charuco_paths(_tensor(image), CHARUCO)
    assert int(out[MarkerPaths.MARKERS].valid.sum()) < 6
    right, wrong = _check(out[MarkerPaths.BOTH].corners[0], truth)
    assert wrong == 0 and right == 24


@pytest.mark.parametrize("variant", ["plain", "mirrored inverted"])
def test_aprilgrid_lattice_with_two_tags_and_blur(variant):
    h = _homography(0.58, 4.0, (80.0, 6.0), tilt=1e-4)
    _, truth = _view(GRID, None, h)
    keep = _near_centre(GRID, truth, 2)
    image, truth = _view(GRID, keep, h, blur=1.5)
    if variant.startswith("mirrored"):
        image = np.ascontiguousarray(255 - image[:, ::-1])
        truth = truth.copy()
        truth[:, 0] = image.shape[1] - 1 - truth[:, 0]
    out = aprilgrid_paths(_tensor(image), GRID)
    right, wrong = _check(out[MarkerPaths.BOTH].corners[0], truth)
    assert np.isfinite(truth).all()
    assert wrong == 0 and right >= 95
    assert int(out[MarkerPaths.MARKERS].valid.sum()) < right


def test_paths_are_checked():
    with pytest.raises(ValueError):
        detect_charuco(torch.zeros(1, 1, 32, 32), CHARUCO, paths="everything")
    out = charuco_paths(torch.zeros(2, 1, 64, 80), CHARUCO)
    assert set(out) == set(MarkerPaths)
    for res in out.values():
        assert res.corners.shape == (2, 24, 2) and res.found.tolist() == [False, False]
