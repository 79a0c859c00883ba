from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.modules.detection.gaussian_deblur import (
    MIN_SIGMA,
    deblur_gaussian,
    gaussian_blur_sigma,
)
from ccs_kornia.modules.detection.markers import charuco
from ccs_kornia.modules.detection.markers.charuco import charuco_detector, layout_fits
from ccs_kornia.modules.detection.markers.marker_board import decode_markers

#: a 4x4-bit board whose markers take three quarters of their square: the narrow margin a blur closes
_BOARD = CharucoBoard(4, 5, 0.054, 0.0405, "DICT_4X4_1000")


def _blurred_board(sigma: float, square: int = 30) -> np.ndarray:
    img = _BOARD.render(square, margin=40).astype(np.float32) * 0.8 + 25.0
    if sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("sigma", [2.0, 2.5, 3.0, 4.0])
def test_blur_measured(sigma):
    got = gaussian_blur_sigma(_blurred_board(sigma))
    assert abs(got - sigma) < 0.25


def test_sharp_image_measures_below_the_threshold():
    assert gaussian_blur_sigma(_blurred_board(0.0)) < MIN_SIGMA
    assert gaussian_blur_sigma(_blurred_board(1.0)) < MIN_SIGMA


def test_no_edge_no_measure():
    assert math.isnan(gaussian_blur_sigma(np.full((64, 64), 128, np.uint8)))


def test_deblurred_copy_reads_the_markers():
    blurred = _blurred_board(2.5)
    det = charuco_detector(_BOARD.dictionary)
    assert len(decode_markers(blurred, det)[1]) == 0
    ids = decode_markers(deblur_gaussian(blurred, gaussian_blur_sigma(blurred)), det)[1]
    assert sorted(ids.tolist()) == list(range(10))


def test_deblur_keeps_shape_and_edges_in_place():
    img = np.zeros((80, 120), np.float32)
    img[:, 60:] = 200
    blurred = cv2.GaussianBlur(img, (0, 0), 2.5).astype(np.uint8)
    sharp = deblur_gaussian(blurred, 2.5)
    assert sharp.shape == blurred.shape and sharp.dtype == np.uint8
    row = sharp[40].astype(np.float64)
    # the step's half-height crossing stays between px 59 and 60
    assert row[59] < 100 < row[60]
    # steeper than the blurred step
    assert row[62] - row[57] > float(blurred[40, 62]) - float(blurred[40, 57])


def test_bad_inputs():
    with pytest.raises(ValueError):
        gaussian_blur_sigma(np.zeros((8, 8), np.float32))
    with pytest.raises(ValueError):
        deblur_gaussian(np.zeros((2, 8, 8), np.uint8), 2.0)
    with pytest.raises(ValueError):
        deblur_gaussian(np.zeros((8, 8), np.uint8), 0.0)


def test_layout_fits_reads_a_blurred_board_on_the_deblurred_copy(monkeypatch):
    blurred = _blurred_board(2.5)
    fit = layout_fits(blurred, _BOARD)[False]
    assert sorted(fit.ids.tolist()) == list(range(10))
    assert fit.defocus is not None and abs(fit.defocus - 2.5) < 0.25
    # without the Gaussian copy the other copies read fewer of them
    monkeypatch.setattr(charuco, "MIN_SIGMA", math.inf)
    without = layout_fits(blurred, _BOARD)[False]
    assert len(without.ids) < len(fit.ids) and without.defocus is None


def test_sharp_board_takes_no_deblurred_copy():
    fit = layout_fits(_blurred_board(0.0), _BOARD)[False]
    assert len(fit.ids) == 10 and fit.defocus is None


@pytest.mark.parametrize("angle", [0.0, math.pi / 2])
def test_blur_across_a_motion_line_measured_in_its_direction(angle):
    from ccs_kornia.modules.detection.motion_deblur import line_kernel

    # the board's edges run along the image's axes: a line along one blurs the edges across it only
    sharp = _blurred_board(0.0, square=40).astype(np.float32)
    smeared = cv2.filter2D(sharp, -1, line_kernel(15, angle), borderType=cv2.BORDER_REFLECT)
    smeared = np.clip(np.rint(smeared), 0, 255).astype(np.uint8)
    across = gaussian_blur_sigma(smeared, angle)
    along = gaussian_blur_sigma(smeared, angle + math.pi / 2)
    assert across >= MIN_SIGMA > along
    assert gaussian_blur_sigma(sharp.astype(np.uint8), angle) < MIN_SIGMA
