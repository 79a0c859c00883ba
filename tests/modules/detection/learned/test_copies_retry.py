from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.base import DetectionResult, Fallbacks
from ccs_kornia.modules.detection.enhanced_copies import UPSCALE
from ccs_kornia.modules.detection.learned.learned_detector import (
    DISPUTED_PX,
    SMALL_PIXELS,
    LearnedChessboardDetector,
)

BOARD = (3, 2)
GRID = torch.tensor([[10.0 + 8 * i, 12.0 + 8 * j] for j in range(2) for i in range(3)])


@pytest.fixture(scope="module")
def detector():
    return LearnedChessboardDetector()


def _staged(det, monkeypatch, boards, refine=None):
    """``det`` whose looks are stubs: ``boards(image (1, 1, H, W)) -> corners (N, 2) or None`` per call; the image's
    saddle fit ``refine(corners (N, 2)) -> corners`` (default: leaves them as they are)."""
    calls = []

    def detect(images, board_size, fallbacks):
        calls.append((tuple(images.shape[-2:]), float(images.max()), fallbacks))
        got = boards(images)
        if got is None:
            return DetectionResult(torch.zeros(1, 6, 2), torch.zeros(1, dtype=torch.bool), ["board not found"])
        return DetectionResult(got[None].clone().float(), torch.ones(1, dtype=torch.bool), ["learned"])

    monkeypatch.setattr(det, "_detect", detect)
    monkeypatch.setattr(det, "_grid_checks", lambda images, out, board_size: out)

    def refined(full, pts, board_size, factor, radius_factor=None):  # the copy's corners refined on the image
        calls.append(("refined", tuple(full.shape[-2:]), factor))
        return pts if refine is None else refine(pts[0])[None]

    monkeypatch.setattr(det, "_refine_at_full_size", refined)
    return calls


def test_a_dim_view_found_on_the_enlarged_copy_in_the_image_pixels(detector, monkeypatch):
    dim = torch.rand(1, 1, 24, 40) * 0.1  # a few grey levels: only the copies span the range
    calls = _staged(detector, monkeypatch,
                    lambda x: (GRID + 0.5) * UPSCALE - 0.5 if x.shape[-1] == 40 * UPSCALE else None)
    out = detector(dim, BOARD)
    assert bool(out.found[0]) and torch.allclose(out.corners[0], GRID) and out.reasons[0].endswith("copy: enlarged)")
    # the image, then its two copies (stretched: the full range; enlarged), none of them again
    assert [c[0] for c in calls] == [(24, 40), (24, 40), (48, 80), "refined"]
    assert calls[-1] == ("refined", (24, 40), 1.0)  # on the image itself
    looks = calls[:-1]
    assert looks[0][1] <= 0.1 and all(c[1] > 0.9 for c in looks[1:])
    assert all(not c[2].copies and c[2].foreshortened and c[2].opencv for c in looks[1:])


def test_only_the_copies_that_suit_the_image(detector, monkeypatch):
    """A full-contrast image is not stretched and a large one not enlarged: a board-free view of a small
    image pays for one more look (the enlarged copy), of a large one for none; an image of one grey level for none."""
    calls = _staged(detector, monkeypatch, lambda x: None)
    assert not bool(detector(torch.rand(1, 1, 24, 40), BOARD).found[0])
    assert [c[0] for c in calls] == [(24, 40), (48, 80)]  # the image, enlarged
    side = int(SMALL_PIXELS**0.5) + 1
    calls = _staged(detector, monkeypatch, lambda x: None)
    detector(torch.rand(1, 1, side, side), BOARD)
    assert [c[0] for c in calls] == [(side, side)]
    calls = _staged(detector, monkeypatch, lambda x: None)
    detector(torch.full((1, 1, 24, 40), 0.5), BOARD)
    assert len(calls) == 1


def test_a_board_on_the_image_skips_the_copies_and_a_call_can_switch_them_off(detector, monkeypatch):
    calls = _staged(detector, monkeypatch, lambda x: GRID)
    assert bool(detector(torch.rand(1, 1, 24, 40), BOARD).found[0]) and len(calls) == 1
    partial = GRID.clone()
    partial[[0, 5]] = float("nan")  # a partial board is kept as it is, never looked at again
    calls = _staged(detector, monkeypatch, lambda x: partial if len(calls) == 1 else GRID)
    out = detector(torch.rand(1, 1, 24, 40), BOARD)
    assert len(calls) == 1 and torch.allclose(out.corners[0], partial, equal_nan=True)
    calls = _staged(detector, monkeypatch, lambda x: None)
    assert not bool(detector(torch.rand(1, 1, 24, 40), BOARD, Fallbacks(copies=False)).found[0]) and len(calls) == 1


def test_a_copy_corner_the_image_moves_is_left_out_and_a_board_left_too_small_is_not_used(detector, monkeypatch):
    image = torch.rand(1, 1, 24, 40)  # no board on the image itself, one on its enlarged copy
    moved = torch.zeros(6, 1)
    moved[2] = 2 * DISPUTED_PX  # the image's saddle fit moves one corner of the copy's board far (motion blur)
    _staged(detector, monkeypatch, lambda x: (GRID + 0.5) * UPSCALE - 0.5 if x.shape[-1] == 40 * UPSCALE else None,
            refine=lambda c: c + moved)
    out = detector(image, BOARD)
    want = GRID.clone()
    want[2] = float("nan")
    assert bool(out.found[0]) and torch.allclose(out.corners[0], want, equal_nan=True)
    moved[:4] = 2 * DISPUTED_PX  # two corners left: under the partial boards' least fraction (0.4 of 6)
    out = detector(image, BOARD)
    assert not bool(out.found[0])
