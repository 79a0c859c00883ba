from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.modules.detection.base import DetectionResult, Fallbacks
from ccs_kornia.modules.detection.enhanced_copies import UPSCALE
from ccs_kornia.modules.detection.learned.learned_detector import DISPUTED_PX, LearnedChessboardDetector

BOARD = (3, 2)
GRID = torch.tensor([[10.0 + 8 * i, 12.0 + 8 * j] for j in range(2) for i in range(3)])


@pytest.fixture(scope="module")
def detector():
    return LearnedChessboardDetector()


def _staged(det, monkeypatch, boards):
    """``det`` whose looks are stubs: ``boards(image (1, 1, H, W)) -> corners (N, 2) or None`` per call."""
    calls = []

    def detect(images, board_size, fallbacks):
        calls.append((tuple(images.shape[-2:]), float(images.max()), fallbacks))
        got = boards(images)
        if got is None:
            return DetectionResult(torch.zeros(1, 6, 2), torch.zeros(1, dtype=torch.bool), ["board not found"])
        return DetectionResult(got[None].clone().float(), torch.ones(1, dtype=torch.bool), ["learned"])

    monkeypatch.setattr(det, "_detect", detect)
    monkeypatch.setattr(det, "_grid_checks", lambda images, out, board_size: out)
    return calls


def test_a_dim_view_found_on_the_enlarged_copy_in_the_image_pixels(detector, monkeypatch):
    dim = torch.rand(1, 1, 24, 40) * 0.1  # a few grey levels: only the copies span the range
    calls = _staged(detector, monkeypatch,
                    lambda x: (GRID + 0.5) * UPSCALE - 0.5 if x.shape[-1] == 40 * UPSCALE else None)
    out = detector(dim, BOARD)
    assert bool(out.found[0]) and torch.allclose(out.corners[0], GRID) and "enhanced copy x2" in out.reasons[0]
    # the image, then its three copies (stretched, sharpened: the full range; enlarged), none of them again
    assert [c[0] for c in calls] == [(24, 40), (24, 40), (24, 40), (48, 80)]
    assert calls[0][1] <= 0.1 and all(c[1] > 0.9 for c in calls[1:])
    assert all(not c[2].copies and not c[2].foreshortened and c[2].opencv for c in calls[1:])


def test_a_whole_board_skips_the_copies_and_a_call_can_switch_them_off(detector, monkeypatch):
    calls = _staged(detector, monkeypatch, lambda x: GRID)
    assert bool(detector(torch.rand(1, 1, 24, 40), BOARD).found[0]) and len(calls) == 1
    calls = _staged(detector, monkeypatch, lambda x: None)
    assert not bool(detector(torch.rand(1, 1, 24, 40), BOARD, Fallbacks(copies=False)).found[0]) and len(calls) == 1


def test_a_copy_board_in_the_image_board_ordering_its_disputed_corners_left_out(detector, monkeypatch):
    image = torch.rand(1, 1, 24, 40)
    partial = GRID.clone()
    partial[[0, 5]] = float("nan")  # the image's board lacks two corners
    disputed = GRID.clone()
    disputed[2] += torch.tensor([0.0, 2 * DISPUTED_PX])  # the copy puts one of its others elsewhere
    copy_board = disputed.reshape(2, 3, 2).flip(0, 1).reshape(-1, 2)  # and names them in the reversed order
    _staged(detector, monkeypatch, lambda x: partial if x.max() < 1.0 else copy_board)
    out = detector(image, BOARD)
    want = GRID.clone()
    want[2] = float("nan")
    assert bool(out.found[0]) and torch.allclose(out.corners[0], want, equal_nan=True)
    # a copy that measures no more corners than the image's board leaves it as it is
    _staged(detector, monkeypatch, lambda x: partial if x.max() < 1.0 else partial)
    assert math.isnan(float(detector(image, BOARD).corners[0, 0, 0]))
