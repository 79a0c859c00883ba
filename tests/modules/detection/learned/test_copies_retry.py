from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.modules.detection.base import DetectionResult, Fallbacks
from ccs_kornia.modules.detection.enhanced_copies import UPSCALE
from ccs_kornia.modules.detection.learned.learned_detector import (
    DISPUTED_PX,
    LearnedChessboardDetector,
)

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

    def refine(full, pts, board_size, factor, radius_factor=None):  # the copy's corners refined on the image
        calls.append(("refined", tuple(full.shape[-2:]), factor))
        return pts

    monkeypatch.setattr(det, "_refine_at_full_size", refine)
    return calls


def test_a_dim_view_found_on_the_enlarged_copy_in_the_image_pixels(detector, monkeypatch):
    dim = torch.rand(1, 1, 24, 40) * 0.1  # a few grey levels: only the copies span the range
    calls = _staged(detector, monkeypatch,
                    lambda x: (GRID + 0.5) * UPSCALE - 0.5 if x.shape[-1] == 40 * UPSCALE else None)
    out = detector(dim, BOARD)
    assert bool(out.found[0]) and torch.allclose(out.corners[0], GRID) and "enhanced copy x2" in out.reasons[0]
    # the image, then its three copies (stretched, sharpened: the full range; enlarged), none of them again
    assert [c[0] for c in calls] == [(24, 40), (24, 40), (24, 40), (48, 80), "refined"]
    assert calls[-1] == ("refined", (24, 40), 1.0)  # on the image itself
    looks = calls[:-1]
    assert looks[0][1] <= 0.1 and all(c[1] > 0.9 for c in looks[1:])
    assert all(not c[2].copies and not c[2].foreshortened and c[2].opencv for c in looks[1:])


def test_a_whole_board_skips_the_copies_and_a_call_can_switch_them_off(detector, monkeypatch):
    calls = _staged(detector, monkeypatch, lambda x: GRID)
    assert bool(detector(torch.rand(1, 1, 24, 40), BOARD).found[0]) and len(calls) == 1
    calls = _staged(detector, monkeypatch, lambda x: None)
    assert not bool(detector(torch.rand(1, 1, 24, 40), BOARD, Fallbacks(copies=False)).found[0]) and len(calls) == 1


def test_a_copy_board_adds_the_corners_the_image_board_lacks_unless_it_disputes_one(detector, monkeypatch):
    image = torch.rand(1, 1, 24, 40)
    partial = GRID.clone()
    partial[[0, 5]] = float("nan")  # the image's board lacks two corners
    near = GRID + 0.3 * DISPUTED_PX  # the copy's corners: near the image's, named in the reversed order
    reversed_ = near.reshape(2, 3, 2).flip(0, 1).reshape(-1, 2)
    _staged(detector, monkeypatch, lambda x: partial if x.max() < 1.0 else reversed_)
    out = detector(image, BOARD)
    want = GRID.clone()
    want[[0, 5]] = near[[0, 5]]  # the image's own corners stay as they are
    assert bool(out.found[0]) and torch.allclose(out.corners[0], want)
    # a copy that places one of the image's corners elsewhere disputes its ids: the image's board stays as it is
    disputed = GRID.clone()
    disputed[2] += torch.tensor([0.0, 2 * DISPUTED_PX])
    _staged(detector, monkeypatch, lambda x: partial if x.max() < 1.0 else disputed)
    assert torch.allclose(detector(image, BOARD).corners[0], partial, equal_nan=True)
    # and one that measures no more corners than the image's board leaves it as it is too
    _staged(detector, monkeypatch, lambda x: partial)
    assert math.isnan(float(detector(image, BOARD).corners[0, 0, 0]))
