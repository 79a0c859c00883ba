from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.modules.detection.motion_deblur import (
    deblur_motion,
    line_kernel,
    motion_blur,
)


def _texture(size: int = 320, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (size, size)).astype(np.float32), (0, 0), 0.7)


def test_line_kernel_shape_and_sum():
    for length in (5, 8, 15):
        k = line_kernel(length, 0.3)
        assert k.shape == (length | 1, length | 1)
        assert math.isclose(float(k.sum()), 1.0, rel_tol=1e-6)


@pytest.mark.parametrize(("length", "angle"), [(9, 0.0), (15, 0.6), (15, 2.2), (21, 1.57)])
def test_blur_measured(length, angle):
    sharp = _texture()
    blurred = cv2.filter2D(sharp, -1, line_kernel(length, angle), borderType=cv2.BORDER_REFLECT)
    got = motion_blur(np.clip(blurred, 0, 255).astype(np.uint8))
    assert got is not None
    assert abs(got[0] - length) <= 1
    assert abs((got[1] - angle + math.pi / 2) % math.pi - math.pi / 2) < 0.08


def test_no_blur_where_there_is_none():
    sharp = np.clip(_texture(), 0, 255).astype(np.uint8)
    assert motion_blur(sharp) is None
    # a blur alike in every direction is not a line
    assert motion_blur(cv2.GaussianBlur(sharp, (0, 0), 2.5)) is None
    assert motion_blur(np.zeros((32, 32), np.uint8)) is None  # too small for the lengths searched


def test_deblur_undoes_the_blur():
    sharp = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250").render(40, margin=20)
    blurred = cv2.filter2D(sharp, -1, line_kernel(15, 0.6), borderType=cv2.BORDER_WRAP)
    out = deblur_motion(blurred, 15, 0.6)
    assert out.shape == sharp.shape and out.dtype == np.uint8
    inner = (slice(20, -20), slice(20, -20))
    before = np.abs(blurred.astype(float) - sharp)[inner].mean()
    after = np.abs(out.astype(float) - sharp)[inner].mean()
    assert after < 0.5 * before


def test_deblur_moves_no_edge():
    # the line is symmetric about its centre: a step's position survives blurring and undoing it
    step = np.zeros((64, 64), np.uint8)
    step[:, 32:] = 200
    out = deblur_motion(cv2.filter2D(step, -1, line_kernel(9, 0.0), borderType=cv2.BORDER_REFLECT), 9, 0.0)
    row = out[32, 16:48].astype(float)
    assert int(np.argmax(np.diff(row))) + 16 in (31, 32)


def test_exceptions():
    with pytest.raises(ValueError, match="grey image"):
        motion_blur(np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match="grey image"):
        deblur_motion(np.zeros((8, 8, 3), np.uint8), 5, 0.0)
    with pytest.raises(ValueError, match="length"):
        deblur_motion(np.zeros((8, 8), np.uint8), 0, 0.0)
