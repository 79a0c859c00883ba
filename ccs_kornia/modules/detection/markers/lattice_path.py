r"""The lattice path of a marker board: every corner of the chessboard lattice the heatmap network sees, named by the
few markers that can be read.

The marker path (:mod:`~ccs_kornia.modules.detection.markers.marker_board`) finds a corner only where OpenCV decodes
a marker beside it; blur, low light and small markers leave most of a board's corners without one. Here the corners
come first:

1. **lattice**: the network's corner peaks (:func:`~ccs_kornia.modules.detection.learned.corner_peaks.corner_peaks`),
   organised into the largest consistent point lattice
   (:func:`~ccs_kornia.modules.detection.grid.point_lattice.organize_lattice`; the board's lattice points: its corners,
   or for an AprilGrid the small squares between its tags, :attr:`LatticeBoard.group`);
2. **names**: the lattice named by the markers that agree
   (:func:`~ccs_kornia.modules.detection.markers.lattice_names.name_lattice`): those OpenCV decoded on the image, and
   those read on the rectified patch of each lattice square; a corner whose name is disputed is dropped;
3. **corners**: every corner of the board the named lattice reaches (at most one lattice step beyond it) is placed
   there (the nearest peak, or the lattice's local prediction), then refined and checked like the marker path's
   (:func:`~ccs_kornia.modules.detection.markers.marker_board.refine_marked_corners`) and grown from its accepted
   neighbours (:func:`~ccs_kornia.modules.detection.markers.marker_board.grow_corners`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from ccs_kornia.modules.detection.grid.point_lattice import (
    organize_lattice,
    predict_cells,
)
from ccs_kornia.modules.detection.learned.corner_peaks import corner_peaks
from ccs_kornia.modules.detection.markers.lattice_names import (
    BoardLattice,
    NamedLattice,
    name_lattice,
)
from ccs_kornia.modules.detection.markers.marker_board import MAX_MOVE, refine_and_grow

__all__ = ["GROWTH_ROUNDS", "MAX_GROUP", "REACH", "SNAP", "LatticeBoard", "LatticeCorners", "group_peaks",
           "lattice_corners"]

#: corners are placed at most this many lattice steps from the nearest named lattice point
REACH = 1.0
#: rounds of growth after the named corners are refined
GROWTH_ROUNDS = 3
#: a corner starts from the nearest peak within this fraction of the distance between the board's closest corners
SNAP = 0.35
#: most peaks in one group of :func:`group_peaks` (a small square and the markers' junctions beside it)
MAX_GROUP = 8


@dataclass(frozen=True)
class LatticeBoard:
    """A marker board as the lattice path sees it: its lattice (:class:`~ccs_kornia.modules.detection.markers.
    lattice_names.BoardLattice`), its corners :math:`(N, 2)` in board units (corner id order), a marker's side in
    lattice steps (``fraction``: the marker centred in each lattice square), the refinement window in board units
    (``radius_factor``), the growth's reach (board units) and support (accepted corners), and ``group``: where the
    lattice points are not corners but the centres of groups of corners (an AprilGrid's small squares), the most
    distance between two corners of a group, relative to the median distance of each peak to its nearest peak, one or
    more (:func:`group_peaks`; ``None``: the peaks are the lattice points)."""

    lattice: BoardLattice
    corners: np.ndarray
    fraction: float
    radius_factor: float
    reach: float
    support: int
    group: tuple[float, ...] | None = None

    @property
    def separation(self) -> float:
        """The distance between the board's two closest corners (board units)."""
        d = np.linalg.norm(self.corners[:, None] - self.corners[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        return float(d.min())


@dataclass
class LatticeCorners:
    """The lattice path's corners :math:`(B, N, 2)` (NaN where none), which are accepted :math:`(B, N)`, the naming of
    each view, a short reason per view, and the corners whose name a marker disputes :math:`(B, N)` (dropped here, and
    by :func:`~ccs_kornia.modules.detection.markers.corner_merge.merge_corners` from the other path too)."""

    corners: torch.Tensor
    accept: torch.Tensor
    named: list
    reasons: list
    disputed: torch.Tensor


def group_peaks(peaks: np.ndarray, scales: float | tuple[float, ...], image: np.ndarray | None = None
                ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Peaks :math:`(M, 2)` grouped where they lie within ``scale`` times the median nearest-peak distance of each
    other (single linkage), groups of three or four (a square's corners; fewer cannot place its centre): their centres
    :math:`(G, 2)` (the midpoint of the two farthest peaks) and members. With several ``scales``, the groups of each
    in turn, less those whose centre another scale's group already has (within half the median nearest-peak
    distance): a tight scale splits a foreshortened square, a loose one joins clutter to it.

    With the grey ``image``, a group must look like a small black square between four markers (or its inverse): its
    centre and the four points beyond its corners on one side of the grey level, the four points beyond its sides
    (the gaps between the markers) on the other. Junctions inside a marker's bits group alike but fail it; a group of
    up to :data:`MAX_GROUP` peaks (a square and such junctions beside it) keeps the four that make the most regular
    small square.

    Example:
        >>> small = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 3.0], [3.0, 3.0]])
        >>> centres, members = group_peaks(np.concatenate([small, small + 10]), (1.3, 1.6))
        >>> centres.tolist(), [len(m) for m in members]
        ([[1.5, 1.5], [11.5, 11.5]], [4, 4])
    """
    m = len(peaks)
    if m < 3:
        return np.zeros((0, 2)), []
    d = np.linalg.norm(peaks[:, None] - peaks[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    nearest = float(np.median(d.min(1)))
    centres: list[np.ndarray] = []
    members: list[np.ndarray] = []
    for scale in np.atleast_1d(np.asarray(scales, dtype=np.float64)).tolist():
        for centre, idx in zip(*_groups(peaks, d < scale * nearest, image)):
            if not centres or np.linalg.norm(np.array(centres) - centre, axis=-1).min() > 0.5 * nearest:
                centres.append(centre)
                members.append(idx)
    return np.array(centres).reshape(-1, 2), members


def _groups(peaks: np.ndarray, link: np.ndarray, image: np.ndarray | None) -> tuple[list, list]:
    """The groups of :func:`group_peaks` for one linking of the peaks."""
    m = len(peaks)
    label = np.arange(m)
    for _ in range(m):  # connected components by label propagation
        new = np.minimum(label, np.where(link, label[None, :], m).min(1))
        if (new == label).all():
            break
        label = new
    centres, members = [], []
    for lab in np.unique(label):
        idx = np.flatnonzero(label == lab)
        if len(idx) < 3 or len(idx) > MAX_GROUP:
            continue
        if len(idx) > 4:  # a small square and junctions of the markers' bits beside it: the four that make it
            if image is None:
                continue
            idx = _best_square(peaks, idx, image)
            if idx is None:
                continue
        centre, diagonal = _centre(peaks[idx])
        if image is not None and not _small_square(image, peaks[idx], centre, diagonal):
            continue
        centres.append(centre)
        members.append(idx)
    return centres, members


def _centre(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The midpoint of the two farthest of a square's corners ``pts`` (three or four) and their indices."""
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    i, j = np.unravel_index(int(np.argmax(d)), d.shape)
    return 0.5 * (pts[i] + pts[j]), np.array([i, j])


def _best_square(peaks: np.ndarray, idx: np.ndarray, image: np.ndarray) -> np.ndarray | None:
    """The four of the peaks ``idx`` that make the most regular small square on the ``image`` (its diagonals'
    midpoints closest), or ``None``."""
    best, err = None, np.inf
    for sub in itertools.combinations(idx.tolist(), 4):
        sub = np.array(sub)
        pts = peaks[sub]
        centre, diagonal = _centre(pts)
        rest = [k for k in range(4) if k not in diagonal]
        side = np.linalg.norm(pts[rest[0]] - pts[diagonal[0]])
        e = float(np.linalg.norm(0.5 * (pts[rest[0]] + pts[rest[1]]) - centre)) / max(side, 1e-9)
        if e < min(err, 0.2) and _small_square(image, pts, centre, diagonal):
            best, err = sub, e
    return best


def _small_square(image: np.ndarray, pts: np.ndarray, centre: np.ndarray, diagonal: np.ndarray) -> bool:
    """Whether the square with corners ``pts`` (three or four; ``centre`` the midpoint of their diagonal
    ``pts[diagonal]``) is a small square between four markers: its centre and the points beyond its corners one grey
    level, the points beyond its sides (the gaps between the markers) the other."""
    corners = pts - centre
    if len(corners) == 3:  # the missing corner mirrors the one off the diagonal
        off = [k for k in range(3) if k not in diagonal][0]
        corners = np.concatenate([corners, -corners[off][None]])
    angle = np.arctan2(corners[:, 1], corners[:, 0])
    corners = corners[np.argsort(angle)]
    sides = 0.5 * (corners + np.roll(corners, -1, axis=0))
    dark_pts = np.concatenate([centre[None], centre + 2.0 * corners])
    light_pts = centre + 2.0 * sides
    h, w = image.shape
    allpts = np.concatenate([dark_pts, light_pts])
    if (allpts < 0).any() or (allpts[:, 0] > w - 1).any() or (allpts[:, 1] > h - 1).any():
        return False
    x, y = allpts[:, 0], allpts[:, 1]
    x0, y0 = np.floor(x).astype(int).clip(0, w - 2), np.floor(y).astype(int).clip(0, h - 2)
    fx, fy = x - x0, y - y0
    v = (image[y0, x0] * (1 - fx) * (1 - fy) + image[y0, x0 + 1] * fx * (1 - fy) + image[y0 + 1, x0] * (1 - fx) * fy
         + image[y0 + 1, x0 + 1] * fx * fy)
    dark, light = v[:5], v[5:]
    return bool(light.min() > dark.max() or light.max() < dark.min())


def _place(named: NamedLattice, cells: np.ndarray, points: np.ndarray, peaks: np.ndarray, board: LatticeBoard
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the named lattice puts each corner of the board: initial points :math:`(N, 2)` (NaN: not reached), the
    spacing there (px per board unit), and the corners at a disputed square :math:`(N,)`."""
    lat = board.lattice
    n = len(board.corners)
    initial, spacing = np.full((n, 2), np.nan), np.full(n, np.nan)
    naming = named.naming
    use = named.named
    if naming is None or use.sum() < 4:
        return initial, spacing, np.zeros(n, dtype=bool)
    c = naming.cells(lat.index_of(board.corners))  # (N, 2) lattice coordinates of every corner
    reach = np.abs(c[:, None] - cells[use][None]).max(-1).min(1)
    nearest = np.rint(c).astype(np.int64)
    disputed = np.array([(int(a), int(b)) in named.disputed_cells for a, b in nearest], dtype=bool)
    todo = np.flatnonzero((reach <= REACH + 1e-9) & ~disputed)
    if not len(todo):
        return initial, spacing, disputed
    pred, step = predict_cells(cells[use], points[use], c[todo])
    per_unit = step / float(lat.pitch)
    if len(peaks):  # the nearest peak, well within half the way to the next corner
        d = np.linalg.norm(pred[:, None] - peaks[None], axis=-1)
        k = d.argmin(1)
        close = d[np.arange(len(todo)), k] < SNAP * board.separation * per_unit
        pred = np.where(close[:, None], peaks[k], pred)
    initial[todo], spacing[todo] = pred, per_unit
    return initial, spacing, disputed


def lattice_corners(images: torch.Tensor, board: LatticeBoard, markers: list[list[tuple[np.ndarray, int, bool]]],
                    peaks: list[np.ndarray] | None = None, min_agree: int = 1, known: torch.Tensor | None = None,
                    square_size: torch.Tensor | None = None, level_square: float | None = None) -> LatticeCorners:
    r"""The lattice path (module docstring) on a batch of images.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        board: the board as the lattice path sees it (:class:`LatticeBoard`).
        markers: per image, the markers OpenCV decoded: corners :math:`(4, 2)` px, id, decoded on the inverted image.
        peaks: per image, the corner peaks :math:`(M, 2)` px (default:
            :func:`~ccs_kornia.modules.detection.learned.corner_peaks.corner_peaks`).
        min_agree: a naming needs this many agreeing markers.
        known: :math:`(B, N, 2)` corners another path refined (NaN where none): a corner the named lattice places
            within :data:`~ccs_kornia.modules.detection.markers.marker_board.MAX_MOVE` spacings of its own id's known
            corner is that corner (the same saddle fit would find it again); elsewhere it is refined here, so two
            paths that disagree still do.
        square_size: :math:`(B,)` the lattice's square size in px where the markers measured it (NaN: not
            measured): the network looks at the image on that size's level
            (:func:`~ccs_kornia.modules.detection.learned.corner_peaks.corner_peaks`); ``level_square``: the
            squares' size on that level (``None``: the network's own target).

    Returns:
        :class:`LatticeCorners`.

    Example:
        >>> from ccs_kornia.modules.detection.boards import CharucoBoard
        >>> from ccs_kornia.modules.detection.markers.charuco import charuco_lattice_board
        >>> b = CharucoBoard(5, 7, 0.04, 0.02)
        >>> img = torch.from_numpy(b.render(40, margin=20)).float()[None, None] / 255
        >>> out = lattice_corners(img, charuco_lattice_board(b), [[]])
        >>> int(out.accept.sum()), out.reasons[0][:19]
        (24, 'lattice: 24 points,')
    """
    b = images.shape[0]
    n = len(board.corners)
    peaks = corner_peaks(images, square_size=square_size, level_square=level_square) if peaks is None else peaks
    gray = (images.detach()[:, 0].float().clamp(0, 1) * 255.0).cpu().numpy()
    initial, spacing = np.full((b, n, 2), np.nan), np.full((b, n), np.nan)
    disputed = np.zeros((b, n), dtype=bool)
    named_all, reasons = [], []
    lat = board.lattice
    for k in range(b):
        p = np.asarray(peaks[k], dtype=np.float64).reshape(-1, 2)
        points = group_peaks(p, board.group, gray[k])[0] if board.group is not None else p
        cells, member = organize_lattice(torch.from_numpy(points)[None], torch.ones(1, len(points), dtype=torch.bool),
                                         max(3, max(lat.size) + 1))
        cells, member = cells[0].numpy(), member[0].numpy()
        if member.sum() < 4:
            named_all.append(None)
            reasons.append(f"no lattice ({len(p)} peaks)")
            continue
        c, pts = cells[member], points[member]
        named = name_lattice(gray[k], c, pts, lat, markers[k], board.fraction, min_agree)
        named_all.append(named)
        if named.naming is None:
            reasons.append(f"lattice of {len(c)} points not named: {named.reason}")
            continue
        initial[k], spacing[k], disputed[k] = _place(named, c, pts, p, board)
        reasons.append(f"lattice: {len(c)} points, {named.agree} markers agree")
    fixed = None
    if known is not None:
        k = known.detach().double().cpu().numpy()
        close = np.linalg.norm(initial - k, axis=-1) <= MAX_MOVE * spacing
        fixed = np.where(close[..., None], k, np.nan)
    refined, accept = refine_and_grow(images, initial, spacing, board.radius_factor, board.corners, board.reach,
                                      board.support, GROWTH_ROUNDS, fixed, blocked=disputed)
    accept = accept & ~torch.from_numpy(disputed)
    corners = torch.where(accept[..., None], refined, torch.full_like(refined, float("nan")))
    return LatticeCorners(corners, accept, named_all, reasons, torch.from_numpy(disputed))
