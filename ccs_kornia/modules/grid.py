"""Chessboard grid organisation and collinearity refinement.

Two stages sit between the sub-pixel corner detector and the solvers:

* :func:`organize_grid` / :class:`GridOrganizer` turn an unordered, padded set of detected corner
  peaks into a ``cols x rows`` board in grid order (``n = j * cols + i``), or report that no
  consistent board of that size is present (``found`` False);
* :func:`collinearity_refine` / :class:`CollinearityRefiner` are the paper's *collineation
  post-processing* (Sec. III-B): fit a straight line to every row and every column of the organised
  board and replace each corner by the intersection of its row and column lines. This also recovers
  missing corners. It assumes an undistorted image (the paper removes distortion first).

Why not the paper's sort (extreme points + homography to a rectangle)? Picking the four board
corners from coordinate extremes breaks under strong perspective, clutter and missing corners.
Instead a lattice is grown from a seed corner:

1. seed: a peak whose nearest neighbours contain two non-parallel pairs of opposite, collinear
   neighbours (a "cross"); it gets lattice cell ``(0, 0)``, the cross arms ``(+-1, 0)``, ``(0, +-1)``;
2. growth, one ring per round: every empty cell next to the lattice is predicted with a homography
   fitted to the lattice points around it (Gaussian weights in lattice distance, so it stays local
   under residual distortion), and takes the nearest unused peak within ``tolerance`` x (local
   square size) of the prediction;
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
The collinearity stage is fully batched torch and differentiable.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

__all__ = [
    "organize_grid",
    "GridOrganizer",
    "collinearity_refine",
    "CollinearityRefiner",
    "is_symmetric_board",
    "predict_missing_corners",
]


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


def _check_board_size(board_size: tuple[int, int]) -> tuple[int, int]:
    if len(board_size) != 2:
        raise ValueError(f"board_size must be (cols, rows), got {board_size}.")
    cols, rows = int(board_size[0]), int(board_size[1])
    if cols < 2 or rows < 2:
        raise ValueError(f"A board needs at least 2x2 inner corners, got {cols}x{rows}.")
    return cols, rows


# ----------------------------------------------------------------------------------------------
# Local homography prediction (numpy, float64)
# ----------------------------------------------------------------------------------------------


def _normal_equation_layout() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where each entry of the DLT normal equations comes from in the moment vector of
    :func:`_local_homographies` (index 23 is a constant zero), and its sign."""
    names = ["1", "u", "v", "uu", "uv", "vv", "x", "xu", "xv", "xuu", "xuv", "xvv",
             "y", "yu", "yv", "yuu", "yuv", "yvv", "ruu", "ruv", "rvv", "ru", "rv", "0"]
    k = {n: i for i, n in enumerate(names)}
    phi = [["uu", "uv", "u"], ["uv", "vv", "v"], ["u", "v", "1"]]
    xphi = [["xuu", "xuv"], ["xuv", "xvv"], ["xu", "xv"]]
    yphi = [["yuu", "yuv"], ["yuv", "yvv"], ["yu", "yv"]]
    rr = [["ruu", "ruv"], ["ruv", "rvv"]]
    index = np.full((8, 8), k["0"])
    sign = np.ones((8, 8))
    for r in range(3):
        for q in range(3):
            index[r, q] = index[3 + r, 3 + q] = k[phi[r][q]]
        for q in range(2):
            index[r, 6 + q] = index[6 + q, r] = k[xphi[r][q]]
            index[3 + r, 6 + q] = index[6 + q, 3 + r] = k[yphi[r][q]]
            sign[r, 6 + q] = sign[6 + q, r] = sign[3 + r, 6 + q] = sign[6 + q, 3 + r] = -1.0
    for r in range(2):
        for q in range(2):
            index[6 + r, 6 + q] = k[rr[r][q]]
    rhs_index = np.array([k[n] for n in ["xu", "xv", "x", "yu", "yv", "y", "ru", "rv"]])
    rhs_sign = np.array([1.0, 1, 1, 1, 1, 1, -1, -1])
    return index, sign, rhs_index, rhs_sign


_NORMAL_INDEX, _NORMAL_SIGN, _RHS_INDEX, _RHS_SIGN = _normal_equation_layout()
_DIAG = np.arange(8)
_RIDGE = np.array([1e-9] * 6 + [1e-5] * 2)


def _local_homographies(
    grid: np.ndarray, pts: np.ndarray, query: np.ndarray, sigma: float, exclude_self: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Predict image positions of lattice cells with Gaussian-weighted local homographies.

    One weighted least-squares homography (inhomogeneous DLT, ``h33 = 1``) per query cell, all solved
    at once: the normal equations are sums of fixed per-support-point moments, so every query's
    system comes out of a single ``(C, A) @ (A, 23)`` product.

    Args:
        grid: (A, 2) lattice cells (float) of the support points.
        pts: (A, 2) image positions of the support points.
        query: (C, 2) lattice cells to predict.
        sigma: Gaussian weight width in lattice cells.
        exclude_self: give zero weight to support cells equal to the query (leave-one-out).

    Returns:
        (C, 2) predicted positions and (C, 2, 2) Jacobians d(x, y)/d(i, j) (columns per lattice axis).
    """
    # normalise both sides (Hartley) so that the moments are O(1)
    g0 = grid.mean(0)
    gs = max(float(np.abs(grid - g0).max()), 1.0)
    p0 = pts.mean(0)
    ps = max(float(np.sqrt(((pts - p0) ** 2).sum(1).mean())), 1e-12)
    u, v = ((grid - g0) / gs).T
    x, y = ((pts - p0) / ps).T
    r2 = x * x + y * y
    uu, uv, vv = u * u, u * v, v * v
    one = np.ones_like(u)
    feats = np.stack(
        [one, u, v, uu, uv, vv, x, x * u, x * v, x * uu, x * uv, x * vv,
         y, y * u, y * v, y * uu, y * uv, y * vv, r2 * uu, r2 * uv, r2 * vv, r2 * u, r2 * v], 1
    )  # (A, 23)
    du = query[:, :1] - grid[:, 0]
    dv = query[:, 1:] - grid[:, 1]
    d2 = du * du + dv * dv  # (C, A), in cells
    w = np.exp(-0.5 * d2 / sigma**2)
    if exclude_self:
        w[d2 < 0.5] = 0.0
    sums = np.concatenate([w @ feats, np.zeros((len(query), 1))], 1)  # (C, 24), last column 0
    m = sums[:, _NORMAL_INDEX] * _NORMAL_SIGN  # (C, 8, 8)
    b = sums[:, _RHS_INDEX] * _RHS_SIGN  # (C, 8)
    # a small ridge keeps thin support (a straight row, the seed cross) solvable; it pulls the
    # perspective terms towards an affine map first
    scale = np.trace(m, axis1=1, axis2=2)[:, None] / 8.0 + 1e-12
    m[:, _DIAG, _DIAG] += _RIDGE * scale
    h = np.linalg.solve(m, b[..., None])[..., 0]  # (C, 8)
    qu, qv = ((query - g0) / gs).T
    den = h[:, 6] * qu + h[:, 7] * qv + 1.0
    px = (h[:, 0] * qu + h[:, 1] * qv + h[:, 2]) / den
    py = (h[:, 3] * qu + h[:, 4] * qv + h[:, 5]) / den
    jac = np.stack(
        [np.stack([h[:, 0] - px * h[:, 6], h[:, 1] - px * h[:, 7]], -1),
         np.stack([h[:, 3] - py * h[:, 6], h[:, 4] - py * h[:, 7]], -1)],
        -2,
    ) / den[:, None, None]  # (C, 2, 2): rows x/y, columns i/j
    return np.stack([px, py], -1) * ps + p0, jac * (ps / gs)


def _fit_homography(grid: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Least-squares homography lattice -> image (h33 = 1), returned as a (3, 3) matrix."""
    u, v = grid[:, 0], grid[:, 1]
    x, y = pts[:, 0], pts[:, 1]
    z, o = np.zeros_like(u), np.ones_like(u)
    a = np.concatenate(
        [np.stack([u, v, o, z, z, z, -x * u, -x * v], -1), np.stack([z, z, z, u, v, o, -y * u, -y * v], -1)], 0
    )
    h = np.linalg.lstsq(a, np.concatenate([x, y]), rcond=None)[0]
    return np.append(h, 1.0).reshape(3, 3)


def _apply_h(h: np.ndarray, grid: np.ndarray) -> np.ndarray:
    q = np.concatenate([grid, np.ones((len(grid), 1))], 1) @ h.T
    return q[:, :2] / q[:, 2:3]


# ----------------------------------------------------------------------------------------------
# Seeds, growth, window
# ----------------------------------------------------------------------------------------------

_COS_OPPOSITE = math.cos(math.radians(12.0))  # arms of a cross are collinear up to noise
_COS_PARALLEL = math.cos(math.radians(20.0))  # the two axes of a cross must differ clearly
_MAX_ARM_RATIO = 1.8  # opposite arms differ by perspective only


def _cross_seeds(p: np.ndarray, dist: np.ndarray, k: int) -> list[tuple[int, int, int, int, int, float]]:
    """Peaks whose ``k`` nearest neighbours contain a cross; returns (seed, +u, -u, +v, -v, score)."""
    n = len(p)
    knn = np.argpartition(dist, k - 1, axis=1)[:, :k]  # (n, k), unordered
    knn = np.take_along_axis(knn, np.argsort(np.take_along_axis(dist, knn, 1), axis=1), 1)
    vec = p[knn] - p[:, None, :]
    length = np.linalg.norm(vec, axis=-1) + 1e-12
    unit = vec / length[..., None]
    cos = np.einsum("nad,nbd->nab", unit, unit)
    ratio = np.maximum(length[:, :, None], length[:, None, :]) / np.minimum(length[:, :, None], length[:, None, :])
    opposite = (cos < -_COS_OPPOSITE) & (ratio < _MAX_ARM_RATIO)
    opposite &= np.triu(np.ones((k, k), dtype=bool), 1)[None]
    pair_len = np.where(opposite, np.maximum(length[:, :, None], length[:, None, :]), np.inf)
    flat = pair_len.reshape(n, -1)
    first = flat.argmin(1)
    has_first = np.isfinite(flat[np.arange(n), first])
    a1, b1 = np.divmod(first, k)
    axis1 = unit[np.arange(n), a1]  # (n, 2)
    # second axis: opposite pair whose direction is not parallel to the first
    par = np.abs(np.einsum("nkd,nd->nk", unit, axis1)) > _COS_PARALLEL  # (n, k)
    ok2 = opposite & ~par[:, :, None] & ~par[:, None, :]
    pair_len2 = np.where(ok2, pair_len, np.inf).reshape(n, -1)
    second = pair_len2.argmin(1)
    has_second = np.isfinite(pair_len2[np.arange(n), second])
    a2, b2 = np.divmod(second, k)
    idx = np.arange(n)
    score = (
        (1.0 + cos[idx, a1, b1]) + (1.0 + cos[idx, a2, b2]) + 0.1 * np.log(ratio[idx, a1, b1] * ratio[idx, a2, b2])
    )
    good = np.nonzero(has_first & has_second)[0]
    if len(good) == 0:
        return []
    # prefer clean crosses near the middle of the point cloud (more room to grow, less clutter)
    centre = np.median(p, 0)
    spread = np.median(np.linalg.norm(p - centre, axis=1)) + 1e-9
    total = score[good] + 0.02 * np.linalg.norm(p[good] - centre, axis=1) / spread
    order = good[np.argsort(total)]
    return [
        (int(s), int(knn[s, a1[s]]), int(knn[s, b1[s]]), int(knn[s, a2[s]]), int(knn[s, b2[s]]), float(score[s]))
        for s in order
    ]


_NEIGHBOURS = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])
_DIAGONALS = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])
_NEIGHBOURS8 = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]])

class _Lattice:
    """Sparse integer lattice of peaks grown from a seed (one image)."""

    def __init__(
        self, p: np.ndarray, seed: tuple[int, int, int, int, int, float], max_extent: int, tol: float, sigma: float
    ) -> None:
        s, pu, mu, pv, mv, _ = seed
        arms = p[[pu, mu, pv, mv]] - p[s]
        self.origin = p[s].copy()
        self.scale = float(np.linalg.norm(arms, axis=1).mean()) + 1e-12
        self.p = (p - self.origin) / self.scale  # normalised positions
        self.cell_of_point = np.full(len(p), -1, dtype=np.int64)
        self.cells: dict[tuple[int, int], int] = {}
        for pt, c in zip((s, pu, mu, pv, mv), ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))):
            self._add(c, pt)
        self.max_extent = max_extent
        self.tol = tol
        self.sigma = sigma

    def _add(self, cell: tuple[int, int], pt: int) -> None:
        self.cells[cell] = pt
        self.cell_of_point[pt] = 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        cells = np.array(list(self.cells.keys()), dtype=np.float64).reshape(-1, 2)
        idx = np.array(list(self.cells.values()), dtype=np.int64)
        return cells, idx

    def match(
        self, query: np.ndarray, support_cells: np.ndarray, support_idx: np.ndarray, tol: float | None = None
    ) -> int:
        """Predict ``query`` cells from the support, accept the nearest free peaks; returns #added."""
        tol = self.tol if tol is None else tol
        if len(query) == 0:
            return 0
        pred, jac = _local_homographies(support_cells, self.p[support_idx], query, self.sigma)
        spacing = np.minimum(np.linalg.norm(jac[:, :, 0], axis=1), np.linalg.norm(jac[:, :, 1], axis=1))
        free = self.cell_of_point < 0
        if not free.any():
            return 0
        free_idx = np.nonzero(free)[0]
        d = np.linalg.norm(pred[:, None, :] - self.p[None, free_idx, :], axis=-1) / (spacing[:, None] + 1e-12)
        best = d.argmin(1)
        best_d = d[np.arange(len(query)), best]
        ok = np.nonzero(best_d < tol)[0]
        if len(ok) == 0:
            return 0
        # each peak goes to the cell that predicts it best
        ok = ok[np.argsort(best_d[ok])]
        _, first = np.unique(best[ok], return_index=True)
        added = 0
        for q in ok[first]:
            self._add((int(query[q, 0]), int(query[q, 1])), int(free_idx[best[q]]))
            added += 1
        return added

    def grow(self) -> None:
        # dense occupancy masks around the seed: growth stays within +-max_extent cells of it
        r = self.max_extent
        size = 2 * r + 1
        span_ok = np.arange(size) - r
        dead = np.zeros((size, size), dtype=bool)  # empty cells not worth asking again
        for _ in range(4 * r + 8):
            cells, idx = self.arrays()
            ci = cells.astype(np.int64) + r
            occ = np.zeros((size, size), dtype=bool)
            occ[ci[:, 0], ci[:, 1]] = True
            cand = _dilate(occ, _NEIGHBOURS8) & ~occ & ~dead
            # never grow beyond what could still be trimmed to a board
            lo, hi = ci.min(0) - r, ci.max(0) - r
            cand &= (np.maximum(hi[0] - span_ok, span_ok - lo[0]) + 1 <= r)[:, None]
            cand &= (np.maximum(hi[1] - span_ok, span_ok - lo[1]) + 1 <= r)[None, :]
            qa, qb = np.nonzero(cand)
            if len(qa) == 0:
                break
            if self.match(np.stack([qa - r, qb - r], -1).astype(np.float64), cells, idx) == 0:
                break
            # an empty cell is retried only once it has at least two lattice neighbours (then its
            # prediction is interpolated, not extrapolated); cells beyond the board edge never do
            ci = self.arrays()[0].astype(np.int64) + r
            occ[ci[:, 0], ci[:, 1]] = True
            dead |= cand & ~occ
            dead &= _count_neighbours(occ) < 2


def _dilate(mask: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Cells that have a True cell at one of ``offsets`` (no wrap-around)."""
    out = np.zeros_like(mask)
    h, w = mask.shape
    for da, db in offsets:
        out[max(da, 0) : h + min(da, 0), max(db, 0) : w + min(db, 0)] |= mask[
            max(-da, 0) : h + min(-da, 0), max(-db, 0) : w + min(-db, 0)
        ]
    return out


def _count_neighbours(mask: np.ndarray) -> np.ndarray:
    """Number of True 4-neighbours of every cell."""
    count = np.zeros(mask.shape, dtype=np.int64)
    h, w = mask.shape
    for da, db in _NEIGHBOURS:
        count[max(da, 0) : h + min(da, 0), max(db, 0) : w + min(db, 0)] += mask[
            max(-da, 0) : h + min(-da, 0), max(-db, 0) : w + min(-db, 0)
        ]
    return count


def _unimodular_bases(limit: int = 2) -> np.ndarray:
    r = range(-limit, limit + 1)
    mats = [np.array([[a, b], [c, d]]) for a in r for b in r for c in r for d in r if abs(a * d - b * c) == 1]
    # identity first so that ties keep the grown basis
    mats.sort(key=lambda m: (np.abs(m - np.eye(2)).sum(), tuple(m.ravel())))
    return np.stack(mats).astype(np.float64)


_BASES = _unimodular_bases()


def _board_basis(cells: np.ndarray) -> np.ndarray:
    """Integer change of lattice basis that makes the grown lattice as compact as possible.

    Seeds take their arms from nearest neighbours, and under shear and foreshortening a square's
    diagonal can be shorter than its side, so the grown basis may be a sheared one of the same point
    lattice. The board axes are the basis whose bounding box of the lattice is smallest.
    """
    t = np.einsum("kij,nj->kni", _BASES, cells)
    area = np.prod(t.max(1) - t.min(1) + 1, axis=-1)
    return _BASES[int(np.argmin(area))]


def _select_window(
    cells: np.ndarray, cols: int, rows: int, min_count: int, line_fraction: float
) -> tuple[int, int, bool, int] | None:
    """Best ``cols x rows`` window of the lattice; returns (offset_a, offset_b, transposed, count)."""
    lo = cells.min(0).astype(np.int64)
    ext = cells.max(0).astype(np.int64) - lo + 1
    occ = np.zeros(tuple(ext), dtype=bool)
    ci = cells.astype(np.int64) - lo
    occ[ci[:, 0], ci[:, 1]] = True
    best = None
    orientations = [(cols, rows, False)] + ([(rows, cols, True)] if cols != rows else [])
    for wa, wb, transposed in orientations:
        if ext[0] < wa or ext[1] < wb:
            continue
        for oa in range(ext[0] - wa + 1):
            for ob in range(ext[1] - wb + 1):
                sub = occ[oa : oa + wa, ob : ob + wb]
                count = int(sub.sum())
                if count < min_count:
                    continue
                borders = (sub[0].mean(), sub[-1].mean(), sub[:, 0].mean(), sub[:, -1].mean())
                if min(borders) < line_fraction:
                    continue
                outside = []
                if oa > 0:
                    outside.append(occ[oa - 1, ob : ob + wb].mean())
                if oa + wa < ext[0]:
                    outside.append(occ[oa + wa, ob : ob + wb].mean())
                if ob > 0:
                    outside.append(occ[oa : oa + wa, ob - 1].mean())
                if ob + wb < ext[1]:
                    outside.append(occ[oa : oa + wa, ob + wb].mean())
                if outside and max(outside) >= line_fraction:
                    continue  # a (nearly) full line beyond the window: the board is larger than asked
                if best is None or count > best[3]:
                    best = (int(oa + lo[0]), int(ob + lo[1]), transposed, count)
    return best


def _prune_inconsistent(lat: _Lattice, check_tolerance: float, sigma: float, max_drops: int = 12) -> float:
    """Leave-one-out check of every lattice corner against its neighbours' homography prediction.

    Corners off by more than an adaptive threshold (six robust standard deviations of the board's
    own leave-one-out errors, clamped to ``[0.04, check_tolerance]`` square sizes) are dropped, worst
    first, one at a time (a wrong corner also bends its neighbours' predictions). Returns the
    threshold, which is reused to accept corners into the holes.
    """
    threshold = check_tolerance
    for it in range(max_drops + 1):
        cells, idx = lat.arrays()
        if len(idx) < 6:
            return threshold
        pred, jac = _local_homographies(cells, lat.p[idx], cells, sigma, exclude_self=True)
        spacing = np.minimum(np.linalg.norm(jac[:, :, 0], axis=1), np.linalg.norm(jac[:, :, 1], axis=1))
        err = np.linalg.norm(pred - lat.p[idx], axis=1) / (spacing + 1e-12)
        if it == 0:
            threshold = float(np.clip(6.0 * 1.4826 * np.median(err), 0.04, check_tolerance))
        worst = int(np.argmax(err))
        if err[worst] <= threshold:
            break
        del lat.cells[(int(cells[worst, 0]), int(cells[worst, 1]))]
        lat.cell_of_point[idx[worst]] = -1
    return threshold


def _board_extends(
    lat: _Lattice,
    cells: np.ndarray,
    idx: np.ndarray,
    window: tuple[int, int, int, int],
    tol: float,
    line_fraction: float,
) -> bool:
    """Whether free peaks continue the board past one of its four edges.

    The growth may have stopped short of a row (clutter, a gap), so the line just outside every edge
    is predicted from the board itself and matched against all unused peaks.
    """
    oa, ob, wa, wb = window
    a = np.arange(oa, oa + wa, dtype=np.float64)
    b = np.arange(ob, ob + wb, dtype=np.float64)
    lines = [
        np.stack([np.full(wb, oa - 1.0), b], -1),
        np.stack([np.full(wb, oa + wa + 0.0), b], -1),
        np.stack([a, np.full(wa, ob - 1.0)], -1),
        np.stack([a, np.full(wa, ob + wb + 0.0)], -1),
    ]
    query = np.concatenate(lines)
    pred, jac = _local_homographies(cells, lat.p[idx], query, lat.sigma)
    free = np.nonzero(lat.cell_of_point < 0)[0]
    if len(free) == 0:
        return False
    spacing = np.minimum(np.linalg.norm(jac[:, :, 0], axis=1), np.linalg.norm(jac[:, :, 1], axis=1))
    d = np.linalg.norm(pred[:, None, :] - lat.p[None, free, :], axis=-1).min(1) / (spacing + 1e-12)
    # extrapolating one line out is less precise than interpolating: allow the growth tolerance
    hit = d < max(tol, 0.5 * lat.tol)
    start = 0
    for line in lines:
        if hit[start : start + len(line)].mean() >= line_fraction:
            return True
        start += len(line)
    return False


def _square_contrast(image: np.ndarray, h: np.ndarray, cols: int, rows: int) -> float:
    """Mean brightness of the squares that should be light minus those that should be dark.

    Under the colour convention (the outer square at corner 0 is dark), the inner square with
    corners ``(i, j)`` to ``(i + 1, j + 1)`` and centre ``(i + 0.5, j + 0.5)`` is dark iff ``i + j`` is even.
    Positive for a labelling that agrees with the image; nan when too few squares are visible.
    """
    j, i = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    centres = np.stack([i.ravel() + 0.5, j.ravel() + 0.5], -1).astype(np.float64)
    dark = ((i + j) % 2 == 0).ravel()
    xy = np.round(_apply_h(h, centres)).astype(np.int64)
    height, width = image.shape
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    if (inside & dark).sum() == 0 or (inside & ~dark).sum() == 0:
        return float("nan")
    values = image[xy[inside, 1], xy[inside, 0]]
    return float(values[~dark[inside]].mean() - values[dark[inside]].mean())


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
) -> tuple[np.ndarray, np.ndarray, bool]:
    n_board = cols * rows
    corners = np.zeros((n_board, 2))
    valid = np.zeros(n_board, dtype=bool)
    min_count = max(4, int(math.ceil(min_fraction * n_board)))
    if len(p) < min_count or len(p) < 5:
        return corners, valid, False
    dist = np.linalg.norm(p[:, None] - p[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    seeds = _cross_seeds(p, dist, min(8, len(p) - 1))
    tried_points = np.zeros(len(p), dtype=bool)
    attempts = 0
    for seed in seeds:
        if attempts >= max_seeds:
            break
        if tried_points[seed[0]]:
            continue  # this seed lies in a lattice that already failed: it would grow the same lattice
        lat = _Lattice(p, seed, cols + rows + 2, tol, sigma)
        # a real cross also has its diagonal neighbours; a false peak near the board can pair up
        # true corners into a "cross" that would grow a dislocated lattice
        cross_cells, cross_idx = lat.arrays()
        if lat.match(_DIAGONALS, cross_cells, cross_idx) < 2:
            continue
        attempts += 1
        lat.grow()
        cells, idx = lat.arrays()
        tried_points[idx] = True
        basis = _board_basis(cells)
        cells = cells @ basis.T
        lat.cells = {(int(c[0]), int(c[1])): int(i) for c, i in zip(cells, idx)}
        win = _select_window(cells, cols, rows, min_count, line_fraction)
        if win is None:
            continue
        oa, ob, transposed, _ = win
        wa, wb = (rows, cols) if transposed else (cols, rows)
        inside = (cells[:, 0] >= oa) & (cells[:, 0] < oa + wa) & (cells[:, 1] >= ob) & (cells[:, 1] < ob + wb)
        # restart the bookkeeping with the window only
        lat.cells = {(int(c[0]), int(c[1])): int(i) for c, i in zip(cells[inside], idx[inside])}
        lat.cell_of_point[:] = -1
        lat.cell_of_point[idx[inside]] = 1
        # drop corners that disagree with their neighbours, then fill the holes with full support
        n_window = len(lat.cells)
        strict = _prune_inconsistent(lat, check_tolerance, sigma)
        if n_window - len(lat.cells) > max(2, 0.1 * n_window):
            continue  # many corners disagree with their neighbours: not one consistent board
        all_cells = np.stack(np.meshgrid(np.arange(oa, oa + wa), np.arange(ob, ob + wb), indexing="ij"), -1)
        all_cells = all_cells.reshape(-1, 2).astype(np.float64)
        for _ in range(2):
            cells, idx = lat.arrays()
            missing = np.array([c for c in all_cells if (int(c[0]), int(c[1])) not in lat.cells]).reshape(-1, 2)
            if lat.match(missing, cells, idx, strict) == 0:
                break
        _prune_inconsistent(lat, check_tolerance, sigma)
        cells, idx = lat.arrays()
        if len(idx) < min_count:
            continue
        if _board_extends(lat, cells, idx, (oa, ob, wa, wb), strict, line_fraction):
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
            h = _fit_homography(t, xy)
            corner0 = _apply_h(h, origin)[0]
            options.append((float(corner0.sum()), t, h))  # x + y of corner 0: smallest is top-left
        if not options:  # degenerate fit
            continue
        options.sort(key=lambda o: o[0])
        chosen = options[0]
        if image is not None and not is_symmetric_board((cols, rows)) and len(options) >= 2:
            # the outer square at corner 0 is dark by convention, so is every inner square whose
            # corner with the lowest (i, j) has i + j even; the 180-degree labelling sees the opposite
            contrast = _square_contrast(image, options[0][2], cols, rows)
            if np.isfinite(contrast) and abs(contrast) > 0.05:
                chosen = options[0] if contrast > 0 else options[1]
        _, t, h = chosen
        n_idx = (t[:, 1] * cols + t[:, 0]).round().astype(np.int64)
        # holes get the homography prediction (marked invalid) so callers have a usable guess
        grid_ij = np.stack(np.meshgrid(np.arange(cols), np.arange(rows), indexing="xy"), -1).reshape(-1, 2)
        corners = _apply_h(h, grid_ij.astype(np.float64))
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

    Returns:
        - corners :math:`(B, N, 2)`, ``N = cols*rows``, grid order ``n = j*cols + i``; cells without a
          peak hold the board homography's prediction, boards not found hold zeros;
        - valid :math:`(B, N)` bool, True where a peak was assigned;
        - found :math:`(B,)` bool.

    Example:
        >>> from ccs_kornia.camera import board_object_points
        >>> pts = board_object_points(4, 3)[:, :2] * 20 + 10
        >>> perm = torch.randperm(12)
        >>> corners, valid, found = organize_grid(pts[perm][None], torch.ones(1, 12, dtype=torch.bool), (4, 3))
        >>> bool(found[0]), bool(valid.all()), torch.allclose(corners[0], pts)
        (True, True, True)
    """
    if points.dim() != 3 or points.shape[-1] != 2:
        raise ValueError(f"points must be (B, M, 2), got {tuple(points.shape)}.")
    if mask.shape != points.shape[:2]:
        raise ValueError(f"mask must be (B, M) = {tuple(points.shape[:2])}, got {tuple(mask.shape)}.")
    cols, rows = _check_board_size(board_size)
    if image is not None and (image.dim() != 4 or image.shape[0] != points.shape[0]):
        raise ValueError(f"image must be (B, C, H, W) with B = {points.shape[0]}, got {tuple(image.shape)}.")
    if not 0.0 < tolerance < 0.5 or not 0.0 < check_tolerance < 0.5:
        raise ValueError(f"tolerances must be in (0, 0.5) square sizes, got {tolerance}, {check_tolerance}.")
    bsz, n_board = points.shape[0], cols * rows
    pts_np = points.detach().to("cpu", torch.float64).numpy()
    mask_np = mask.detach().to("cpu", torch.bool).numpy()
    mask_np = mask_np & np.isfinite(pts_np).all(-1)
    img_np = None
    if image is not None:
        img_np = image.detach().to("cpu", torch.float64).mean(1).numpy()
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
        self.board_size = _check_board_size(board_size)
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


# ----------------------------------------------------------------------------------------------
# Collinearity refinement (batched torch)
# ----------------------------------------------------------------------------------------------


def _fit_lines(pts: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted total-least-squares lines along dim -2.

    Args:
        pts: (..., L, 2) points; w: (..., L) weights.

    Returns:
        unit normals (..., 2) and offsets (...,) with ``normal . x = offset`` on the line.
    """
    wsum = w.sum(-1, keepdim=True).clamp_min(1e-12)
    mean = (w.unsqueeze(-1) * pts).sum(-2) / wsum
    d = pts - mean.unsqueeze(-2)
    sxx = (w * d[..., 0] ** 2).sum(-1)
    syy = (w * d[..., 1] ** 2).sum(-1)
    sxy = (w * d[..., 0] * d[..., 1]).sum(-1)
    # principal direction of the 2x2 scatter matrix in closed form
    theta = 0.5 * torch.atan2(2.0 * sxy, sxx - syy)
    normal = torch.stack([-torch.sin(theta), torch.cos(theta)], -1)
    return normal, (normal * mean).sum(-1)


def _concurrent_lines(
    pts: torch.Tensor, w: torch.Tensor, normal: torch.Tensor, offset: torch.Tensor, line_w: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Refit a family of lines (all rows, or all columns, of each board) through one common point.

    Under a homography (no distortion) the rows of a board meet in one vanishing point, and so do the
    columns. The point is the least-squares meeting point of the free lines (homogeneous, so it may
    lie at infinity); each line is then refitted through it, leaving one free parameter per line
    instead of two, which steadies lines with few or clustered corners.

    Args:
        pts: (B, L, K, 2) points of each line; w: (B, L, K) weights.
        normal, offset: (B, L, 2), (B, L) free lines ``normal . x = offset``.
        line_w: (B, L) weight of each line in the meeting-point estimate (0 for undefined lines).

    Returns:
        unit normals (B, L, 2) and offsets (B, L) of the concurrent lines.
    """
    lines = torch.cat([normal, -offset.unsqueeze(-1)], -1)  # (B, L, 3), homogeneous
    scatter = torch.einsum("bl,bli,blj->bij", line_w, lines, lines)
    _, vecs = torch.linalg.eigh(scatter)
    basis = vecs[..., 1:]  # (B, 3, 2): lines through the meeting point are l = basis @ a
    hom = torch.cat([pts, torch.ones_like(pts[..., :1])], -1)  # (B, L, K, 3)
    m3 = torch.einsum("blk,blki,blkj->blij", w, hom, hom)
    m = basis.transpose(-1, -2).unsqueeze(1) @ m3 @ basis.unsqueeze(1)  # (B, L, 2, 2)
    e2 = basis[:, :2, :]
    n = (e2.transpose(-1, -2) @ e2).unsqueeze(1).expand_as(m)  # |normal|^2 = a^T n a
    # smallest root of det(m - lambda n) = 0 (generalised 2x2 eigenproblem), stable form
    qa = n[..., 0, 0] * n[..., 1, 1] - n[..., 0, 1] ** 2
    qb = m[..., 0, 0] * n[..., 1, 1] + m[..., 1, 1] * n[..., 0, 0] - 2.0 * m[..., 0, 1] * n[..., 0, 1]
    qc = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] ** 2
    disc = (qb**2 - 4.0 * qa * qc).clamp_min(1e-30)
    lam = 2.0 * qc / (qb + torch.sqrt(disc)).clamp_min(1e-30)
    r = m - lam[..., None, None] * n
    # null vector of the (singular) 2x2 matrix r, from whichever row is better conditioned
    a0 = torch.stack([-r[..., 0, 1], r[..., 0, 0]], -1)
    a1 = torch.stack([-r[..., 1, 1], r[..., 1, 0]], -1)
    a = torch.where((a0.norm(dim=-1) >= a1.norm(dim=-1)).unsqueeze(-1), a0, a1)
    line = (basis.unsqueeze(1) @ a.unsqueeze(-1))[..., 0]  # (B, L, 3)
    scale = line[..., :2].norm(dim=-1, keepdim=True).clamp_min(1e-12)
    line = line / scale
    return line[..., :2], -line[..., 2]


def collinearity_refine(
    corners: torch.Tensor,
    valid: torch.Tensor,
    board_size: tuple[int, int],
    iterations: int = 2,
    min_points: int = 3,
    blend: float = 1.0,
    concurrent: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Refine organised corners by fitting straight rows and columns and intersecting them.

    The paper's collineation post-processing. Every row ``j`` (``cols`` corners) and every column
    ``i`` (``rows`` corners) gets a total-least-squares line fitted to its valid corners (all lines of
    all boards at once, closed-form 2x2 eigenvector); each corner becomes the intersection of its
    row and column lines, which also recovers corners that are missing. With ``iterations > 1`` the
    fits are repeated with Cauchy weights on each corner's distance to its lines, so a single bad
    corner cannot bend its row and column.

    .. note:: Straight lines assume an image **without distortion** (the paper removes distortion
       first); on a distorted image this pulls corners off their true (curved) rows.

    Args:
        corners: :math:`(B, N, 2)` corners in grid order ``n = j*cols + i``.
        valid: :math:`(B, N)` bool, which corners were measured.
        board_size: ``(cols, rows)``.
        iterations: line fits (1: plain least squares; more: robust reweighting).
        min_points: a line is defined by at least this many valid corners (2 works, 3 is safer).
        blend: weight of the line intersection against the measured position for measured corners
            (1.0: the intersection, as in the paper; missing corners always take the intersection).
        concurrent: also make all rows meet in one (vanishing) point and all columns in another, as
            they do in a perspective image; much steadier lines for rows/columns with few corners,
            at the price of assuming the perspective model more strictly (``False``: the paper's
            independent lines).

    Returns:
        refined corners :math:`(B, N, 2)` and valid :math:`(B, N)` (measured, or both lines defined).

    Example:
        >>> from ccs_kornia.camera import board_object_points
        >>> pts = board_object_points(5, 4)[:, :2][None] * 30 + 20
        >>> valid = torch.ones(1, 20, dtype=torch.bool); valid[0, 7] = False
        >>> refined, ok = collinearity_refine(pts + 0.1 * torch.randn_like(pts), valid, (5, 4))
        >>> bool(ok.all()), bool((refined - pts).norm(dim=-1).max() < 0.5)
        (True, True)
    """
    if corners.dim() != 3 or corners.shape[-1] != 2:
        raise ValueError(f"corners must be (B, N, 2), got {tuple(corners.shape)}.")
    cols, rows = _check_board_size(board_size)
    if corners.shape[1] != cols * rows:
        raise ValueError(f"corners hold {corners.shape[1]} points, board {cols}x{rows} needs {cols * rows}.")
    if valid.shape != corners.shape[:2]:
        raise ValueError(f"valid must be (B, N) = {tuple(corners.shape[:2])}, got {tuple(valid.shape)}.")
    if iterations < 1 or min_points < 2:
        raise ValueError(f"iterations must be >= 1 and min_points >= 2, got {iterations}, {min_points}.")
    if not 0.0 <= blend <= 1.0:
        raise ValueError(f"blend must be in [0, 1], got {blend}.")
    bsz = corners.shape[0]
    measured = corners.reshape(bsz, rows, cols, 2)
    vmask = valid.reshape(bsz, rows, cols)
    # zero the unmeasured entries so padding values (nan, garbage) cannot leak into sums or gradients
    grid = torch.where(vmask.unsqueeze(-1), measured, torch.zeros_like(measured))
    base_w = vmask.to(corners.dtype)
    # work in board-normalised coordinates (centred, unit RMS radius): well-conditioned homogeneous lines
    count = base_w.sum((1, 2)).clamp_min(1.0)[:, None, None, None]
    centre = (grid * base_w.unsqueeze(-1)).sum((1, 2), keepdim=True) / count
    spread = ((((grid - centre) ** 2).sum(-1) * base_w).sum((1, 2)) / count[..., 0, 0, 0]).sqrt()
    spread = spread.clamp_min(1e-9)[:, None, None, None]
    grid = torch.where(vmask.unsqueeze(-1), (grid - centre) / spread, torch.zeros_like(grid))
    row_ok = vmask.sum(2) >= min_points  # (B, rows)
    col_ok = vmask.sum(1) >= min_points  # (B, cols)
    weight = base_w
    for it in range(iterations):
        n_row, c_row = _fit_lines(grid, weight)  # (B, rows, 2), (B, rows)
        n_col, c_col = _fit_lines(grid.transpose(1, 2), weight.transpose(1, 2))  # (B, cols, 2), (B, cols)
        if concurrent:
            row_w = row_ok.to(grid.dtype) * weight.sum(2)
            col_w = col_ok.to(grid.dtype) * weight.sum(1)
            n_row, c_row = _concurrent_lines(grid, weight, n_row, c_row, row_w)
            n_col, c_col = _concurrent_lines(grid.transpose(1, 2), weight.transpose(1, 2), n_col, c_col, col_w)
        nr = n_row[:, :, None, :]
        cr = c_row[:, :, None]
        nc = n_col[:, None, :, :]
        cc = c_col[:, None, :]
        det = nr[..., 0] * nc[..., 1] - nr[..., 1] * nc[..., 0]  # sine of the row/column angle
        det_safe = torch.where(det.abs() > 1e-6, det, torch.ones_like(det))
        x = (cr * nc[..., 1] - cc * nr[..., 1]) / det_safe
        y = (nr[..., 0] * cc - nc[..., 0] * cr) / det_safe
        inter = torch.stack([x, y], -1)  # (B, rows, cols, 2)
        if it + 1 < iterations:
            # Cauchy weights on the distance of each measured corner to its row and column lines
            r_row = (grid * nr).sum(-1) - cr
            r_col = (grid * nc).sum(-1) - cc
            res = torch.sqrt(r_row**2 + r_col**2 + 1e-18)
            masked = torch.where(vmask, res, torch.full_like(res, float("nan"))).reshape(bsz, -1)
            med = torch.nanmedian(masked, dim=1).values.nan_to_num(0.0)
            scale = (2.5 * 1.4826 * med).clamp_min(1e-6)[:, None, None]
            weight = base_w / (1.0 + (res / scale) ** 2)
    inter = inter * spread + centre
    inter_ok = row_ok[:, :, None] & col_ok[:, None, :] & (det.abs() > 1e-6)
    blended = torch.where(vmask.unsqueeze(-1), blend * inter + (1.0 - blend) * measured, inter)
    out = torch.where(inter_ok.unsqueeze(-1), blended, measured)
    return out.reshape(bsz, -1, 2), (vmask | inter_ok).reshape(bsz, -1)


class CollinearityRefiner(nn.Module):
    r"""Module wrapper of :func:`collinearity_refine` (assumes undistorted corners).

    Example:
        >>> ref = CollinearityRefiner((4, 3))
        >>> c, v = ref(torch.rand(2, 12, 2), torch.ones(2, 12, dtype=torch.bool))
        >>> c.shape, v.shape
        (torch.Size([2, 12, 2]), torch.Size([2, 12]))
    """

    def __init__(
        self,
        board_size: tuple[int, int],
        iterations: int = 2,
        min_points: int = 3,
        blend: float = 1.0,
        concurrent: bool = True,
    ) -> None:
        super().__init__()
        self.board_size = _check_board_size(board_size)
        self.iterations = iterations
        self.min_points = min_points
        self.blend = blend
        self.concurrent = concurrent

    def forward(self, corners: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return collinearity_refine(
            corners, valid, self.board_size, self.iterations, self.min_points, self.blend, self.concurrent
        )

    def extra_repr(self) -> str:
        return f"board_size={self.board_size}, iterations={self.iterations}, blend={self.blend}"


def predict_missing_corners(
    corners: torch.Tensor, valid: torch.Tensor, board_size: tuple[int, int], passes: int = 3
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Predict invalid grid cells from their row and column neighbours (local, so it follows distortion).

    Each missing cell takes the mean of every available estimate: the midpoint of its two neighbours
    along a row or column, and the quadratic extrapolation ``3 p_1 - 3 p_2 + p_3`` from the three next
    cells on either side along a row or column (linear ``2 p_1 - p_2`` when only two exist). A global
    board homography cannot follow strong barrel distortion near the image border; these local
    estimates can. Chains of missing cells fill over successive passes.

    Args:
        corners: :math:`(B, N, 2)` grid-ordered corners, ``N = cols * rows``.
        valid: :math:`(B, N)` bool.
        board_size: ``(cols, rows)``.
        passes: filling passes.

    Returns:
        corners with predictions written into the missing cells, and the mask of cells that now hold a
        measured or predicted position.

    Example:
        >>> from ccs_kornia.camera import board_object_points
        >>> pts = board_object_points(4, 3)[None, :, :2] * 10
        >>> valid = torch.ones(1, 12, dtype=torch.bool); valid[0, 0] = False
        >>> out, filled = predict_missing_corners(pts * valid[..., None], valid, (4, 3))
        >>> bool(filled.all()), torch.allclose(out, pts)
        (True, True)
    """
    cols, rows = _check_board_size(board_size)
    if corners.dim() != 3 or corners.shape[1] != cols * rows or valid.shape != corners.shape[:2]:
        raise ValueError(f"corners must be (B, {cols * rows}, 2) with a matching valid mask, got {tuple(corners.shape)}.")
    b = corners.shape[0]
    g = corners.reshape(b, rows, cols, 2).clone()
    v = valid.reshape(b, rows, cols).clone()

    def shifted(x: torch.Tensor, k: int, dim: int) -> torch.Tensor:
        # value of the cell k steps further along ``dim`` (zero / False beyond the board)
        out = torch.zeros_like(x)
        n = x.shape[dim]
        if abs(k) >= n:
            return out
        src = x.narrow(dim, max(k, 0), n - abs(k))
        out.narrow(dim, max(-k, 0), n - abs(k)).copy_(src)
        return out

    for _ in range(passes):
        if bool(v.all()):
            break
        total = torch.zeros_like(g)
        count = torch.zeros(g.shape[:-1], dtype=g.dtype, device=g.device)
        for dim in (1, 2):  # rows (along j) and columns (along i)
            for sgn in (1, -1):
                p1, v1 = shifted(g, sgn, dim), shifted(v, sgn, dim)
                p2, v2 = shifted(g, 2 * sgn, dim), shifted(v, 2 * sgn, dim)
                p3, v3 = shifted(g, 3 * sgn, dim), shifted(v, 3 * sgn, dim)
                quad = v1 & v2 & v3
                lin = v1 & v2 & ~v3
                est = torch.where(quad[..., None], 3 * p1 - 3 * p2 + p3, 2 * p1 - p2)
                use = quad | lin
                total = total + est * use[..., None]
                count = count + use
            pa, va = shifted(g, 1, dim), shifted(v, 1, dim)
            pb, vb = shifted(g, -1, dim), shifted(v, -1, dim)
            mid = va & vb
            # the midpoint is the most reliable estimate: count it twice
            total = total + (pa + pb) * mid[..., None]
            count = count + 2 * mid
        fill = ~v & (count > 0)
        g = torch.where(fill[..., None], total / count.clamp_min(1)[..., None], g)
        v = v | fill
    return g.reshape(b, -1, 2), v.reshape(b, -1)
