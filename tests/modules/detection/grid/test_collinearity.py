"""Tests of the paper's collinearity refinement."""

from __future__ import annotations

import pytest
import torch
from _grid_views import _views

from ccs_kornia.geometry.camera import intrinsics_matrix
from ccs_kornia.modules.detection.grid.collinearity import (
    CollinearityRefiner,
    collinearity_refine,
)

F64 = torch.float64
W, H = 640, 480
K = intrinsics_matrix(torch.tensor([600.0, 600.0, (W - 1) / 2, (H - 1) / 2], dtype=F64))


def test_collinearity_exact_on_lines():
    gt, _ = _views(9, 6, 4, seed=20, tilt=(30.0, 60.0))
    valid = torch.ones(4, 54, dtype=torch.bool)
    valid[:, [0, 13, 40]] = False
    refined, ok = collinearity_refine(gt, valid, (9, 6))
    assert ok.all()
    assert (refined - gt).norm(dim=-1).max() < 1e-8


@pytest.mark.parametrize("board", [(9, 6), (11, 8)])
def test_collinearity_reduces_noise(board):
    cols, rows = board
    gt, _ = _views(cols, rows, 20, seed=21)
    g = torch.Generator().manual_seed(21)
    noisy = gt + 0.2 * torch.randn(gt.shape, generator=g, dtype=F64)
    valid = torch.ones(gt.shape[:2], dtype=torch.bool)
    before = (noisy - gt).norm(dim=-1).mean()
    for concurrent in (False, True):
        refined, ok = collinearity_refine(noisy, valid, board, concurrent=concurrent)
        after = (refined - gt).norm(dim=-1).mean()
        assert ok.all()
        assert after < 0.7 * before  # at least a 30 % reduction


def test_collinearity_recovers_missing_corners():
    gt, _ = _views(9, 6, 20, seed=22)
    g = torch.Generator().manual_seed(22)
    noisy = gt + 0.2 * torch.randn(gt.shape, generator=g, dtype=F64)
    valid = torch.rand(gt.shape[:2], generator=g) >= 0.15
    noisy = torch.where(valid[..., None], noisy, torch.full_like(noisy, float("nan")))  # holes hold garbage
    refined, ok = collinearity_refine(noisy, valid, (9, 6))
    grid_valid = valid.reshape(-1, 6, 9)
    lines_ok = (grid_valid.sum(2, keepdim=True) >= 3) & (grid_valid.sum(1, keepdim=True) >= 3)
    assert torch.equal(ok, valid | lines_ok.reshape(-1, 54))
    recovered = ok & ~valid
    assert recovered.sum() > 100 and torch.isfinite(refined[ok]).all()
    err = (refined - gt).norm(dim=-1)[recovered]
    assert err.mean() < 0.2 and err.max() < 0.8
    # the paper's independent lines recover them too, less steadily
    paper, _ = collinearity_refine(noisy, valid, (9, 6), concurrent=False)
    err_paper = (paper - gt).norm(dim=-1)[recovered]
    assert err.mean() < err_paper.mean() < 0.3


def test_collinearity_robust_to_one_bad_corner():
    gt, _ = _views(9, 6, 6, seed=23)
    g = torch.Generator().manual_seed(23)
    noisy = gt + 0.1 * torch.randn(gt.shape, generator=g, dtype=F64)
    noisy[:, 22] += torch.tensor([3.0, -3.0], dtype=F64)  # one corner badly off
    valid = torch.ones(gt.shape[:2], dtype=torch.bool)
    others = torch.ones(54, dtype=torch.bool)
    others[22] = False
    plain = (collinearity_refine(noisy, valid, (9, 6), iterations=1)[0] - gt).norm(dim=-1)[:, others].mean()
    robust = (collinearity_refine(noisy, valid, (9, 6), iterations=3)[0] - gt).norm(dim=-1)[:, others].mean()
    assert robust < 0.6 * plain


def test_collinearity_undefined_lines_and_blend():
    gt, _ = _views(5, 5, 1, seed=24)
    valid = torch.ones(1, 25, dtype=torch.bool)
    valid[0, 5:10] = False  # row 1 empty: its corners cannot be recovered
    valid[0, 0] = False  # column 0 keeps 3 corners: recoverable
    noisy = gt + 0.3
    refined, ok = collinearity_refine(noisy, valid, (5, 5), min_points=3)
    assert not ok[0, 5:10].any() and ok[0, 0] and ok[0, 10:].all()
    assert torch.equal(refined[0, 5:10], noisy[0, 5:10])  # untouched
    assert not collinearity_refine(noisy, valid, (5, 5), min_points=4)[1][0, 0]
    kept, _ = collinearity_refine(noisy, valid, (5, 5), blend=0.0)
    assert torch.allclose(kept[0, valid[0]], noisy[0, valid[0]])
    assert torch.allclose(kept[0, 0], refined[0, 0])  # missing corners always take the intersection


def test_collinearity_batch_and_module():
    gt, _ = _views(8, 6, 3, seed=25)
    noisy = gt + 0.2 * torch.randn(gt.shape, generator=torch.Generator().manual_seed(25), dtype=F64)
    valid = torch.rand(gt.shape[:2], generator=torch.Generator().manual_seed(26)) > 0.1
    refiner = CollinearityRefiner((8, 6))
    batch, ok = refiner(noisy, valid)
    for b in range(3):
        one, ok1 = refiner(noisy[b : b + 1], valid[b : b + 1])
        assert torch.allclose(one[0], batch[b], atol=1e-10) and torch.equal(ok1[0], ok[b])
    assert "board_size=(8, 6)" in repr(refiner)


def test_collinearity_gradcheck():
    gt, _ = _views(4, 3, 1, seed=27)
    noisy = (gt + 0.2 * torch.randn(gt.shape, generator=torch.Generator().manual_seed(27), dtype=F64)).requires_grad_()
    valid = torch.ones(1, 12, dtype=torch.bool)
    valid[0, 5] = False
    for concurrent in (False, True):
        fn = lambda c: collinearity_refine(c, valid, (4, 3), iterations=2, concurrent=concurrent)[0]  # noqa: E731
        assert torch.autograd.gradcheck(fn, (noisy,))


def test_collinearity_exceptions():
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 53, 2), torch.ones(1, 53, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(54, 2), torch.ones(54, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 54, 2), torch.ones(1, 53, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 54, 2), torch.ones(1, 54, dtype=torch.bool), (9, 6), min_points=1)
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 54, 2), torch.ones(1, 54, dtype=torch.bool), (9, 6), blend=2.0)
