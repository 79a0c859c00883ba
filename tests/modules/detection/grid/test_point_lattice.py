"""The free point lattice: peaks to integer cells with no board size, under perspective, with clutter, batched; the
local prediction of cells the peaks missed."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ccs_kornia.modules.detection.grid.point_lattice import (
    organize_lattice,
    predict_cells,
)


def _lattice(cols: int, rows: int, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cells = np.stack(np.meshgrid(np.arange(cols), np.arange(rows), indexing="xy"), -1).reshape(-1, 2).astype(float)
    q = np.c_[cells, np.ones(len(cells))] @ h.T
    return cells, q[:, :2] / q[:, 2:]


H = np.array([[22.0, 4.0, 60.0], [-3.0, 20.0, 40.0], [2e-3, 1e-3, 1.0]])


def _consistent(cells: np.ndarray, truth: np.ndarray) -> bool:
    """Whether ``cells`` are ``truth`` up to one of the lattice's symmetries and a shift."""
    a = np.linalg.lstsq(np.c_[cells, np.ones(len(cells))], truth, rcond=None)[0]
    return bool(np.allclose(np.c_[cells, np.ones(len(cells))] @ a, truth, atol=1e-6)) and \
        bool(np.allclose(np.abs(a[:2]).sum(0), 1.0)) and bool(np.allclose(np.abs(np.linalg.det(a[:2])), 1.0))


def test_smoke_and_shapes(device, dtype):
    cells, pts = _lattice(7, 5, H)
    points = torch.from_numpy(pts).to(device, dtype)[None].repeat(2, 1, 1)
    mask = torch.ones(2, 35, dtype=torch.bool, device=device)
    mask[1, 5:] = False  # a second image with too few peaks
    out, member = organize_lattice(points, mask, 8)
    assert out.shape == (2, 35, 2) and out.dtype == torch.int64 and member.shape == (2, 35)
    assert out.device.type == device.type and member.device.type == device.type
    assert bool(member[0].all()) and not bool(member[1].any())
    assert _consistent(out[0].cpu().numpy().astype(float), cells)
    assert out[0].min().item() == 0


def test_clutter_and_a_second_smaller_lattice_are_left_out():
    cells, pts = _lattice(6, 5, H)
    rng = np.random.default_rng(3)
    clutter = rng.uniform(0, 400, size=(15, 2))
    _, small = _lattice(3, 3, np.array([[15.0, 0.0, 450.0], [0.0, 15.0, 300.0], [0.0, 0.0, 1.0]]))
    every = np.concatenate([pts, clutter, small])
    perm = rng.permutation(len(every))
    out, member = organize_lattice(torch.from_numpy(every[perm])[None], torch.ones(1, len(every), dtype=torch.bool), 8)
    back = np.argsort(perm)
    member = member[0].numpy()[back]
    assert member[:30].all() and not member[30:].any()
    assert _consistent(out[0].numpy()[back][:30].astype(float), cells)


def test_max_extent_bounds_the_growth():
    _, pts = _lattice(12, 4, np.array([[20.0, 0, 20], [0, 20.0, 20], [0, 0, 1.0]]))
    _, member = organize_lattice(torch.from_numpy(pts)[None], torch.ones(1, 48, dtype=torch.bool), 6)
    assert 0 < int(member.sum()) < 48


def test_predict_cells_follows_the_lattice():
    cells, pts = _lattice(6, 5, H)
    keep = np.ones(30, dtype=bool)
    keep[[7, 14]] = False
    pred, spacing = predict_cells(cells[keep], pts[keep], cells[~keep])
    assert np.abs(pred - pts[~keep]).max() < 0.05
    assert spacing.shape == (2,) and (spacing > 15).all()
    assert predict_cells(cells, pts, np.zeros((0, 2)))[0].shape == (0, 2)


def test_exceptions():
    pts = torch.rand(1, 10, 2)
    with pytest.raises(ValueError):
        organize_lattice(pts[0], torch.ones(10, dtype=torch.bool), 8)
    with pytest.raises(ValueError):
        organize_lattice(pts, torch.ones(1, 9, dtype=torch.bool), 8)
    with pytest.raises(ValueError):
        organize_lattice(pts, torch.ones(1, 10, dtype=torch.bool), 2)
    with pytest.raises(ValueError):
        organize_lattice(pts, torch.ones(1, 10, dtype=torch.bool), 8, tolerance=0.6)
