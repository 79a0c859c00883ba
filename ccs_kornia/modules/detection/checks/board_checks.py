"""Checks of a detected corner grid and its canonical order (numpy, one board at a time).

* :func:`check_grid`: the corners form a plausible ``cols x rows`` lattice (no fold, turn or jump);
* :func:`check_saddles`: every corner is an X-junction of the checker pattern;
* :func:`skipped_line`: no row or column of corners was skipped (a saddle halfway between neighbours);
* :func:`board_extends`: the checker pattern does not continue past a side (a sub-board of a larger board);
* :func:`whole_board_check`: the one entry point of the learned detector's "is this one whole board?" question (the
  lattice, skipped lines, the sides);
* :func:`canonical_corner_order`: of the orderings that describe the same physical grid (reversed for
  180-degree-symmetric boards, also the 90-degree rotations for square ones) the one whose first corner is
  nearest the image's top-left corner, so every view of a set uses the same convention.

OpenCV hands us one board at a time anyway, so these run per board on the CPU.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ccs_kornia.modules.detection.grid.lattice import fit_lattice_homography
from ccs_kornia.modules.detection.grid.missing_corners import lattice_deviation
from ccs_kornia.modules.detection.refine.image_noise import noise_sigma

__all__ = ["check_grid", "check_saddles", "skipped_line", "board_extends", "whole_board_check", "canonical_corner_order"]

#: where :func:`skipped_line` looks for a saddle around the midpoint of two neighbouring corners, in lattice steps
MIDPOINT_OFFSETS = (0.25, 0.1)


def check_grid(corners: np.ndarray, board_size: tuple[int, int], image_size: tuple[int, int] | None = None) -> str:
    """Check that ``corners`` form a plausible ``cols x rows`` lattice; return ``""`` or the reason.

    A perspective (and moderately distorted) view of a board keeps, along every row and column,
    steps that point the same way, turn gently and change length gradually, and all cells keep the
    same orientation. False positives and mis-ordered detections break one of these.

    Args:
        corners: :math:`(N, 2)` corners in grid order.
        board_size: ``(cols, rows)``.
        image_size: ``(W, H)``; corners outside the image are rejected when given.
    """
    cols, rows = board_size
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if pts.shape[0] != cols * rows:
        return f"expected {cols * rows} corners, got {pts.shape[0]}"
    if not np.isfinite(pts).all():
        return "non-finite corner coordinates"
    if image_size is not None:
        w, h = image_size
        if (pts[:, 0] < -0.5).any() or (pts[:, 1] < -0.5).any() or (pts[:, 0] > w - 0.5).any() or (pts[:, 1] > h - 0.5).any():
            return "corner outside the image"
    grid = pts.reshape(rows, cols, 2)
    for name, steps in (("row", grid[:, 1:] - grid[:, :-1]), ("column", (grid[1:] - grid[:-1]).transpose(1, 0, 2))):
        # steps: (lines, steps per line, 2)
        length = np.linalg.norm(steps, axis=-1)
        if (length < 1.0).any():
            return f"two neighbouring corners along a {name} coincide"
        if steps.shape[1] >= 2:
            a, b = steps[:, 1:], steps[:, :-1]
            cos = (a * b).sum(-1) / (length[:, 1:] * length[:, :-1])
            if (cos < 0.7).any():
                return f"a {name} of corners turns by more than 45 degrees"
            ratio = length[:, 1:] / length[:, :-1]
            if (ratio > 2.0).any() or (ratio < 0.5).any():
                return f"corner spacing along a {name} jumps by more than 2x"
    # every cell must keep the orientation of the board (no fold, no flip)
    u = grid[:-1, 1:] - grid[:-1, :-1]
    v = grid[1:, :-1] - grid[:-1, :-1]
    cross = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    if not ((cross > 0).all() or (cross < 0).all()):
        return "the corner lattice folds over itself"
    return ""


def _sample(image: np.ndarray, points: np.ndarray, radius: float) -> np.ndarray:
    """Mean intensity in small boxes around ``points`` (K, 2); NaN where the box leaves the image or a point is not
    finite (the hidden corners of a partial board)."""
    h, w = image.shape
    r = max(1, int(round(radius)))
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = np.where(np.isfinite(pts).all(-1, keepdims=True), pts, -float(r) - 1.0)
    out = np.full(pts.shape[0], np.nan)
    xi, yi = np.rint(pts[:, 0]).astype(np.int64), np.rint(pts[:, 1]).astype(np.int64)
    inside = (xi - r >= 0) & (yi - r >= 0) & (xi + r < w) & (yi + r < h)
    if inside.any():
        off = np.arange(-r, r + 1)
        boxes = image[yi[inside, None, None] + off[None, :, None], xi[inside, None, None] + off[None, None, :]]
        out[inside] = boxes.reshape(boxes.shape[0], -1).mean(-1)
    return out


def board_extends(image: np.ndarray, corners: np.ndarray, board_size: tuple[int, int]) -> str:
    """Return the side (``"left"``, ...) where the checker pattern continues past the grid, or ``""``.

    Beyond the outermost corners of a true board lies its outermost row of squares and then a
    uniform margin. One step further out along the lattice, the two squares that would lie outside
    therefore have the same colour; on a larger board they alternate like those inside. The test
    compares the contrast between the two outer squares with that between the two inner ones at
    every point along each side.

    Args:
        image: grey ``H x W`` image.
        corners: :math:`(N, 2)` corners in grid order.
        board_size: ``(cols, rows)``.
    """
    cols, rows = board_size
    grid = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    img = np.asarray(image, dtype=np.float32)  # no copy of a float32 image (24 Mpx: 96 MB)
    sides = {
        "top": (grid[0], grid[1]),
        "bottom": (grid[-1], grid[-2]),
        "left": (grid[:, 0], grid[:, 1]),
        "right": (grid[:, -1], grid[:, -2]),
    }
    for side, (edge, inner) in sides.items():
        out = edge - inner  # one lattice step outwards
        along = np.gradient(edge, axis=0)  # one lattice step along the side
        virtual = edge + out  # where the next corner would be on a larger board
        step = np.minimum(np.linalg.norm(out, axis=1), np.linalg.norm(along, axis=1))
        radius = max(1.0, 0.08 * float(np.median(step)))
        # quadrant samples close to the virtual corner: robust to foreshortening and bending
        outer_a, outer_b, inner_a, inner_b = _sample_quadrants(
            img, [virtual + 0.3 * out + 0.3 * along, virtual + 0.3 * out - 0.3 * along,
                  virtual - 0.3 * out + 0.3 * along, virtual - 0.3 * out - 0.3 * along], radius)
        d_out, d_in = np.abs(outer_a - outer_b), np.abs(inner_a - inner_b)
        ok = np.isfinite(d_out) & np.isfinite(d_in) & (d_in > 0.05 * max(float(img.max() - img.min()), 1e-6))
        if ok.sum() < max(2, (len(edge) + 1) // 2):
            continue  # the side runs out of the image or has no contrast: cannot tell
        ratio = d_out[ok] / d_in[ok]
        # on a larger board the outer squares alternate like the inner ones (ratio ~ 1) and the
        # colours flip across the side; on a margin they are equal (ratio ~ 0)
        flips = np.sign(outer_a[ok] - outer_b[ok]) == -np.sign(inner_a[ok] - inner_b[ok])
        if np.median(ratio) > 0.5 and (flips & (ratio > 0.4)).mean() > 0.7:
            return side
    return ""


def check_saddles(image: np.ndarray, corners: np.ndarray, board_size: tuple[int, int], max_ratio: float = 1.0) -> str:
    """Check that the corners are X-junctions of the checker pattern; return ``""`` or the reason.

    Around a true inner corner the four squares alternate (diagonal squares equal, neighbouring
    ones different). The classic detector sometimes adds a line of points on the board's outer edge
    (three squares of one colour meet there), which this rejects. For every corner the quadrant
    means ``a, b, c, d`` (in turn around it) give the saddle strength ``s = |a + c - b - d| / 2`` and
    the asymmetry ``e = max(|a - c|, |b - d|)``; a corner fails when ``e > max_ratio * s``. A few
    failures happen on real photographs (glare, blur), so the view is rejected only when most of an
    outer row/column fails, or more than a quarter of all corners.

    Args:
        image: grey ``H x W`` image.
        corners: :math:`(N, 2)` corners in grid order.
        board_size: ``(cols, rows)``.
        max_ratio: asymmetry allowed relative to the saddle strength.
    """
    cols, rows = board_size
    grid = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    img = np.asarray(image, dtype=np.float32)  # no copy of a float32 image (24 Mpx: 96 MB)
    u, v, radius, (a, b, c, d) = _corner_quadrants(img, grid)
    strength = np.abs(a + c - b - d) / 2
    asym = np.maximum(np.abs(a - c), np.abs(b - d))
    judged = np.isfinite(strength) & np.isfinite(asym)
    # halfway between neighbouring corners lies a square's edge (no saddle); a saddle there means
    # the lattice skipped a row or column of corners
    reference = float(np.nanmedian(strength)) if judged.any() else 0.0
    reason = _skipped(img, grid, u, v, radius, reference)
    if reason:
        return reason
    fails = (judged & (asym > max_ratio * np.maximum(strength, 1e-6))).reshape(rows, cols)
    judged = judged.reshape(rows, cols)
    lines = {"top": np.s_[0, :], "bottom": np.s_[-1, :], "left": np.s_[:, 0], "right": np.s_[:, -1]}
    for side, index in lines.items():
        n_judged, n_fail = int(judged[index].sum()), int(fails[index].sum())
        if n_fail >= 2 and n_fail >= 0.75 * n_judged:
            return f"the corners along the {side} side are not chessboard corners (false or shifted detection)"
    if fails.sum() > 0.25 * max(int(judged.sum()), 1):
        return f"{int(fails.sum())} of {int(judged.sum())} points are not chessboard corners"
    return ""


def _lattice_steps(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steps ``u, v`` (rows, cols, 2) along the rows and columns of a ``rows x cols x 2`` grid whose hidden corners
    are NaN: the mean of the steps to the measured neighbours (``np.gradient`` on a whole board), and at measured
    corners with no measured neighbour along a direction the derivative of the homography fitted to the measured
    corners. Without that fallback a partial board whose hidden corners alternate with its measured ones (a lattice
    through every other corner of the board, half its corners 'hidden' off the board, as on ChArUco renders:
    ``docs/measurements.md``) has no step anywhere, and no test of it can run."""
    steps = []
    for axis in (1, 0):
        fwd = np.diff(grid, axis=axis)
        pad = [(0, 0)] * 3
        pad[axis] = (0, 1)
        ahead = np.pad(fwd, pad, constant_values=np.nan)
        pad[axis] = (1, 0)
        behind = np.pad(fwd, pad, constant_values=np.nan)
        both = np.stack([ahead, behind])
        count = np.isfinite(both).all(-1).sum(0)[..., None]
        steps.append(np.where(count > 0, np.nansum(both, 0) / np.maximum(count, 1), np.nan))
    u, v = steps
    measured = np.isfinite(grid).all(-1)
    gap = measured & ~(np.isfinite(u).all(-1) & np.isfinite(v).all(-1))
    if gap.any() and measured.sum() >= 4:
        rows, cols = np.nonzero(measured)
        h = fit_lattice_homography(np.stack([cols, rows], -1).astype(np.float64), grid[measured])
        gr, gc = np.nonzero(gap)
        q = np.stack([gc, gr, np.ones_like(gc)], -1).astype(np.float64) @ h.T
        p = q[:, :2] / q[:, 2:]
        # d(x, y)/d(col) and d(x, y)/d(row) of the homography at each corner
        du = (h[:2, 0][None] - p * h[2, 0]) / q[:, 2:]
        dv = (h[:2, 1][None] - p * h[2, 1]) / q[:, 2:]
        u[gr, gc] = np.where(np.isfinite(u[gr, gc]), u[gr, gc], du)
        v[gr, gc] = np.where(np.isfinite(v[gr, gc]), v[gr, gc], dv)
    return u, v


def _corner_quadrants(img: np.ndarray, grid: np.ndarray) -> tuple:
    """Lattice steps ``u, v`` (rows, cols, 2; :func:`_lattice_steps`), the box radius and the quadrant means ``a, b,
    c, d`` (in turn around every corner, 0.3 of a step out along both lattice directions) of a ``rows x cols x 2``
    grid."""
    u, v = _lattice_steps(grid)
    step = np.minimum(np.linalg.norm(u, axis=-1), np.linalg.norm(v, axis=-1))
    radius = max(1.0, 0.08 * float(np.median(step)))
    p, uf, vf = grid.reshape(-1, 2), u.reshape(-1, 2), v.reshape(-1, 2)
    quadrants = _sample_quadrants(img, [p + su * 0.3 * uf + sv * 0.3 * vf for su, sv in _QUADRANTS], radius)
    return u, v, radius, quadrants


#: the quadrants around a corner, in turn: signs of the steps along ``u`` and ``v``
_QUADRANTS = ((1, 1), (-1, 1), (-1, -1), (1, -1))


def _sample_quadrants(img: np.ndarray, points: list[np.ndarray], radius: float) -> list[np.ndarray]:
    """:func:`_sample` of each array of ``points`` in one call (the same values; a board's checks sample two dozen
    small sets of points, and each call's overhead outweighed its work)."""
    flat = _sample(img, np.concatenate(points), radius)
    return np.split(flat, np.cumsum([len(x) for x in points])[:-1])


def _saddle_strength(img: np.ndarray, points: np.ndarray, u: np.ndarray, v: np.ndarray, out: float,
                     radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Saddle strength ``|a + c - b - d| / 2`` and asymmetry ``max(|a - c|, |b - d|)`` of the quadrant means
    ``a, b, c, d`` sampled ``out`` lattice steps ``u, v`` (N, 2) from ``points`` (N, 2)."""
    a, b, c, d = _sample_quadrants(img, [points + su * out * u + sv * out * v for su, sv in _QUADRANTS], radius)
    return np.abs(a + c - b - d) / 2, np.maximum(np.abs(a - c), np.abs(b - d))


def _skipped(img: np.ndarray, grid: np.ndarray, u: np.ndarray, v: np.ndarray, radius: float, reference: float) -> str:
    """:func:`skipped_line` on the quadrant geometry of :func:`_corner_quadrants` (``reference``: the median corner
    strength there).

    The midpoints are looked at a quarter of a step out (against ``reference``) and a tenth (against the corners'
    median strength a tenth of a step out): on a board with marks inside the white squares (ChArUco) the quarter
    step of a lattice through every other corner (half a square) can land on the marks, the tenth lies on the
    white margin around them (``docs/measurements.md``)."""
    for out in MIDPOINT_OFFSETS:
        ref = reference
        if out != MIDPOINT_OFFSETS[0]:
            near = _saddle_strength(img, grid.reshape(-1, 2), u.reshape(-1, 2), v.reshape(-1, 2), out, radius)[0]
            ref = float(np.nanmedian(near)) if np.isfinite(near).any() else 0.0
        if not ref > 0:
            continue
        # the midpoints along the rows, then along the columns, sampled in one call
        axes = [(axis, name) for axis, name in ((1, "row"), (0, "column")) if grid.shape[axis] >= 2]
        mids = [[0.5 * (x.take(range(x.shape[axis] - 1), axis) + x.take(range(1, x.shape[axis]), axis)).reshape(-1, 2)
                 for x in (grid, u, v)] for axis, _ in axes]
        if not mids:
            continue
        strength, asym = _saddle_strength(img, *(np.concatenate([m[k] for m in mids]) for k in range(3)), out, radius)
        start = 0
        for (_, name), (mid, _, _) in zip(axes, mids):
            s, a = strength[start:start + len(mid)], asym[start:start + len(mid)]
            start += len(mid)
            saddle = (s > 0.5 * ref) & (a < s)
            # the noise's margin is measured only where a midpoint reads as a saddle at all
            if saddle.any() and (saddle & (a < s - _noise_margin(img, grid, radius))).any():
                return f"the grid skips a {name} of corners (a corner lies between two detected neighbours)"
    return ""


def _noise_margin(img: np.ndarray, grid: np.ndarray, radius: float) -> float:
    """How far a midpoint's saddle strength must exceed its asymmetry to count (:func:`_skipped`): two standard
    deviations of their difference where the quadrant means (boxes of ``2 r + 1`` px a side) carry the image's noise
    (:func:`~ccs_kornia.modules.detection.refine.image_noise.noise_sigma` over the board's bounding box). On a
    photograph taken in the dark the boxes of a tenth of a step (1 px on a foreshortened board) make a square's edge
    read as a saddle; on a photograph in good light the margin is a fraction of a grey level."""
    h, w = img.shape
    pts = grid.reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(-1)]
    x0, y0 = np.clip(np.floor(pts.min(0)).astype(int), 0, None)
    x1, y1 = np.minimum(np.ceil(pts.max(0)).astype(int) + 1, (w, h))
    if x1 - x0 < 3 or y1 - y0 < 3:
        return 0.0
    r = max(1, int(round(radius)))
    sigma = float(noise_sigma(torch.from_numpy(np.ascontiguousarray(img[y0:y1, x0:x1]))[None, None])[0])
    return 2.0 * math.sqrt(3.0) * sigma / (2 * r + 1)


def skipped_line(image: np.ndarray, corners: np.ndarray, board_size: tuple[int, int]) -> str:
    """Return ``""``, or the reason when the grid skipped a row or column of corners.

    Halfway between two neighbouring corners of a board lies a square's edge, not a saddle. Where a saddle at least
    half as strong as the board's median corner lies there, the grid joined every other corner of a finer lattice
    (a grid of lines, a finer checker pattern). This is the part of :func:`check_saddles` that holds on every true
    board, boards with marks inside the white squares included (the X-junction test itself refuses a third of
    those).

    Args:
        image: grey ``H x W`` image.
        corners: :math:`(N, 2)` corners in grid order.
        board_size: ``(cols, rows)``.

    Example:
        >>> yy, xx = np.mgrid[:96, :96]
        >>> img = ((xx // 16 + yy // 16) % 2).astype(np.float32)  # squares of 16 px, corners at 15.5 + 16 k
        >>> skipped_line(img, np.array([[31.5, 31.5], [47.5, 31.5], [31.5, 47.5], [47.5, 47.5]]), (2, 2))
        ''
        >>> skipped_line(img, np.array([[15.5, 15.5], [47.5, 15.5], [15.5, 47.5], [47.5, 47.5]]), (2, 2))
        'the grid skips a row of corners (a corner lies between two detected neighbours)'
    """
    cols, rows = board_size
    grid = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    img = np.asarray(image, dtype=np.float32)  # no copy of a float32 image (24 Mpx: 96 MB)
    u, v, radius, (a, b, c, d) = _corner_quadrants(img, grid)
    strength = np.abs(a + c - b - d) / 2
    reference = float(np.nanmedian(strength)) if np.isfinite(strength).any() else 0.0
    return _skipped(img, grid, u, v, radius, reference)


def whole_board_check(
    image: np.ndarray, corners: np.ndarray, board_size: tuple[int, int], max_deviation: float | None = None,
    skipped: bool = True, extends: bool = True,
) -> str:
    """Return ``""``, or the reason why ``corners`` are not one whole ``cols x rows`` board of ``image``.

    The checks, cheapest first, the first failure answers:

    1. with ``max_deviation``: no corner farther than that (in squares) from where its row and column neighbours put
       it (:func:`~ccs_kornia.modules.detection.grid.missing_corners.lattice_deviation`): boards from OpenCV's candidates,
       whose corners can converge onto a mark's own junctions;
    2. ``skipped``: no saddle halfway between neighbouring corners (:func:`skipped_line`): a lattice through every
       other crossing of a finer pattern;
    3. ``extends``: the checker pattern does not continue past a side (:func:`board_extends`): a sub-board. Off for a
       partial board judged on its own level (its sides are checked with the board's final corners).

    Args:
        image: grey ``H x W`` image.
        corners: :math:`(N, 2)` corners in grid order (NaN at the hidden corners of a partial board).
        board_size: ``(cols, rows)``.
        max_deviation, skipped, extends: see above.

    Example:
        >>> yy, xx = np.mgrid[:96, :96]
        >>> img = ((xx // 16 + yy // 16) % 2).astype(np.float32)  # squares of 16 px, corners at 15.5 + 16 k
        >>> grid = np.stack(np.meshgrid(np.arange(5), np.arange(5), indexing="xy"), -1).reshape(-1, 2) * 16 + 15.5
        >>> whole_board_check(img, grid, (5, 5))
        ''
        >>> whole_board_check(img, grid.reshape(5, 5, 2)[:, :4].reshape(-1, 2), (4, 5), max_deviation=0.08)
        'the checker pattern continues past its right side'
    """
    if max_deviation is not None:
        dev = float(lattice_deviation(torch.as_tensor(np.asarray(corners, dtype=np.float64))[None], board_size).max())
        if dev > max_deviation:
            return f"a corner {dev:.2f} squares off its neighbours' lattice"
    reason = skipped_line(image, corners, board_size) if skipped else ""
    if not reason and extends:
        side = board_extends(image, corners, board_size)
        if side:
            reason = f"the checker pattern continues past its {side} side"
    return reason


def canonical_corner_order(corners: np.ndarray, board_size: tuple[int, int]) -> np.ndarray:
    """Reorder a detected grid so that its first corner is the one nearest the image's top-left.

    Only orderings that describe the same physical lattice with the same handedness are considered:
    the 180-degree rotation (reversed order) always, and the 90/270-degree rotations when
    ``cols == rows``. Object points stay ``(i*s, j*s, 0)``, so every view of a set (and every
    detector) follows one convention.

    Args:
        corners: :math:`(N, 2)` corners in grid order.
        board_size: ``(cols, rows)``.

    Returns:
        :math:`(N, 2)` reordered corners.
    """
    cols, rows = board_size
    grid = np.asarray(corners).reshape(rows, cols, 2)
    candidates = [grid, grid[::-1, ::-1]]
    if cols == rows:
        candidates += [np.rot90(grid, 1, axes=(0, 1)), np.rot90(grid, 3, axes=(0, 1))]
    best = min(candidates, key=lambda g: float(np.hypot(g[0, 0, 0], g[0, 0, 1])))
    return np.ascontiguousarray(best.reshape(-1, 2))
