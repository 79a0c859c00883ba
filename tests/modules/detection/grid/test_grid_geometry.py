"""line_sagitta: the bend of an organised board's rows and columns at each corner."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.modules.detection.grid.grid_geometry import (
    MIN_SHEAR_SHRINK,
    grid_spacing,
    line_sagitta,
)


def _grid(cols: int = 9, rows: int = 6, step: float = 20.0, dtype=torch.float64) -> torch.Tensor:
    xs, ys = torch.meshgrid(torch.arange(cols, dtype=dtype), torch.arange(rows, dtype=dtype), indexing="xy")
    return step * torch.stack([xs, ys], -1).reshape(1, cols * rows, 2)


def _homography(points: torch.Tensor) -> torch.Tensor:
    H = torch.tensor([[1.1, 0.2, 40.0], [-0.1, 0.9, 30.0], [4e-4, -3e-4, 1.0]], dtype=points.dtype)
    p = torch.cat([points, torch.ones_like(points[..., :1])], -1) @ H.T
    return p[..., :2] / p[..., 2:]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_straight_lines_under_perspective_have_no_bend(dtype):
    corners = _homography(_grid(dtype=torch.float64)).to(dtype)
    sag = line_sagitta(corners, torch.ones(1, 54, dtype=torch.bool), (9, 6))
    assert sag.shape == (1, 54) and sag.dtype == dtype
    assert float(sag.max()) < (1e-3 if dtype == torch.float32 else 1e-8)


def test_a_parabola_gives_its_sagitta_and_the_bend_is_the_larger_of_row_and_column():
    grid = _grid()
    bent = grid.clone()
    bent[..., 1] += 0.005 * (bent[..., 0] - 80) ** 2  # every row a parabola: y'' = 0.01 / px, step 20 px
    sag = line_sagitta(bent, torch.ones(1, 54, dtype=torch.bool), (9, 6))
    torch.testing.assert_close(sag, torch.full_like(sag, 0.01 * 20**2 / 2), atol=1e-6, rtol=1e-3)


def test_invalid_and_non_finite_corners_are_ignored_and_short_lines_are_unknown():
    grid = _grid()
    valid = torch.ones(1, 54, dtype=torch.bool)
    wild = grid.clone()
    wild[0, 10] = torch.tensor([1e4, -1e4])  # far off its row and column, but marked invalid
    wild[0, 20] = float("nan")
    valid[0, 10] = valid[0, 20] = False
    assert float(line_sagitta(wild, valid, (9, 6)).max()) < 1e-8
    # a column of the 9x2 board has two corners: its bend is unknown, so every corner's is
    assert bool(torch.isinf(line_sagitta(_grid(9, 2), torch.ones(1, 18, dtype=torch.bool), (9, 2))).all())
    # rows of three or four corners get a parabola: y'' = 0.01 / px, step 20 px
    three = _grid(3, 3)
    three[..., 1] += 0.005 * (three[..., 0] - 20) ** 2
    torch.testing.assert_close(line_sagitta(three, torch.ones(1, 9, dtype=torch.bool), (3, 3)),
                               torch.full((1, 9), 2.0, dtype=torch.float64))


def test_batch_is_per_board():
    grid = _grid()
    bent = grid.clone()
    bent[..., 0] += 0.004 * (bent[..., 1] - 50) ** 2
    both = line_sagitta(torch.cat([grid, bent]), torch.ones(2, 54, dtype=torch.bool), (9, 6))
    alone = line_sagitta(bent, torch.ones(1, 54, dtype=torch.bool), (9, 6))
    torch.testing.assert_close(both[1:], alone)
    assert float(both[0].max()) < 1e-8


def test_exceptions():
    with pytest.raises(ValueError, match="corners must be"):
        line_sagitta(torch.zeros(54, 2), torch.ones(54, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError, match="board_size"):
        line_sagitta(torch.zeros(1, 54, 2), torch.ones(1, 54, dtype=torch.bool), (6, 6))
    with pytest.raises(ValueError, match="2x2"):
        line_sagitta(torch.zeros(1, 9, 2), torch.ones(1, 9, dtype=torch.bool), (9, 1))


def test_gradcheck():
    corners = _homography(_grid(5, 5)).clone()
    corners[..., 1] += 0.002 * (corners[..., 0] - 80) ** 2
    corners.requires_grad_(True)
    valid = torch.ones(1, 25, dtype=torch.bool)
    assert torch.autograd.gradcheck(lambda c: line_sagitta(c, valid, (5, 5)), (corners,))


def _sheared(angle_deg: float, cols: int = 5, rows: int = 4, step: float = 20.0) -> torch.Tensor:
    a = torch.deg2rad(torch.tensor(angle_deg, dtype=torch.float64))
    ex = torch.tensor([step, 0.0], dtype=torch.float64)
    ey = step * torch.stack([torch.cos(a), torch.sin(a)])
    j, i = torch.meshgrid(torch.arange(rows, dtype=torch.float64), torch.arange(cols, dtype=torch.float64), indexing="ij")
    return (i.reshape(-1, 1) * ex + j.reshape(-1, 1) * ey)[None]


@pytest.mark.parametrize("angle", [90.0, 60.0, 30.0])
def test_spacing_is_the_nearest_neighbour_on_cells_of_30_degrees_and_more(angle):
    sp = grid_spacing(_sheared(angle), torch.ones(1, 20, dtype=torch.bool), (5, 4))
    torch.testing.assert_close(sp, torch.full_like(sp, 20.0))


@pytest.mark.parametrize("angle", [25.0, 15.0, 160.0])
def test_spacing_shrinks_with_the_height_of_sheared_cells(angle):
    """Below 30 degrees the next edge passes a corner at the cell's height: spacing x sin(angle) / sin(30 degrees)."""
    sp = grid_spacing(_sheared(angle), torch.ones(1, 20, dtype=torch.bool), (5, 4))
    want = 20.0 * 2.0 * math.sin(math.radians(angle))
    torch.testing.assert_close(sp, torch.full_like(sp, want))


def test_degenerate_cells_keep_a_window_and_lonely_corners_no_spacing():
    flat = _sheared(0.5)
    sp = grid_spacing(flat, torch.ones(1, 20, dtype=torch.bool), (5, 4))
    assert float(sp.min()) >= 20.0 * MIN_SHEAR_SHRINK - 1e-9
    valid = torch.zeros(1, 20, dtype=torch.bool)
    valid[0, 0] = True
    assert bool(torch.isinf(grid_spacing(_sheared(90.0), valid, (5, 4))).all())
