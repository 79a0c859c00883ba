"""A chessboard smeared by a straight motion blur: its corners refined where the blur is undone, and a board the
image does not give looked for on the deblurred copy."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.camera import intrinsics_matrix
from ccs_kornia.modules.detection.learned import learned_detector as ld
from ccs_kornia.modules.detection.motion_deblur import line_kernel

BOARD = (9, 6)


@pytest.fixture(scope="module")
def detector():
    return ld.LearnedChessboardDetector()


@pytest.fixture(scope="module")
def smeared():
    """A rendered 640x480 view and its copy smeared along a 15 px line (the direction that leaves a third of the
    corners without a saddle fit at full resolution), in 8-bit grey levels."""
    K = intrinsics_matrix(torch.tensor([600.0, 590.0, 318.0, 242.0]))
    s = make_calibration_set(K, BOARD, 0.025, (640, 480), 4, dist=torch.tensor([-0.2, 0.05, 0, 0, 0]),
                             condition="clean", seed=9_100_000)
    sharp = s.images[1, 0].double().numpy()
    blurred = cv2.filter2D(sharp, -1, line_kernel(15, 1.2), borderType=cv2.BORDER_REFLECT)
    x = torch.from_numpy(np.rint(blurred * 255.0) / 255.0).float()[None, None]
    return x, s.corners[1:2]


def test_corners_refined_where_the_motion_blur_is_undone(detector, smeared, monkeypatch):
    x, truth = smeared
    out = detector(x, BOARD)
    assert bool(out.found[0])
    found = out.corners[0].isfinite().all(-1)
    err = (out.corners[0] - truth[0]).norm(dim=-1)
    assert int(found.sum()) == 54 and float(err.mean()) < 0.05 and float(err.max()) < 0.2
    # the same view without the blur measured: the saddle fit fails across the smear and those corners are left out
    monkeypatch.setattr(ld, "motion_blur", lambda gray8: None)
    plain = detector(x, BOARD)
    assert int(plain.corners[0].isfinite().all(-1).sum()) < 45


def test_a_sharp_board_is_not_deblurred(detector, monkeypatch):
    K = intrinsics_matrix(torch.tensor([600.0, 590.0, 318.0, 242.0]))
    s = make_calibration_set(K, BOARD, 0.025, (640, 480), 1, condition="clean", seed=9_100_001)
    calls = []
    monkeypatch.setattr(ld, "motion_blur", lambda gray8: calls.append(gray8.shape))
    out = detector(s.images, BOARD)
    assert bool(out.found[0]) and bool(out.corners.isfinite().all()) and calls == []  # every saddle found: no look


def test_the_deblurred_copy_only_where_a_blur_is_measured(smeared):
    x, _ = smeared
    gray8 = np.rint(x[0, 0].numpy() * 255.0).astype(np.uint8)
    names = [name for name, _, _ in ld.chessboard_copies(gray8)]
    assert names == ["deblurred"]  # full contrast, 307,200 px: neither stretched nor enlarged
    copy_ = ld.chessboard_copies(gray8)[0][1]
    assert copy_.shape == gray8.shape and copy_.dtype == np.uint8
    # sharper across the smear: the grey levels' spread grows back towards the board's black and white
    assert float(copy_.std()) > float(gray8.std())
    rng = np.random.default_rng(0)
    assert ld.chessboard_copies(rng.integers(0, 256, (480, 640)).astype(np.uint8)) == []
