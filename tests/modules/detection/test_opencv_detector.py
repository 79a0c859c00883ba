"""Tests of the detector interface and the OpenCV baseline detector."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.io.images import load_image_gray
from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.opencv_detector import OpenCVChessboardDetector

BOARD = (9, 6)
K = torch.tensor([[620.0, 0.0, 322.0], [0.0, 610.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


@pytest.fixture(scope="module")
def rendered():
    return make_calibration_set(
        K, BOARD, 0.025, (640, 480), num_views=4, dist=torch.tensor([-0.2, 0.05, 0.0, 0.0, 0.0], dtype=torch.float64),
        seed=5, supersample=2,
    )


@pytest.fixture(scope="module")
def detected(rendered):
    return OpenCVChessboardDetector()(rendered.images, BOARD)


@pytest.fixture(scope="module")
def real_dir() -> Path:
    return REAL_DATA


def test_interface_and_shapes(detected, rendered):
    assert isinstance(OpenCVChessboardDetector(), ChessboardDetector)
    assert isinstance(detected, DetectionResult)
    n = BOARD[0] * BOARD[1]
    assert detected.corners.shape == (4, n, 2) and detected.corners.dtype == torch.float32
    assert detected.found.shape == (4,) and detected.found.dtype == torch.bool
    assert detected.valid.shape == (4, n)
    assert detected.reasons is not None and len(detected.reasons) == 4


def test_matches_ground_truth(detected, rendered):
    assert bool(detected.found.all()), detected.reasons
    gt = rendered.corners.to(torch.float64)
    est = detected.corners.to(torch.float64)
    # the renderer's order exactly: these views are rolled by less than 90 degrees, where the OpenCV detector's
    # convention (first corner nearest the image's top-left, test_order_convention) agrees with the renderer's
    err = (est - gt).norm(dim=-1).mean(-1)
    assert float(err.max()) < 0.1, err
    # no systematic half-pixel shift
    assert float((est - gt).mean((0, 1)).abs().max()) < 0.03


def test_order_convention(detected):
    # of the two orderings of the same physical grid, the first corner is the one nearest the top-left
    first = detected.corners[:, 0].norm(dim=-1)
    last = detected.corners[:, -1].norm(dim=-1)
    assert bool((first <= last).all())


def test_no_board(rendered):
    det = OpenCVChessboardDetector(num_workers=1)
    noise = torch.rand(1, 1, 480, 640, generator=torch.Generator().manual_seed(0))
    blank = torch.full((1, 1, 480, 640), 0.5)
    out = det(torch.cat([noise, blank]), BOARD)
    assert out.found.tolist() == [False, False]
    assert float(out.corners.abs().max()) == 0.0
    assert all("not found" in r for r in out.reasons)


def test_sub_board_is_rejected(rendered):
    # asking for 8x6 on a 9x6 board: the classic detector finds a sub-board; it must be rejected
    out = OpenCVChessboardDetector()(rendered.images[:2], (8, 6))
    assert not bool(out.found.any()), out.reasons


def test_batched_equals_single(rendered, detected):
    det = OpenCVChessboardDetector(num_workers=1)
    single = det(rendered.images[1:2], BOARD)
    torch.testing.assert_close(single.corners[0], detected.corners[1])


def test_input_validation():
    det = OpenCVChessboardDetector()
    with pytest.raises(ValueError, match=r"\(B, 1, H, W\)"):
        det(torch.zeros(1, 3, 32, 32), BOARD)
    with pytest.raises(ValueError, match="board_size"):
        det(torch.zeros(1, 1, 32, 32), (1, 6))


def test_real_false_positive_and_sub_board(real_dir):
    folder = real_dir / "opencv_left"
    if not folder.is_dir():
        pytest.skip(f"real data not present at {folder}")
    det = OpenCVChessboardDetector(num_workers=1)
    left13, _ = load_image_gray(folder / "left13.jpg")
    left02, _ = load_image_gray(folder / "left02.jpg")
    # the classic detector reports a visibly wrong 10x6 grid on left13 and an 8x6 sub-board on left02
    corners, reason = det.detect_one(left13, (10, 6))
    assert corners is None and "rejected" in reason
    corners, reason = det.detect_one(left02, (8, 6))
    assert corners is None and "continues" in reason
    corners, reason = det.detect_one(left02, (9, 6))
    assert corners is not None and reason == "classic"


def test_tiny_images_are_not_found_with_a_reason():
    from ccs_kornia.modules.detection.opencv_detector import OpenCVChessboardDetector

    out = OpenCVChessboardDetector()(torch.rand(2, 1, 8, 8), (9, 6))
    assert not bool(out.found.any()) and all("too small" in r for r in out.reasons)
