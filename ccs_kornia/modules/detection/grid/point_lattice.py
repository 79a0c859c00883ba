r"""A free point lattice: unordered corner peaks to integer lattice cells, with no board size and no window.

:func:`~ccs_kornia.modules.detection.grid.grid_organizer.organize_grid` needs the board's size: it places a
``cols x rows`` window on the lattice it grew and refuses anything else. A marker board cut by the frame shows a
lattice of any extent, and its markers, not the window, say which corner is which; :func:`organize_lattice` stops
after the organiser's growth, basis and leave-one-out check
(:mod:`~ccs_kornia.modules.detection.grid.lattice`): every peak gets a cell ``(a, b)`` of the largest consistent
lattice (up to the lattice's symmetries: a caller fixes them), and :func:`predict_cells` places cells the peaks
missed from the lattice around them.
"""

from __future__ import annotations

import numpy as np
import torch

from ccs_kornia.modules.detection.grid.lattice import (
    DIAGONAL_OFFSETS,
    Lattice,
    board_basis,
    cross_seeds,
    local_homographies,
    prune_inconsistent,
)
from ccs_kornia.runtime.checks import check_shape

__all__ = ["organize_lattice", "predict_cells"]


def _one_lattice(p: np.ndarray, max_extent: int, tol: float, check_tolerance: float, max_seeds: int, sigma: float,
                 min_points: int) -> tuple[np.ndarray, np.ndarray]:
    cells_out = np.zeros((len(p), 2), dtype=np.int64)
    member = np.zeros(len(p), dtype=bool)
    if len(p) < max(5, min_points):
        return cells_out, member
    dist = np.linalg.norm(p[:, None] - p[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    tried = np.zeros(len(p), dtype=bool)
    attempts = 0
    best: tuple[np.ndarray, np.ndarray] | None = None
    for seed in cross_seeds(p, dist, min(8, len(p) - 1)):
        if attempts >= max_seeds:
            break
        if tried[seed[0]]:
            continue  # this seed lies in a lattice already grown
        lat = Lattice(p, seed, max_extent, tol, sigma)
        cross_cells, cross_idx = lat.arrays()
        if lat.match(DIAGONAL_OFFSETS, cross_cells, cross_idx) < 2:
            continue  # a real cross has its diagonal neighbours too
        attempts += 1
        lat.grow()
        cells, idx = lat.arrays()
        tried[idx] = True
        cells = cells @ board_basis(cells).T
        lat.cells = {(int(c[0]), int(c[1])): int(i) for c, i in zip(cells, idx)}
        prune_inconsistent(lat, check_tolerance, sigma)
        cells, idx = lat.arrays()
        if len(idx) >= min_points and (best is None or len(idx) > len(best[1])):
            best = (cells, idx)
        if len(idx) > 0.7 * len(p):
            break  # no other lattice can be larger
    if best is None:
        return cells_out, member
    cells, idx = best
    cells_out[idx] = (cells - cells.min(0)).round().astype(np.int64)
    member[idx] = True
    return cells_out, member


def organize_lattice(
    points: torch.Tensor,
    mask: torch.Tensor,
    max_extent: int,
    tolerance: float = 0.3,
    check_tolerance: float = 0.15,
    max_seeds: int = 6,
    min_points: int = 6,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The largest consistent point lattice among unordered peaks, per image.

    The organiser's seeds, growth, basis and leave-one-out check
    (:mod:`~ccs_kornia.modules.detection.grid.grid_organizer`, steps 1-3 and 5) without its window: the lattice may
    have any extent up to ``max_extent`` cells a side. Its cells are known up to the lattice's symmetries (a quarter
    turn, a mirror) and a shift; the lowest cell of each axis is 0.

    Args:
        points: :math:`(B, M, 2)` peak positions ``(x, y)`` px (padded).
        mask: :math:`(B, M)` bool, True for real peaks.
        max_extent: most cells of the lattice along each axis (the board's corners per side).
        tolerance: while growing, accept a peak within this fraction of the local spacing of its predicted cell.
        check_tolerance: upper bound of the leave-one-out check's threshold, in spacings.
        max_seeds: seeds tried per image.
        min_points: a smaller lattice is no lattice.

    Returns:
        cells :math:`(B, M, 2)` int64 ``(a, b)`` of each peak and member :math:`(B, M)` bool (the peak is in the
        lattice; cells of other peaks are 0).

    Example:
        >>> grid = torch.stack(torch.meshgrid(torch.arange(4.0), torch.arange(3.0), indexing="xy"), -1).reshape(-1, 2)
        >>> pts = grid * 20 + 10
        >>> cells, member = organize_lattice(pts[None], torch.ones(1, 12, dtype=torch.bool), 8)
        >>> bool(member.all()), sorted((cells[0].max(0).values + 1).tolist())
        (True, [3, 4])
    """
    check_shape(points, ["B", "M", "2"], "points must be (B, M, 2)")
    check_shape(mask, points.shape[:2], f"mask must be (B, M) = {tuple(points.shape[:2])}")
    if max_extent < 3:
        raise ValueError(f"max_extent must be >= 3, got {max_extent}.")
    if not 0.0 < tolerance < 0.5 or not 0.0 < check_tolerance < 0.5:
        raise ValueError(f"tolerances must be in (0, 0.5) spacings, got {tolerance}, {check_tolerance}.")
    pts = points.detach().to("cpu", torch.float64).numpy()
    ok = mask.detach().to("cpu", torch.bool).numpy() & np.isfinite(pts).all(-1)
    cells = np.zeros(pts.shape, dtype=np.int64)
    member = np.zeros(ok.shape, dtype=bool)
    for b in range(pts.shape[0]):
        idx = np.flatnonzero(ok[b])
        c, m = _one_lattice(pts[b, idx], int(max_extent), tolerance, check_tolerance, max_seeds, 1.5, min_points)
        cells[b, idx], member[b, idx] = c, m
    return torch.from_numpy(cells).to(points.device), torch.from_numpy(member).to(points.device)


def predict_cells(cells: np.ndarray, points: np.ndarray, query: np.ndarray, sigma: float = 1.5
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Where the lattice (``cells`` :math:`(A, 2)` at ``points`` :math:`(A, 2)` px) puts the ``query`` cells
    :math:`(C, 2)`, and the lattice's spacing there (px): Gaussian-weighted local homographies (``sigma`` cells), so
    the prediction follows the lens's distortion.

    Example:
        >>> cells = np.stack(np.meshgrid(np.arange(4.0), np.arange(3.0)), -1).reshape(-1, 2)
        >>> pos, spacing = predict_cells(cells, cells * 20 + 10, np.array([[4.0, 1.0]]))
        >>> pos.round(6).tolist(), spacing.round(6).tolist()
        ([[90.0, 30.0]], [20.0])
    """
    cells = np.asarray(cells, dtype=np.float64).reshape(-1, 2)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    query = np.asarray(query, dtype=np.float64).reshape(-1, 2)
    if len(query) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    pred, jac = local_homographies(cells, points, query, sigma)
    spacing = np.minimum(np.linalg.norm(jac[:, :, 0], axis=1), np.linalg.norm(jac[:, :, 1], axis=1))
    return pred, spacing
