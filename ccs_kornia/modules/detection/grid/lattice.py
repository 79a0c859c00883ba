"""The point lattice behind :func:`~ccs_kornia.modules.detection.grid.grid_organizer.organize_grid` (numpy, float64).

* local homography prediction: Gaussian-weighted DLT homographies, one per query cell, all solved at once;
* seeds: peaks whose nearest neighbours form a "cross" (two non-parallel pairs of opposite neighbours);
* :class:`Lattice`: growth from a seed, one ring per round, matching the nearest free peak to each prediction;
* the board basis (undoing a sheared seed basis), the ``cols x rows`` window, the leave-one-out consistency
  check and the test that the board continues past an edge.

What the image says about a lattice (a partial board's placement, the two 180-degree orientations of a
non-symmetric board) is in :mod:`~ccs_kornia.modules.detection.grid.lattice_evidence`.

The organiser (:mod:`~ccs_kornia.modules.detection.grid.grid_organizer`, a ``cols x rows`` board) and the free lattice
of the marker boards (:mod:`~ccs_kornia.modules.detection.grid.point_lattice`, no window) are both built from these
parts; see the organiser for the method as a whole.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "DIAGONAL_OFFSETS",
    "Lattice",
    "apply_homography",
    "board_basis",
    "cross_seeds",
    "fit_lattice_homography",
    "lattice_extends",
    "local_homographies",
    "prune_inconsistent",
    "select_window",
]

# ----------------------------------------------------------------------------------------------
# Local homography prediction (numpy, float64)
# ----------------------------------------------------------------------------------------------


def _normal_equation_layout() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where each entry of the DLT normal equations comes from in the moment vector of
    :func:`local_homographies` (index 23 is a constant zero), and its sign."""
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


def local_homographies(
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


def fit_lattice_homography(grid: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Least-squares homography lattice -> image (``h33 = 1``, inhomogeneous DLT), one for the whole lattice.

    The placement of a whole board (its corner 0, its holes, the square colours) and of the lattice's cells in the
    image checks; :func:`local_homographies` are the local ones that follow residual distortion.

    Args:
        grid: (A, 2) lattice cells (float), at least four not collinear.
        pts: (A, 2) their image positions.

    Returns:
        (3, 3) homography, cells ``(u, v, 1)`` to image points.

    Example:
        >>> cells = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        >>> np.allclose(fit_lattice_homography(cells, 20 * cells + 5), [[20, 0, 5], [0, 20, 5], [0, 0, 1]])
        True
    """
    u, v = grid[:, 0], grid[:, 1]
    x, y = pts[:, 0], pts[:, 1]
    z, o = np.zeros_like(u), np.ones_like(u)
    a = np.concatenate(
        [np.stack([u, v, o, z, z, z, -x * u, -x * v], -1), np.stack([z, z, z, u, v, o, -y * u, -y * v], -1)], 0
    )
    h = np.linalg.lstsq(a, np.concatenate([x, y]), rcond=None)[0]
    return np.append(h, 1.0).reshape(3, 3)


def apply_homography(h: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Points ``grid`` (A, 2) through the homography ``h`` (3, 3), (A, 2): where a lattice fit puts its cells.

    Example:
        >>> apply_homography(np.diag([2.0, 2.0, 1.0]), np.array([[1.0, 3.0]])).tolist()
        [[2.0, 6.0]]
    """
    q = np.concatenate([grid, np.ones((len(grid), 1))], 1) @ h.T
    return q[:, :2] / q[:, 2:3]


# ----------------------------------------------------------------------------------------------
# Seeds, growth, window
# ----------------------------------------------------------------------------------------------

_COS_OPPOSITE = math.cos(math.radians(12.0))  # arms of a cross are collinear up to noise
_COS_PARALLEL = math.cos(math.radians(20.0))  # the two axes of a cross must differ clearly
_MAX_ARM_RATIO = 1.8  # opposite arms differ by perspective only


def cross_seeds(p: np.ndarray, dist: np.ndarray, k: int) -> list[tuple[int, int, int, int, int, float]]:
    """Seeds of a lattice: peaks whose ``k`` nearest neighbours contain a "cross" (two non-parallel pairs of opposite,
    collinear neighbours), best first (clean crosses near the middle of the point cloud).

    Args:
        p: (n, 2) peak positions.
        dist: (n, n) their pairwise distances, ``inf`` on the diagonal.
        k: neighbours looked at (at most ``n - 1``).

    Returns:
        ``(seed, +u, -u, +v, -v, score)`` per seed: the peak, its four arms (peak indices) and the cross's score
        (lower is cleaner).
    """
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
#: the four diagonal neighbours of a cell: a real seed's cross has peaks there too (a false peak beside the board can
#: pair true corners into a cross that would grow a dislocated lattice)
DIAGONAL_OFFSETS = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])
_NEIGHBOURS8 = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]])


class Lattice:
    """Sparse integer lattice of peaks grown from a seed of :func:`cross_seeds` (one image).

    ``cells`` maps a lattice cell ``(a, b)`` to the index of its peak; positions ``p`` are normalised by the seed's
    arm length. :meth:`match` accepts the nearest free peaks to the cells a local homography predicts, :meth:`grow`
    does so ring by ring, :meth:`bridge` across a gap of empty cells.

    Args:
        p: (n, 2) peak positions.
        seed: one entry of :func:`cross_seeds`: the seed gets cell ``(0, 0)``, its arms ``(+-1, 0)``, ``(0, +-1)``.
        max_extent: growth stays within this many cells of the seed.
        tol: a peak is accepted within this fraction of the local square size of its predicted cell.
        sigma: width of the local homographies' Gaussian weights, in cells.
    """

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
        self, query: np.ndarray, support_cells: np.ndarray, support_idx: np.ndarray, tol: float | None = None,
        sigma: float | None = None,
    ) -> int:
        """Predict ``query`` cells from the support, accept the nearest free peaks; returns #added."""
        tol = self.tol if tol is None else tol
        if len(query) == 0:
            return 0
        sigma = self.sigma if sigma is None else sigma
        pred, jac = local_homographies(support_cells, self.p[support_idx], query, sigma)
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

    def bridge(self, max_side: int, min_added: int = 3) -> bool:
        """Peaks across a gap of empty cells (a glare over the board's middle splits its corners into separate
        clusters, which :meth:`grow` cannot join): every free cell of the ``max_side`` x ``max_side`` windows that hold
        the lattice, predicted by a wide-weighted homography of the whole lattice (the prediction extrapolates over the
        gap) and matched with half the growth tolerance. Kept, and grown further, only where at least ``min_added``
        peaks fit; returns whether the lattice grew."""
        cells, idx = self.arrays()
        lo, hi = cells.min(0).astype(np.int64), cells.max(0).astype(np.int64)
        if (hi - lo + 1 > max_side).any():
            return False
        a = np.arange(hi[0] - max_side + 1, lo[0] + max_side)
        b = np.arange(hi[1] - max_side + 1, lo[1] + max_side)
        grid = np.stack(np.meshgrid(a, b, indexing="ij"), -1).reshape(-1, 2)
        query = np.array([c for c in grid if (int(c[0]), int(c[1])) not in self.cells], dtype=np.float64)
        saved = dict(self.cells), self.cell_of_point.copy()
        if self.match(query.reshape(-1, 2), cells, idx, 0.5 * self.tol, sigma=float(max_side)) < min_added:
            self.cells, self.cell_of_point = saved
            return False
        self.grow()
        return True


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


def board_basis(cells: np.ndarray) -> np.ndarray:
    """Integer change of lattice basis (2, 2) that makes the grown lattice's cells (A, 2) as compact as possible.

    Seeds take their arms from nearest neighbours, and under shear and foreshortening a square's
    diagonal can be shorter than its side, so the grown basis may be a sheared one of the same point
    lattice. The board axes are the basis whose bounding box of the lattice is smallest.
    """
    t = np.einsum("kij,nj->kni", _BASES, cells)
    area = np.prod(t.max(1) - t.min(1) + 1, axis=-1)
    return _BASES[int(np.argmin(area))]


def select_window(
    cells: np.ndarray, cols: int, rows: int, min_count: int, line_fraction: float, partial: bool = False
) -> list[tuple[int, int, bool, int]]:
    """Best ``cols x rows`` windows of the lattice, as (offset_a, offset_b, transposed, count); empty if none.

    Every border line of the window must hold ``line_fraction`` of its corners, so that the window cannot slide by a
    line, and the one best window is returned. With ``partial``, a border line may be nearly empty where the lattice
    spans exactly the window in that direction (a glare over one side of the board leaves its outermost corners at
    both ends), and where the lattice is shorter than the board (a glare across it) every placement holding the whole
    lattice is returned: the image decides (:mod:`~ccs_kornia.modules.detection.grid.lattice_evidence`)."""
    lo = cells.min(0).astype(np.int64)
    ext = cells.max(0).astype(np.int64) - lo + 1
    occ = np.zeros(tuple(ext), dtype=bool)
    ci = cells.astype(np.int64) - lo
    occ[ci[:, 0], ci[:, 1]] = True
    orientations = [(cols, rows, False)] + ([(rows, cols, True)] if cols != rows else [])
    windows = []
    for wa, wb, transposed in orientations:
        if not partial and (ext[0] < wa or ext[1] < wb):
            continue
        # offsets of windows inside the lattice, or (partial, a lattice shorter than the board) holding it whole
        for oa in range(min(0, ext[0] - wa), max(0, ext[0] - wa) + 1):
            for ob in range(min(0, ext[1] - wb), max(0, ext[1] - wb) + 1):
                sub = occ[max(oa, 0) : oa + wa, max(ob, 0) : ob + wb]
                count = int(sub.sum())
                if count < min_count:
                    continue
                borders = [] if partial and ext[0] <= wa else [sub[0].mean(), sub[-1].mean()]
                borders += [] if partial and ext[1] <= wb else [sub[:, 0].mean(), sub[:, -1].mean()]
                if borders and min(borders) < line_fraction:
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
                windows.append((int(oa + lo[0]), int(ob + lo[1]), transposed, count))
    if not windows:
        return []
    most = max(w[3] for w in windows)
    best = [w for w in windows if w[3] == most]
    return best if partial else best[:1]


def prune_inconsistent(lat: Lattice, check_tolerance: float, sigma: float, max_drops: int = 12) -> float:
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
        pred, jac = local_homographies(cells, lat.p[idx], cells, sigma, exclude_self=True)
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


def lattice_extends(
    lat: Lattice,
    cells: np.ndarray,
    idx: np.ndarray,
    window: tuple[int, int, int, int],
    tol: float,
    line_fraction: float,
) -> bool:
    """Whether free peaks continue the board past one of its four edges (then it is a larger board than asked).

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
    pred, jac = local_homographies(cells, lat.p[idx], query, lat.sigma)
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
