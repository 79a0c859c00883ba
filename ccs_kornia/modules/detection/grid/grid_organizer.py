"""Chessboard grid organisation: unordered corner peaks to a ``cols x rows`` board in grid order.

:func:`organize_grid` / :class:`GridOrganizer` turn an unordered, padded set of detected corner
peaks into a ``cols x rows`` board in grid order (``n = j * cols + i``), or report that no
consistent board of that size is present (``found`` False). The lattice machinery (local homographies,
seeds, growth, window, checks) is in :mod:`~ccs_kornia.modules.detection.grid.lattice`; the paper's collinearity
refinement that may follow is :mod:`~ccs_kornia.modules.detection.grid.collinearity`, the filling of cells the
network missed :mod:`~ccs_kornia.modules.detection.grid.missing_corners`.

Why not the paper's sort (extreme points + homography to a rectangle)? Picking the four board
corners from coordinate extremes breaks under strong perspective, clutter and missing corners.
Instead a lattice is grown from a seed corner:

1. seed: a peak whose nearest neighbours contain two non-parallel pairs of opposite, collinear
   neighbours (a "cross"); it gets lattice cell ``(0, 0)``, the cross arms ``(+-1, 0)``, ``(0, +-1)``;
2. growth, one ring per round: every empty cell next to the lattice is predicted with a homography
   fitted to the lattice points around it (Gaussian weights in lattice distance, so it stays local
   under residual distortion), and takes the nearest unused peak within ``tolerance`` x (local
   square size) of the prediction; with ``partial``, a lattice still short of ``min_fraction`` then
   bridges a gap of empty cells (a glare band across the board) where at least three peaks beyond it
   fit a homography of the whole lattice within half that tolerance, and grows on from them;
3. basis: under shear and foreshortening a square's diagonal can be shorter than its side, so the
   seed may have picked a sheared basis of the same point lattice; the integer change of basis
   that makes the lattice most compact recovers the board's rows and columns;
4. window: the lattice must contain a ``cols x rows`` (or ``rows x cols``: the board may appear
   rotated by 90 degrees) window whose four border lines are at least half occupied, with no line
   just outside it that is half occupied (that would be a larger board), holding at least
   ``min_fraction`` of the corners; otherwise the next seed is tried, and finally ``found`` is False
   (a sub-board, a board of another size, clutter, nothing);
5. check and fill: every corner is checked against a leave-one-out prediction from its neighbours
   (threshold adapted to the board's own scatter, at most ``check_tolerance`` squares), the worst
   offenders are dropped, and empty cells of the window are matched again with that threshold.

Boards need at least 3 corners in each direction (a seed needs neighbours on both sides).

Ordering convention. The lattice fixes the board up to its symmetries; the labelling chosen is

* ``i`` runs along the board's ``cols`` direction (``cols`` corners per row, as OpenCV's
  ``patternSize``);
* the labelling is never mirrored: ``d(x)/di x d(x)/dj > 0`` in image coordinates (y down), as for
  a board seen from its printed side with an OpenCV pose (``R`` near identity gives ``i`` to the
  right and ``j`` down);
* of the remaining labellings (two related by 180 degrees; four for square boards), the one whose
  corner 0 is nearest the image's top-left, i.e. with the smallest ``x + y``, is chosen.

A bare point lattice is always 180-degree symmetric, so without the image this rule is the only
possible one, and for boards whose square counts ``cols + 1`` and ``rows + 1`` are both even or both
odd (:func:`is_symmetric_board`: the printed pattern itself is 180-degree symmetric) it is the only
one at all. For the other boards (e.g. 9x6: 10x7 squares) the square colours tell the two apart:
when ``image`` is given, the labelling in which the outer square at corner 0 (beyond corner 0
diagonally, object ``x, y in (-s, 0)``) is **dark** is chosen. This is the order of OpenCV's classic
``findChessboardCorners`` (checked on rendered boards at 8 in-plane rotations; note that
``findChessboardCornersSB`` returns the opposite end first). It is decided from all inner squares
(square ``(i, j)-(i+1, j+1)`` is dark iff ``i + j`` is even), so it works when the outer squares
are cut off. A renderer producing ground truth should draw that square black.

The grid stage is combinatorial and sequential, so it runs per image in float64 numpy on the CPU
(a few milliseconds for ~100 peaks); every per-point step inside a growth round is vectorised.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from ccs_kornia.modules.detection.grid.lattice import (
    DIAGONAL_OFFSETS,
    Lattice,
    apply_homography,
    board_basis,
    cross_seeds,
    fit_lattice_homography,
    lattice_extends,
    prune_inconsistent,
    select_window,
)
from ccs_kornia.modules.detection.grid.lattice_evidence import (
    empty_cell_contrast,
    empty_cells_flat,
    placement_contrast,
    square_contrast,
)
from ccs_kornia.runtime.checks import check_board_size, check_shape

__all__ = ["organize_grid", "GridOrganizer", "is_symmetric_board"]


def is_symmetric_board(board_size: tuple[int, int]) -> bool:
    """Whether the printed ``cols x rows`` (inner corners) pattern is invariant under 180 degrees.

    True when the square counts ``cols + 1`` and ``rows + 1`` are both even or both odd; then the
    two 180-degree-related orderings cannot be told apart even from the image.

    Example:
        >>> is_symmetric_board((9, 6)), is_symmetric_board((8, 6)), is_symmetric_board((7, 5))
        (False, True, True)
    """
    cols, rows = board_size
    return (cols + rows) % 2 == 0


def _organize_one(
    p: np.ndarray,
    cols: int,
    rows: int,
    tol: float,
    check_tolerance: float,
    min_fraction: float,
    line_fraction: float,
    max_seeds: int,
    sigma: float,
    image: np.ndarray | None,
    partial: bool = False,
) -> tuple[np.ndarray, np.ndarray, bool]:
    n_board = cols * rows
    corners = np.zeros((n_board, 2))
    valid = np.zeros(n_board, dtype=bool)
    min_count = max(4, int(math.ceil(min_fraction * n_board)))
    if len(p) < min_count or len(p) < 5:
        return corners, valid, False
    dist = np.linalg.norm(p[:, None] - p[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    seeds = cross_seeds(p, dist, min(8, len(p) - 1))
    tried_points = np.zeros(len(p), dtype=bool)
    attempts = 0
    for seed in seeds:
        if attempts >= max_seeds:
            break
        if tried_points[seed[0]]:
            continue  # this seed lies in a lattice that already failed: it would grow the same lattice
        lat = Lattice(p, seed, cols + rows + 2, tol, sigma)
        # a real cross also has its diagonal neighbours; a false peak near the board can pair up
        # true corners into a "cross" that would grow a dislocated lattice
        cross_cells, cross_idx = lat.arrays()
        if lat.match(DIAGONAL_OFFSETS, cross_cells, cross_idx) < 2:
            continue
        attempts += 1
        lat.grow()
        if partial and len(lat.cells) < min_count:
            lat.bridge(max(cols, rows))
        cells, idx = lat.arrays()
        tried_points[idx] = True
        basis = board_basis(cells)
        cells = cells @ basis.T
        lat.cells = {(int(c[0]), int(c[1])): int(i) for c, i in zip(cells, idx)}
        windows = select_window(cells, cols, rows, min_count, line_fraction, partial)
        if not windows:
            continue
        if len(windows) > 1:
            # a partial board's lattice shorter than the board: the hidden lines go where the image shows no checker
            if image is None:
                continue
            scored = [(w, empty_cell_contrast(image, cells, p[idx], w, cols, rows)) for w in windows]
            scored.sort(key=lambda ws: placement_contrast(ws[1]))
            if not empty_cells_flat(image, cells, p[idx], scored[0][1]):
                continue  # the image shows a checker at the empty cells: corners missed, not hidden
            windows = [scored[0][0]]
        oa, ob, transposed, _ = windows[0]
        wa, wb = (rows, cols) if transposed else (cols, rows)
        inside = (cells[:, 0] >= oa) & (cells[:, 0] < oa + wa) & (cells[:, 1] >= ob) & (cells[:, 1] < ob + wb)
        # restart the bookkeeping with the window only
        lat.cells = {(int(c[0]), int(c[1])): int(i) for c, i in zip(cells[inside], idx[inside])}
        lat.cell_of_point[:] = -1
        lat.cell_of_point[idx[inside]] = 1
        # drop corners that disagree with their neighbours, then fill the holes with full support
        n_window = len(lat.cells)
        strict = prune_inconsistent(lat, check_tolerance, sigma)
        if n_window - len(lat.cells) > max(2, 0.1 * n_window):
            continue  # many corners disagree with their neighbours: not one consistent board
        all_cells = np.stack(np.meshgrid(np.arange(oa, oa + wa), np.arange(ob, ob + wb), indexing="ij"), -1)
        all_cells = all_cells.reshape(-1, 2).astype(np.float64)
        for _ in range(2):
            cells, idx = lat.arrays()
            missing = np.array([c for c in all_cells if (int(c[0]), int(c[1])) not in lat.cells]).reshape(-1, 2)
            if lat.match(missing, cells, idx, strict) == 0:
                break
        prune_inconsistent(lat, check_tolerance, sigma)
        cells, idx = lat.arrays()
        if len(idx) < min_count:
            continue
        if lattice_extends(lat, cells, idx, (oa, ob, wa, wb), strict, line_fraction):
            continue  # corners continue past an edge: a larger board than asked
        # lattice (a, b) -> board (i, j) before symmetry choice
        ga, gb = cells[:, 0] - oa, cells[:, 1] - ob
        ij = np.stack([gb, ga], -1) if transposed else np.stack([ga, gb], -1)
        xy = p[idx]
        candidates = [(False, False, False), (True, False, False), (False, True, False), (True, True, False)]
        if cols == rows:
            candidates += [(fi, fj, True) for fi, fj, _ in candidates]
        origin = np.zeros((1, 2))
        options = []
        for flip_i, flip_j, swap in candidates:
            t = ij[:, ::-1].copy() if swap else ij.copy()
            if flip_i:
                t[:, 0] = cols - 1 - t[:, 0]
            if flip_j:
                t[:, 1] = rows - 1 - t[:, 1]
            # chirality of the labelling, from the affine part of a fit (sign is robust to perspective)
            a = np.linalg.lstsq(np.concatenate([t, np.ones((len(t), 1))], 1), xy, rcond=None)[0]
            if np.linalg.det(a[:2].T) <= 0:
                continue
            h = fit_lattice_homography(t, xy)
            corner0 = apply_homography(h, origin)[0]
            options.append((float(corner0.sum()), t, h))  # x + y of corner 0: smallest is top-left
        if not options:  # degenerate fit
            continue
        options.sort(key=lambda o: o[0])
        chosen = options[0]
        if image is not None and not is_symmetric_board((cols, rows)) and len(options) >= 2:
            # the outer square at corner 0 is dark by convention, so is every inner square whose
            # corner with the lowest (i, j) has i + j even; the 180-degree labelling sees the opposite
            contrast = square_contrast(image, options[0][2], cols, rows)
            if np.isfinite(contrast) and abs(contrast) > 0.05:
                chosen = options[0] if contrast > 0 else options[1]
        _, t, h = chosen
        n_idx = (t[:, 1] * cols + t[:, 0]).round().astype(np.int64)
        # holes get the homography prediction (marked invalid) so callers have a usable guess
        grid_ij = np.stack(np.meshgrid(np.arange(cols), np.arange(rows), indexing="xy"), -1).reshape(-1, 2)
        corners = apply_homography(h, grid_ij.astype(np.float64))
        corners[n_idx] = xy
        valid[n_idx] = True
        return corners, valid, True
    return corners, valid, False


def organize_grid(
    points: torch.Tensor,
    mask: torch.Tensor,
    board_size: tuple[int, int],
    image: torch.Tensor | None = None,
    tolerance: float = 0.3,
    check_tolerance: float = 0.15,
    min_fraction: float = 0.7,
    line_fraction: float = 0.5,
    max_seeds: int = 6,
    partial: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Assign chessboard indices to unordered corner peaks.

    See the module docstring for the method and the ordering convention (corner 0 nearest the
    image's top-left, ``i`` along ``cols``, never mirrored; with ``image``, the dark outer square at
    corner 0 decides for non-symmetric boards).

    Args:
        points: :math:`(B, M, 2)` peak positions ``(x, y)`` in pixels (padded).
        mask: :math:`(B, M)` bool, True for real peaks.
        board_size: ``(cols, rows)`` inner corners, as OpenCV's ``patternSize``.
        image: optional :math:`(B, C, H, W)` image the peaks come from (used only to tell the two
            180-degree orientations of a non-symmetric board apart).
        tolerance: while growing, accept a peak within this fraction of the local square size of
            its predicted cell (predictions there are extrapolations).
        check_tolerance: upper bound of the stricter, data-adaptive threshold used to re-check every
            corner against its neighbours and to fill holes, in square sizes.
        min_fraction: least fraction of the ``cols*rows`` corners that must be found.
        line_fraction: least occupancy of each border row/column of the board; a line just outside
            the board with this occupancy means a larger board (rejected).
        max_seeds: seeds tried per image before giving up.
        partial: boards may lack corners (glare, an occluder; use with a low ``min_fraction``): a border line may
            then be nearly empty where the lattice spans the whole board in that direction, and a lattice shorter
            than the board is placed where ``image`` shows no checker at its empty cells (refused without ``image``, and
            where most of them show one: corners the network missed, not hidden ones).

    Returns:
        - corners :math:`(B, N, 2)`, ``N = cols*rows``, grid order ``n = j*cols + i``; cells without a
          peak hold the board homography's prediction, boards not found hold zeros;
        - valid :math:`(B, N)` bool, True where a peak was assigned;
        - found :math:`(B,)` bool.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> pts = board_object_points(4, 3)[:, :2] * 20 + 10
        >>> perm = torch.randperm(12)
        >>> corners, valid, found = organize_grid(pts[perm][None], torch.ones(1, 12, dtype=torch.bool), (4, 3))
        >>> bool(found[0]), bool(valid.all()), torch.allclose(corners[0], pts)
        (True, True, True)
    """
    check_shape(points, ["B", "M", "2"], "points must be (B, M, 2)")
    check_shape(mask, points.shape[:2], f"mask must be (B, M) = {tuple(points.shape[:2])}")
    cols, rows = check_board_size(board_size)
    if image is not None:
        check_shape(image, [points.shape[0], "C", "H", "W"], f"image must be (B, C, H, W) with B = {points.shape[0]}")
    if not 0.0 < tolerance < 0.5 or not 0.0 < check_tolerance < 0.5:
        raise ValueError(f"tolerances must be in (0, 0.5) square sizes, got {tolerance}, {check_tolerance}.")
    bsz, n_board = points.shape[0], cols * rows
    pts_np = points.detach().to("cpu", torch.float64).numpy()
    mask_np = mask.detach().to("cpu", torch.bool).numpy()
    mask_np = mask_np & np.isfinite(pts_np).all(-1)
    img_np = None
    if image is not None:
        # only sampled at a few square centres (the colour test): no float64 copy of the whole image
        img_np = image.detach()[:, 0].to("cpu", torch.float32).numpy() if image.shape[1] == 1 else \
            image.detach().to("cpu", torch.float32).mean(1).numpy()
    corners = np.zeros((bsz, n_board, 2))
    valid = np.zeros((bsz, n_board), dtype=bool)
    found = np.zeros(bsz, dtype=bool)
    for b in range(bsz):
        corners[b], valid[b], found[b] = _organize_one(
            pts_np[b][mask_np[b]],
            cols,
            rows,
            tolerance,
            check_tolerance,
            min_fraction,
            line_fraction,
            max_seeds,
            1.5,
            None if img_np is None else img_np[b],
            partial,
        )
    return (
        torch.from_numpy(corners).to(device=points.device, dtype=points.dtype),
        torch.from_numpy(valid).to(points.device),
        torch.from_numpy(found).to(points.device),
    )


class GridOrganizer(nn.Module):
    r"""Module wrapper of :func:`organize_grid` for a fixed board size.

    Example:
        >>> org = GridOrganizer((4, 3))
        >>> pts = torch.rand(2, 20, 2) * 100
        >>> corners, valid, found = org(pts, torch.ones(2, 20, dtype=torch.bool))
        >>> corners.shape, valid.shape, found.shape
        (torch.Size([2, 12, 2]), torch.Size([2, 12]), torch.Size([2]))
    """

    def __init__(
        self,
        board_size: tuple[int, int],
        tolerance: float = 0.3,
        check_tolerance: float = 0.15,
        min_fraction: float = 0.7,
        line_fraction: float = 0.5,
        max_seeds: int = 6,
    ) -> None:
        super().__init__()
        self.board_size = check_board_size(board_size)
        self.tolerance = tolerance
        self.check_tolerance = check_tolerance
        self.min_fraction = min_fraction
        self.line_fraction = line_fraction
        self.max_seeds = max_seeds

    def forward(
        self, points: torch.Tensor, mask: torch.Tensor, image: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return organize_grid(
            points,
            mask,
            self.board_size,
            image,
            self.tolerance,
            self.check_tolerance,
            self.min_fraction,
            self.line_fraction,
            self.max_seeds,
        )

    def extra_repr(self) -> str:
        return f"board_size={self.board_size}, tolerance={self.tolerance}, min_fraction={self.min_fraction}"
