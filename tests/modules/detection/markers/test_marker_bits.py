"""Markers read on a rectified patch: the board's codes as OpenCV draws them, their orientations against OpenCV's
corner order, blurred templates where hard bits fail, codes a mirror makes identical."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ccs_kornia.modules.detection.boards import aruco_dictionary
from ccs_kornia.modules.detection.markers.marker_bits import (
    ORIENTATIONS,
    CodeTemplates,
    MarkerCodes,
    read_bits,
    sample_cells,
)

CODES = MarkerCodes.of("DICT_6X6_250", range(12), 1)
TEMPLATES = CodeTemplates(CODES)


def test_codes_are_opencvs():
    d = aruco_dictionary("DICT_6X6_250")
    img = d.generateImageMarker(5, 8)  # one pixel per cell, the border included
    assert np.array_equal(CODES.codes[5], (img[1:-1, 1:-1] > 128).astype(np.uint8))
    assert CODES.codes.shape == (12, 6, 6) and CODES.ids.tolist() == list(range(12))
    # below half the smallest distance between two codes turned any way
    distances = [CODES.distances(CODES.codes[k])[:4] for k in range(12)]
    smallest = min(int(np.delete(dd.reshape(-1), k).min()) for k, dd in enumerate(distances))
    assert 0 < 2 * CODES.errors < smallest


def _marker_view(mid: int, orientation: int, blur: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Marker ``mid`` (80 px, a white ring of 40 px) turned into ``orientation``: the image and the homography of
    its unit frame (the square's own, unturned) to the image."""
    d = aruco_dictionary("DICT_6X6_250")
    marker = d.generateImageMarker(mid, 80)
    t = ORIENTATIONS[orientation].astype(np.float64)
    # the code's frame point m shows at the square's frame point t (m - 0.5) + 0.5
    a = np.eye(3)
    a[:2, :2] = t
    a[:2, 2] = 0.5 - t @ np.array([0.5, 0.5])
    to_px = np.array([[80.0, 0, 39.5], [0, 80.0, 39.5], [0, 0, 1]])
    warp = to_px @ a @ np.linalg.inv(np.array([[80.0, 0, -0.5], [0, 80.0, -0.5], [0, 0, 1]]))
    img = np.full((160, 160), 255, np.uint8)
    img = cv2.warpPerspective(marker, warp, (160, 160), dst=img, borderMode=cv2.BORDER_TRANSPARENT,
                              flags=cv2.INTER_NEAREST)
    if blur:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    return img, to_px


@pytest.mark.parametrize("orientation", range(8))
def test_every_orientation_is_named_and_its_corners_are_opencvs(orientation):
    img, to_px = _marker_view(7, orientation)
    scores = TEMPLATES.scores(TEMPLATES.sample(img.astype(np.float32), to_px))
    assert TEMPLATES.best(scores) == (orientation, 7)
    assert TEMPLATES.agrees(scores, orientation, 7) and not TEMPLATES.disputes(scores, orientation, 7)
    assert TEMPLATES.disputes(scores, orientation, 3) and not TEMPLATES.agrees(scores, orientation, 3)
    # the hard bits say the same
    read = read_bits(sample_cells(img.astype(np.float32), to_px, 8), 1)
    assert read.readable and CODES.distances(read.bits)[orientation, 7] == 0
    if orientation < 4:  # OpenCV decodes a marker seen from its front: its first corner is the code's top left
        corners, ids, _ = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_6X6_250")).detectMarkers(img)
        assert ids.reshape(-1).tolist() == [7]
        frame = CODES.corners_in_frame(orientation)
        expected = (np.c_[frame, np.ones(4)] @ to_px.T)[:, :2]
        assert np.abs(corners[0].reshape(4, 2) - expected).max() < 1.5


def test_blur_wider_than_a_bit_still_names_the_code():
    img, to_px = _marker_view(9, 2, blur=14.0)  # a bit is 10 px
    patch = TEMPLATES.sample(img.astype(np.float32), to_px)
    assert TEMPLATES.best(TEMPLATES.scores(patch)) == (2, 9)
    read = read_bits(sample_cells(img.astype(np.float32), to_px, 8), 1)
    assert CODES.distances(read.bits)[2, 9] > CODES.errors  # the hard bits are lost
    inverted = TEMPLATES.scores(-patch)  # the wrong polarity names nothing
    assert TEMPLATES.best(inverted) is None or inverted.max() < TEMPLATES.scores(patch).max()


def test_codes_a_mirror_makes_identical_never_dispute_each_other():
    codes = MarkerCodes.of("DICT_4X4_1000", range(10), 1)
    t = CodeTemplates(codes)
    pairs = [(o, k, k2) for o, k, o2, k2 in np.argwhere(t.identical) if o2 == 0 and (o, k) != (0, k2)]
    assert pairs  # a mirrored 4x4 code is another code of the board
    o, k, k2 = (int(v) for v in pairs[0])
    assert o >= 4  # a mirror, not a turn
    scores = t.scores(t.draw(codes.codes[k2], 0.3))  # code k2 as read, or code k mirrored: one image
    for orientation, code in ((0, k2), (o, k)):
        assert t.agrees(scores, orientation, code) and not t.disputes(scores, orientation, code)


def test_blank_patches_are_not_readable():
    flat = np.full((10, 10), 0.5)
    assert not read_bits(flat, 1).readable
    assert not read_bits(np.full((10, 10), np.nan), 1).readable
    assert TEMPLATES.best(TEMPLATES.scores(np.full((40, 40), 100.0, np.float32))) is None
