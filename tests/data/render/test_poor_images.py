"""Real photographs made poor: each condition does what it says, seeded, and the corners move with the small one."""

from __future__ import annotations

import numpy as np
import pytest

from ccs_kornia.data.render.poor_images import POOR_CONDITIONS, make_poor, scale_points


def _board() -> np.ndarray:
    img = np.full((60, 80), 30, np.uint8)
    for r in range(6):
        for c in range(8):
            if (r + c) % 2:
                img[r * 10:(r + 1) * 10, c * 10:(c + 1) * 10] = 220
    return img


@pytest.mark.parametrize("condition", POOR_CONDITIONS)
def test_make_poor_is_seeded_and_keeps_the_type(condition):
    img = _board()
    a, s = make_poor(img, condition, np.random.default_rng(3))
    b, _ = make_poor(img, condition, np.random.default_rng(3))
    assert a.dtype == np.uint8 and np.array_equal(a, b)
    assert a.shape == ((24, 32) if condition == "small" else img.shape) and s == (0.4 if condition == "small" else 1.0)
    assert not np.array_equal(a, img) if condition != "small" else True


def test_make_poor_conditions():
    img = _board()
    rng = np.random.default_rng(0)
    dark, _ = make_poor(img, "dark", rng)
    assert abs(float(dark.mean()) - 0.12 * float(img.mean())) < 0.5
    assert 1.5 < float(np.std(dark[:10, :10].astype(float))) < 2.5  # the read noise on a flat square
    sensor, _ = make_poor(img, "dark sensor", rng)
    # shot noise grows with the light: the light squares are noisier than the dark ones
    assert np.std(sensor[:10, 10:20].astype(float)) > np.std(sensor[:10, :10].astype(float))
    blur, _ = make_poor(img, "blur", rng)
    assert blur[5, 9] > 40 and blur[5, 10] < 210  # the edge is spread over several pixels
    assert make_poor(img, "clean", rng)[0].tolist() == img.tolist()
    with pytest.raises(ValueError, match="Unknown condition"):
        make_poor(img, "fog", rng)
    with pytest.raises(ValueError, match="uint8"):
        make_poor(img.astype(float), "dark", rng)


def test_scale_points_follows_area_resize():
    # a 10-px square's corner (between pixels 9 and 10) lies between pixels 3 and 4 at 0.4
    assert scale_points(np.array([[9.5, 19.5]]), 0.4).tolist() == [[3.5, 7.5]]
