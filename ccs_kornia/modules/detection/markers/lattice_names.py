r"""Names for a corner lattice: which board point each lattice cell is, from the markers that agree.

A lattice organised from corner peaks (:func:`~ccs_kornia.modules.detection.grid.point_lattice.organize_lattice`) is
known up to its symmetries (a quarter turn, a mirror) and a shift; a marker fixes all of them at once, since its code
is neither symmetric nor mirror-symmetric. A naming (:class:`LatticeNaming`) maps lattice cell ``c`` to the board's
lattice point ``D c + t`` (``D`` one of the eight orientations, ``t`` a shift) and says whether the print is
inverted. :func:`name_lattice`:

1. **candidates**: every marker OpenCV decoded, placed in the lattice (a homography of the lattice points around it),
   and every lattice square whose rectified patch reads as one of the board's markers in one of eight orientations
   (:class:`~ccs_kornia.modules.detection.markers.marker_bits.CodeTemplates`: blurred code templates, read once per
   square and print polarity) proposes the naming that puts that marker there;
2. **votes**: each candidate naming is checked on every square where it expects a marker: the square's read names
   the expected code in the expected orientation (``agree``), or clearly another marker or another orientation
   (``dispute``); a marker OpenCV decoded agrees where the naming puts its id, and disputes elsewhere;
3. **choice**: the naming with the most agreeing squares net of its disputed ones, kept only where no other naming
   comes close (more than twice the runner-up's net count: a board of OpenCV's two layouts seen under the wrong one,
   shifted by a square, agrees on about half its markers, and the other half dispute it) and where disputes are few
   (at most a quarter of its agreements). The lattice points of a disputed square are dropped, never guessed; so are
   cells the naming puts off the board.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ccs_kornia.modules.detection.grid.point_lattice import predict_cells
from ccs_kornia.modules.detection.markers.marker_bits import (
    ORIENTATIONS,
    CodeTemplates,
    MarkerCodes,
    read_bits,
    sample_cells,
)
from ccs_kornia.modules.detection.markers.marker_board import fit_homography, map_points

__all__ = ["BoardLattice", "LatticeNaming", "NamedLattice", "name_lattice"]

#: a marker's corners must lie within this many lattice steps of the lattice points a naming puts them at
PLACEMENT_TOLERANCE = 0.25
#: most candidate namings checked on every square (by their votes)
MAX_CANDIDATES = 8


@dataclass(frozen=True)
class BoardLattice:
    """What naming needs of a board: its lattice points (``size`` ``(nx, ny)`` of them, point ``(i, j)`` at board point
    ``origin + pitch * (i, j)``), its markers per layout (``layouts``: a key, e.g. OpenCV's legacy flag, -> marker id
    -> its corners :math:`(4, 2)` on the board in OpenCV's order) and their codes as templates."""

    size: tuple[int, int]
    origin: tuple[float, float]
    pitch: float
    layouts: dict
    templates: CodeTemplates

    def index_of(self, board_points: np.ndarray) -> np.ndarray:
        """Board points :math:`(..., 2)` in lattice-point units."""
        return (np.asarray(board_points, dtype=np.float64) - np.asarray(self.origin)) / float(self.pitch)

    def inside(self, index: np.ndarray) -> np.ndarray:
        """Which integer lattice points :math:`(..., 2)` the board has."""
        return (index >= 0).all(-1) & (index[..., 0] < self.size[0]) & (index[..., 1] < self.size[1])


@dataclass(frozen=True)
class LatticeNaming:
    """Lattice cell ``c`` is the board's lattice point ``D c + t``; ``inverted``: a white-on-black print; ``layout``:
    the key of :attr:`BoardLattice.layouts`."""

    D: tuple
    t: tuple
    inverted: bool
    layout: object

    def index(self, cells: np.ndarray) -> np.ndarray:
        """Lattice points :math:`(..., 2)` of ``cells`` :math:`(..., 2)` (float or int)."""
        return np.asarray(cells) @ np.array(self.D).T + np.array(self.t)

    def cells(self, index: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`index`."""
        return (np.asarray(index, dtype=np.float64) - np.array(self.t)) @ np.linalg.inv(np.array(self.D, float)).T

    @property
    def mirrored(self) -> bool:
        """The board is seen from its back (the naming mirrors the lattice)."""
        return bool(np.linalg.det(np.array(self.D, float)) < 0)


@dataclass
class NamedLattice:
    """The outcome of :func:`name_lattice`: the naming (``None``: none trusted), the board's lattice point of every
    cell (``index`` :math:`(P, 2)`, valid where ``named``), the squares that agreed and disputed, the runner-up
    naming's agreeing squares net of its disputed ones, and why no naming was kept."""

    naming: LatticeNaming | None
    index: np.ndarray
    named: np.ndarray
    agree: int = 0
    dispute: int = 0
    runner_up: int = 0
    reason: str = ""
    disputed_cells: set = field(default_factory=set)


class _Lattice:
    """Lattice cells -> image: the measured points, and the local prediction
    (:func:`~ccs_kornia.modules.detection.grid.point_lattice.predict_cells`) of every other cell up to one step
    beyond them (the board's outermost squares have their outer corners there)."""

    def __init__(self, cells: np.ndarray, points: np.ndarray) -> None:
        self.cells = np.asarray(cells, dtype=np.int64)
        self.points = np.asarray(points, dtype=np.float64)
        self.lo = self.cells.min(0) - 1
        span = self.cells.max(0) + 2 - self.lo
        grid = np.stack(np.meshgrid(np.arange(span[0]), np.arange(span[1]), indexing="ij"), -1) + self.lo
        self.grid, _ = predict_cells(self.cells, self.points, grid.reshape(-1, 2))
        self.grid = self.grid.reshape(int(span[0]), int(span[1]), 2)
        self.measured = np.zeros(tuple(int(v) for v in span), dtype=bool)
        rel = self.cells - self.lo
        self.grid[rel[:, 0], rel[:, 1]] = self.points
        self.measured[rel[:, 0], rel[:, 1]] = True

    def square(self, a: int, b: int) -> np.ndarray | None:
        """The homography lattice -> image of the square with lowest cell ``(a, b)``, where at least two of its
        corners are measured (the others predicted), else ``None``."""
        corners = np.array([(a, b), (a + 1, b), (a + 1, b + 1), (a, b + 1)])
        rel = corners - self.lo
        if (rel < 0).any() or (rel >= np.array(self.measured.shape)).any():
            return None
        if self.measured[rel[:, 0], rel[:, 1]].sum() < 2:
            return None
        return fit_homography(corners.astype(np.float64), self.grid[rel[:, 0], rel[:, 1]])

    def to_lattice(self, image_pts: np.ndarray, near: int = 12) -> np.ndarray | None:
        """Image points :math:`(K, 2)` in lattice coordinates, by a homography of the ``near`` lattice points
        closest to their centre."""
        if len(self.points) < 4:
            return None
        d = np.linalg.norm(self.points - image_pts.mean(0), axis=-1)
        pick = np.argsort(d)[:near]
        h = fit_homography(self.points[pick], self.cells[pick].astype(np.float64))
        return None if h is None else map_points(h, image_pts)


def _naming_from_marker(lattice_corners: np.ndarray, board_corners: np.ndarray, board: BoardLattice,
                        inverted: bool, layout) -> LatticeNaming | None:
    """The naming that puts a marker's corners (:math:`(4, 2)` in lattice coordinates) at its board corners: the
    orientation with the smallest residual, within :data:`PLACEMENT_TOLERANCE` lattice steps."""
    target = board.index_of(board_corners)
    best, err = None, PLACEMENT_TOLERANCE
    for d in ORIENTATIONS:
        mapped = lattice_corners @ d.T
        t = np.rint((target - mapped).mean(0))
        e = float(np.abs(mapped + t - target).max())
        if e < err:
            best, err = LatticeNaming(tuple(map(tuple, d.tolist())), tuple(int(v) for v in t), inverted, layout), e
    return best


def _marker_frame(board_corners: np.ndarray, naming: LatticeNaming, board: BoardLattice) -> np.ndarray:
    """The affine map :math:`(3, 3)` from a marker's unit frame (``x`` along its code's rows, ``y`` down its columns)
    to lattice cells under ``naming``."""
    c = naming.cells(board.index_of(board_corners))
    a = np.eye(3)
    a[:2, 0], a[:2, 1], a[:2, 2] = c[1] - c[0], c[3] - c[0], c[0]
    return a


def _orientation(lattice_corners: np.ndarray, a: int, b: int, fraction: float, codes: MarkerCodes) -> int | None:
    """The orientation in which a marker whose corners lie at ``lattice_corners`` :math:`(4, 2)` sits in the square
    ``(a, b)`` (centred, ``fraction`` of its side), or ``None`` where it does not sit there."""
    lo = 0.5 * (1.0 - fraction)
    unit = (lattice_corners - np.array([a + lo, b + lo])) / fraction
    for o in range(len(ORIENTATIONS)):
        if np.abs(codes.corners_in_frame(o) - unit).max() < PLACEMENT_TOLERANCE / max(fraction, 1e-6):
            return o
    return None


def _square_frame(a: int, b: int, fraction: float) -> np.ndarray:
    """The affine map from the unit frame of the marker centred in square ``(a, b)`` (``fraction`` of its side) to
    lattice cells."""
    lo = 0.5 * (1.0 - fraction)
    return np.array([[fraction, 0.0, a + lo], [0.0, fraction, b + lo], [0.0, 0.0, 1.0]])


def _square_cells(centre: np.ndarray) -> set:
    """The four lattice cells around the square holding the lattice point ``centre``."""
    a, b = int(np.floor(centre[0])), int(np.floor(centre[1]))
    return {(a, b), (a + 1, b), (a, b + 1), (a + 1, b + 1)}


def name_lattice(image: np.ndarray, cells: np.ndarray, points: np.ndarray, board: BoardLattice,
                 markers: list[tuple[np.ndarray, int, bool]], fraction: float, min_agree: int = 1) -> NamedLattice:
    """Name the lattice points (``cells`` :math:`(P, 2)` int at ``points`` :math:`(P, 2)` px of the ``float32`` grey
    ``image``) from the markers OpenCV decoded (``markers``: corners :math:`(4, 2)` px, id, decoded on the inverted
    image) and the codes read on the lattice's squares (each marker centred in its square, ``fraction`` of its
    side). See the module docstring for the steps.

    Returns:
        :class:`NamedLattice`.

    Example:
        >>> from ccs_kornia.modules.detection.boards import CharucoBoard
        >>> from ccs_kornia.modules.detection.markers.charuco import charuco_lattice
        >>> b = CharucoBoard(5, 7, 0.04, 0.02)
        >>> img = b.render(40, margin=20).astype(np.float32)
        >>> cells = np.stack(np.meshgrid(np.arange(4), np.arange(6)), -1).reshape(-1, 2)
        >>> named = name_lattice(img, cells, cells * 40.0 + 59.5, charuco_lattice(b), [], 0.5)
        >>> named.agree, bool(named.named.all()), bool((named.index == cells).all())
        (17, True, True)
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    none = NamedLattice(None, np.zeros_like(cells), np.zeros(len(cells), dtype=bool))
    if len(cells) < 4:
        none.reason = "no lattice"
        return none
    lattice = _Lattice(cells, points)
    templates = board.templates
    codes = templates.codes
    code_index = {int(i): k for k, i in enumerate(codes.ids)}

    # the codes read on every square of the lattice (each polarity whose border reads dark on a light ring)
    reads: dict[tuple[int, int, bool], np.ndarray] = {}
    lo, hi = cells.min(0), cells.max(0)
    for a in range(int(lo[0]) - 1, int(hi[0]) + 1):
        for b in range(int(lo[1]) - 1, int(hi[1]) + 1):
            h = lattice.square(a, b)
            if h is None:
                continue
            to_image = h @ _square_frame(a, b, fraction)
            means = sample_cells(image, to_image, templates.cells)
            patch = templates.sample(image, to_image)
            for inverted in (False, True):
                if read_bits(-means if inverted else means, codes.border).readable:
                    reads[(a, b, inverted)] = templates.scores(-patch if inverted else patch)

    # 1. candidates: OpenCV's markers, then the squares' own codes
    votes: dict[LatticeNaming, int] = {}
    placed = []  # (lattice corners, id, inverted) of each OpenCV marker the board has

    def vote(corners: np.ndarray, mid: int, inverted: bool) -> None:
        for layout, where in board.layouts.items():
            if mid in where:
                naming = _naming_from_marker(corners, where[mid], board, inverted, layout)
                if naming is not None:
                    votes[naming] = votes.get(naming, 0) + 1

    for corners, mid, inverted in markers:
        if not any(int(mid) in where for where in board.layouts.values()):
            continue
        q = lattice.to_lattice(np.asarray(corners, dtype=np.float64))
        if q is not None:
            placed.append((q, int(mid), bool(inverted)))
            vote(q, int(mid), bool(inverted))
    for (a, b, inverted), scores in reads.items():
        got = templates.best(scores)
        if got is not None:
            corners = map_points(_square_frame(a, b, fraction), codes.corners_in_frame(got[0]))
            vote(corners, int(codes.ids[got[1]]), inverted)
    if not votes:
        none.reason = "no marker read on the lattice"
        return none

    # 2. every candidate checked on every square where it expects a marker
    scored = []
    for naming in sorted(votes, key=lambda nm: -votes[nm])[:MAX_CANDIDATES]:
        where = board.layouts[naming.layout]
        agreed, dispute, disputed = set(), 0, set()
        for mid, corners in where.items():
            if mid not in code_index:
                continue
            q = naming.cells(board.index_of(corners))
            a, b = (int(v) for v in np.floor(q.mean(0)))
            scores = reads.get((a, b, naming.inverted))
            o = _orientation(q, a, b, fraction, codes)
            if scores is None or o is None:
                continue
            if templates.agrees(scores, o, code_index[mid]):
                agreed.add(mid)
            elif templates.disputes(scores, o, code_index[mid]):  # clearly another marker, or this one turned
                dispute += 1
                disputed |= _square_cells(q.mean(0))
        for q, mid, inverted in placed:  # the markers OpenCV decoded: where this naming puts them?
            expected = naming.cells(board.index_of(where[mid])) if mid in where else None
            if expected is not None and inverted == naming.inverted and \
                    np.abs(expected - q).max() < PLACEMENT_TOLERANCE:
                agreed.add(mid)
            else:
                dispute += 1
                disputed |= _square_cells(q.mean(0))
        scored.append((len(agreed), dispute, naming, disputed))
    # 3. the naming with the most agreeing squares net of its disputed ones
    scored.sort(key=lambda s: (-(s[0] - s[1]), s[1]))
    agree, dispute, naming, disputed = scored[0]
    runner_up = max((s[0] - s[1] for s in scored[1:]), default=0)
    out = NamedLattice(None, none.index, none.named, agree, dispute, runner_up, disputed_cells=disputed)
    if agree < min_agree:
        out.reason = f"{agree} marker(s) agree on the lattice (at least {min_agree} needed)"
        return out
    if agree - dispute <= 2 * max(runner_up, 0):
        out.reason = f"two namings of the lattice: {agree - dispute} and {runner_up} markers agree (net of disputes)"
        return out
    if 4 * dispute > agree:
        out.reason = f"{dispute} marker(s) dispute the lattice's naming ({agree} agree)"
        return out

    # names: every cell the board has, less the disputed ones
    index = naming.index(cells)
    named = board.inside(index) & np.array([(int(a), int(b)) not in disputed for a, b in cells], dtype=bool)
    return NamedLattice(naming, index, named, agree, dispute, runner_up, disputed_cells=disputed)
