"""Names for a corner lattice: the naming every marker agrees on under perspective and in any orientation of the
lattice, OpenCV's markers as votes and disputes, and no naming where the markers do not decide."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.modules.detection.markers.charuco import charuco_lattice
from ccs_kornia.modules.detection.markers.lattice_names import (
    LatticeNaming,
    name_lattice,
)
from ccs_kornia.modules.detection.markers.marker_bits import ORIENTATIONS

BOARD = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250", legacy=False)
H = np.array([[0.42, 0.05, 90.0], [-0.04, 0.40, 50.0], [1.5e-4, 1e-4, 1.0]])


def _view(orientation: int = 0, blank: bool = False):
    """The board through ``H``, its inner corners as a lattice whose cells are the board's turned by
    ``orientation`` (``cells = D index + shift``): image, cells, points, the true index of each cell."""
    art, a = BOARD.texture(100)
    if blank:
        art = art.copy()
        art[art < 128] = 255
    img = cv2.warpPerspective(cv2.GaussianBlur(art, (0, 0), 1.0), H, (640, 480), borderValue=128).astype(np.float32)
    obj = BOARD.object_points().numpy()[:, :2]
    pts = cv2.perspectiveTransform((np.c_[obj, np.ones(len(obj))] @ a.T)[None], H)[0]
    index = np.stack([np.arange(24) % 4, np.arange(24) // 4], -1)
    d = ORIENTATIONS[orientation]
    cells = index @ d.T
    cells = cells - cells.min(0) + np.array([3, 1])
    return img, cells, pts, index


@pytest.mark.parametrize("orientation", range(8))
def test_the_naming_undoes_any_orientation_of_the_lattice(orientation):
    img, cells, pts, index = _view(orientation)
    if orientation >= 4:  # a mirrored lattice: the board seen from its back, so the view is mirrored too
        img = np.ascontiguousarray(img[:, ::-1])
        pts = pts.copy()
        pts[:, 0] = 639 - pts[:, 0]
    named = name_lattice(img, cells, pts, charuco_lattice(BOARD), [], float(BOARD.marker / BOARD.square))
    assert named.naming is not None and named.agree == 17 and named.dispute == 0 and named.runner_up == 0
    assert named.naming.mirrored == (orientation >= 4) and not named.naming.inverted
    assert bool(named.named.all()) and np.array_equal(named.index, index)
    assert np.allclose(named.naming.cells(named.index), cells)


def test_opencvs_markers_vote_and_dispute():
    img, cells, pts, _ = _view()
    lat = charuco_lattice(BOARD)
    where = lat.layouts[False]
    obj = where[8] * float(BOARD.square)  # marker 8's corners, where the board puts them (a square inside)
    a = BOARD.texture(100)[1]
    corners = cv2.perspectiveTransform((np.c_[obj, np.ones(4)] @ a.T)[None], H)[0]
    named = name_lattice(img, cells, pts, lat, [(corners, 8, False)], 0.5)
    assert named.agree == 17 and named.dispute == 0
    wrong = name_lattice(img, cells, pts, lat, [(corners, 3, False)], 0.5)  # decoded as another id: disputed
    assert wrong.naming is not None and wrong.dispute == 1 and len(wrong.disputed_cells) == 4
    assert not wrong.named.all() and wrong.named.sum() == 24 - 4


def test_no_markers_no_naming():
    img, cells, pts, _ = _view(blank=True)  # a plain chessboard
    named = name_lattice(img, cells, pts, charuco_lattice(BOARD), [], 0.5)
    assert named.naming is None and named.reason and not named.named.any()
    img, cells, pts, _ = _view()
    named = name_lattice(img, cells, pts, charuco_lattice(BOARD), [], 0.5, min_agree=18)
    assert named.naming is None and "at least 18" in named.reason
    assert name_lattice(img, cells[:3], pts[:3], charuco_lattice(BOARD), [], 0.5).reason == "no lattice"


def test_naming_maps_cells_both_ways():
    naming = LatticeNaming(((0, -1), (1, 0)), (3, 0), False, False)
    cells = np.array([[0, 0], [1, 2], [2, 1]])
    assert np.allclose(naming.cells(naming.index(cells)), cells) and not naming.mirrored
