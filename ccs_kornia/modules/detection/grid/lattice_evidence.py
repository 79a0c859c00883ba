"""What the image says about a lattice of :mod:`~ccs_kornia.modules.detection.grid.lattice` (numpy, float64; the contrast
is :func:`~ccs_kornia.modules.detection.checks.hidden_corners.intensity_range`, the detector's one contrast measure).

* :func:`_cell_contrast`: the checker contrast at lattice cells (a quarter-square intensity range);
* :func:`empty_cell_contrast`, :func:`placement_contrast`, :func:`empty_cells_flat`: where a partial board's
  lattice, shorter than the board, sits on it: its empty cells must show no checker (a glare, an occluder), unlike
  the margin beyond the board's edge or corners that the network missed;
* :func:`square_contrast`: the square colours that tell the two 180-degree orientations of a non-symmetric board
  apart.

See :mod:`~ccs_kornia.modules.detection.grid.grid_organizer` for the method as a whole.
"""

from __future__ import annotations

import numpy as np
import torch

from ccs_kornia.modules.detection.checks.hidden_corners import intensity_range
from ccs_kornia.modules.detection.grid.lattice import (
    apply_homography,
    fit_lattice_homography,
)

__all__ = ["empty_cell_contrast", "empty_cells_flat", "placement_contrast", "square_contrast"]


def _cell_contrast(image: np.ndarray, cells: np.ndarray, pts: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Checker contrast (intensity range on a 5 x 5 grid within a quarter square along the lattice axes) at the
    lattice cells ``query`` (Q, 2), placed by a homography of the lattice ``cells`` -> ``pts``: (Q,), NaN where the
    whole grid falls outside the image."""
    if len(query) == 0:
        return np.zeros(0)
    s = np.linspace(-0.25, 0.25, 5)
    off = np.stack(np.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2)
    xy = apply_homography(fit_lattice_homography(cells, pts), (query[:, None] + off[None]).reshape(-1, 2))
    xy = xy.astype(np.float32)
    img = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32))[None, None]
    points = torch.from_numpy(xy).reshape(1, len(query), -1, 2)
    return intensity_range(img, points, outside="nan")[0].double().numpy()


def _empty_cells(cells: np.ndarray, window: tuple[int, int, bool, int], cols: int, rows: int) -> np.ndarray:
    """The cells of a ``cols x rows`` window (its origin and orientation from
    :func:`~ccs_kornia.modules.detection.grid.lattice.select_window`) that the lattice ``cells`` lacks, (E, 2)."""
    oa, ob, transposed, _ = window
    wa, wb = (rows, cols) if transposed else (cols, rows)
    grid = np.stack(np.meshgrid(np.arange(oa, oa + wa), np.arange(ob, ob + wb), indexing="ij"), -1).reshape(-1, 2)
    taken = {(int(a), int(b)) for a, b in cells}
    return np.array([c for c in grid if (int(c[0]), int(c[1])) not in taken], dtype=np.float64).reshape(-1, 2)


def empty_cell_contrast(image: np.ndarray, cells: np.ndarray, pts: np.ndarray,
                        window: tuple[int, int, bool, int], cols: int, rows: int) -> np.ndarray:
    """:func:`_cell_contrast` at the empty cells of a window of the lattice ``cells`` (A, 2) -> ``pts`` (A, 2) on the
    grey ``image`` (H, W), (E,): about none where a glare hides the board, and beyond the board's edge the outer squares
    against the margin show the full step (cells outside the image read NaN). ``window`` is one placement of
    :func:`~ccs_kornia.modules.detection.grid.lattice.select_window` on a ``cols x rows`` board."""
    return _cell_contrast(image, cells, pts, _empty_cells(cells, window, cols, rows))


def placement_contrast(empty: np.ndarray) -> float:
    """The largest contrast of :func:`empty_cell_contrast` (0 where none is measured): the placement with the least
    is the one under the glare."""
    return float(np.nanmax(empty)) if np.isfinite(empty).any() else 0.0


def empty_cells_flat(image: np.ndarray, cells: np.ndarray, pts: np.ndarray, empty: np.ndarray,
                     fraction: float = 0.5) -> bool:
    """Whether most empty cells of a placement show no checker (median of their :func:`empty_cell_contrast`
    ``empty`` below ``fraction`` of the lattice's own contrast): a lattice short of the board because something hides
    the rest, not because the network missed corners that the image shows (a real fisheye photograph's coarse level
    showed most of the board's contrast there, glares at most a fifth: ``docs/measurements.md``)."""
    own = np.nanmedian(_cell_contrast(image, cells, pts, cells))
    return not np.isfinite(empty).any() or bool(np.nanmedian(empty) < fraction * own)


def square_contrast(image: np.ndarray, h: np.ndarray, cols: int, rows: int) -> float:
    """Mean brightness of the squares that should be light minus those that should be dark, on the grey ``image``
    (H, W) with the board's homography ``h`` (3, 3) from board cells ``(i, j)`` to pixels.

    Under the colour convention (the outer square at corner 0 is dark), the inner square with
    corners ``(i, j)`` to ``(i + 1, j + 1)`` and centre ``(i + 0.5, j + 0.5)`` is dark iff ``i + j`` is even.
    Positive for a labelling that agrees with the image; nan when too few squares are visible.
    """
    j, i = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    centres = np.stack([i.ravel() + 0.5, j.ravel() + 0.5], -1).astype(np.float64)
    dark = ((i + j) % 2 == 0).ravel()
    xy = np.round(apply_homography(h, centres)).astype(np.int64)
    height, width = image.shape
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    if (inside & dark).sum() == 0 or (inside & ~dark).sum() == 0:
        return float("nan")
    values = image[xy[inside, 1], xy[inside, 0]]
    return float(values[~dark[inside]].mean() - values[dark[inside]].mean())
