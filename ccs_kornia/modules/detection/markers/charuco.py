r"""ChArUco corners with partial views: OpenCV's marker ids, this package's corners.

A ChArUco board identifies every corner by the ArUco markers beside it, so a board cut by the image's frame (where
the lens distortion is largest, and where a plain chessboard cannot be identified) still gives corners with their ids.

1. **markers**: ``cv2.aruco.ArucoDetector`` decodes the markers on the image, on its inverse (white-on-black prints)
   and on both mirrored (a two-sided board seen from its back: ids decoded on the flipped image, their corners mapped
   back);
2. **lattice**: the decoded markers must sit where the board puts their ids: a homography from the board to the image,
   grown from every single marker in turn, keeps the largest consistent set (markers within :data:`LATTICE_TOLERANCE`
   squares); markers the global homography misses (strong distortion) join where a homography fitted to their
   consistent neighbours puts them within :data:`LOCAL_TOLERANCE` squares. The variant (plain, inverted, mirrored)
   with the most consistent markers is kept, and for a board of unknown layout (``legacy=None``) the layout with
   the most; a view both layouts explain alike (a board with an even number of rows of squares differs between
   them by a one-square shift of most markers) takes the layout most views of the batch fit, or none
   (:func:`charuco_markers`); a view with more of the board's marker ids off its lattice than on it is refused (the
   markers of another board: a wrong board size, :attr:`CharucoMarkers.off_lattice`);
3. **initial corners**: each inner corner from the markers around it (:data:`NEIGHBOUR_RADIUS` squares, one of them
   touching it): a local homography, so the lens distortion matters little;
4. **refinement**: this package's saddle fit and symmetry polish
   (:func:`~ccs_kornia.modules.detection.refine.saddle_refine.refine_corners`, ``"symmetric"``) with a window that stays in
   the clear band between the corner and the markers (:func:`marked_radius_factor`);
5. **check**: a corner the refinement did not confirm, whose window leaves the image, or that it moved by more
   than :data:`MAX_MOVE` squares from where the markers put it, is dropped (a wrong corner is worse than a missing
   one).

The result is the package's :class:`~ccs_kornia.modules.detection.base.DetectionResult` with one slot per corner id
(``id = row * (squares_x - 1) + col``, OpenCV's), NaN where a corner is not seen; a view is found with at least
``min_corners`` corners.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.boards import (
    ARUCO_DICTIONARIES,
    CharucoBoard,
    aruco_dictionary,
)
from ccs_kornia.modules.detection.refine.saddle_refine import (
    POLISH_WINDOW,
    refine_corners,
)

__all__ = [
    "LATTICE_TOLERANCE", "LOCAL_TOLERANCE", "MAX_MOVE", "NEIGHBOUR_RADIUS", "CharucoDetector", "CharucoMarkers",
    "MarkerBoardDetector",
    "charuco_markers", "detect_charuco", "layout_fits", "dictionary_hint", "marked_radius_factor",
    "refine_marked_corners", "squares_hint",
]

#: a marker belongs to the board's lattice when its corners lie within this many squares of where the homography
#: puts them (a wrong id lands at least 1.4 squares away: the next marker of the board)
LATTICE_TOLERANCE = 0.5
#: ... or within this many squares of where a homography fitted to its consistent neighbours puts them
LOCAL_TOLERANCE = 0.25
#: markers whose centre lies within this many squares of a corner place it (the two touching ones at 0.71, the next
#: ring at 1.58)
NEIGHBOUR_RADIUS = 1.6
#: a refined corner farther than this (squares) from where its markers put it is dropped
MAX_MOVE = 0.25
#: largest refinement window half-size (px)
MAX_RADIUS = 12
#: the order in which image variants are decoded (the first of equal counts is kept)
VARIANTS = ("plain", "inverted", "mirrored", "mirrored inverted")


def marked_radius_factor(board: CharucoBoard, largest: float = 0.2) -> float:
    """The refinement window's half-size in grid spacings: the saddle fit's window and the symmetry polish's
    (:data:`~ccs_kornia.modules.detection.refine.saddle_refine.POLISH_WINDOW` times larger) stay in the clear band of width
    ``(square - marker) / 2`` between the corner and the markers (at most ``largest``, the plain boards' window).

    Example:
        >>> round(marked_radius_factor(CharucoBoard(5, 7, 0.04, 0.02)), 3)
        0.133
    """
    band = 0.5 * (float(board.square) - float(board.marker)) / float(board.square)
    return float(min(largest, 0.8 * band / POLISH_WINDOW))


def _detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)


def _decode(gray8: np.ndarray, detector: cv2.aruco.ArucoDetector, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """Marker corners ``(M, 4, 2)`` (in the image's own coordinates) and ids ``(M,)`` on one image variant."""
    img = gray8
    mirrored = variant.startswith("mirrored")
    if mirrored:
        img = cv2.flip(img, 1)
    if variant.endswith("inverted"):
        img = 255 - img
    corners, ids, _ = detector.detectMarkers(img)
    if ids is None or not len(ids):
        return np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64)
    pts = np.stack([c.reshape(4, 2) for c in corners]).astype(np.float64)
    if mirrored:
        pts[..., 0] = gray8.shape[1] - 1 - pts[..., 0]
    return pts, ids.reshape(-1).astype(np.int64)


def _board_markers(board: CharucoBoard, legacy: bool) -> dict[int, np.ndarray]:
    """Marker id -> its corners ``(4, 2)`` on the board, in squares."""
    b = board.cv2_board(legacy)
    s = float(board.square)
    ids, corners = b.getIds().reshape(-1), b.getObjPoints()
    return {int(i): np.asarray(p, dtype=np.float64)[:, :2] / s for i, p in zip(ids, corners)}


def _map(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    q = np.concatenate([pts, np.ones_like(pts[..., :1])], -1) @ h.T
    return q[..., :2] / q[..., 2:3]


def _fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    h, _ = cv2.findHomography(src.reshape(-1, 2), dst.reshape(-1, 2), 0)
    return h if h is not None and np.isfinite(h).all() and abs(np.linalg.det(h)) > 1e-12 else None


def _lattice(image_pts: np.ndarray, board_pts: np.ndarray) -> np.ndarray:
    """Mask ``(M,)`` of the markers consistent with the board: the largest set a homography (image -> board) grown
    from each single marker explains within :data:`LATTICE_TOLERANCE` squares, then the markers a homography of
    their consistent neighbours explains within :data:`LOCAL_TOLERANCE`."""
    m = len(image_pts)
    best = np.zeros(m, dtype=bool)
    if m < 2:
        return best
    for seed in range(m):
        keep = np.zeros(m, dtype=bool)
        keep[seed] = True
        for _ in range(4):
            h = _fit(image_pts[keep], board_pts[keep])
            if h is None:
                break
            err = np.linalg.norm(_map(h, image_pts) - board_pts, axis=-1).max(-1)
            grown = err < LATTICE_TOLERANCE
            if (grown == keep).all() or grown.sum() < keep.sum():
                keep = grown if grown.sum() >= keep.sum() else keep
                break
            keep = grown
        if keep.sum() > best.sum():
            best = keep
        if best.sum() == m:
            break
    if best.sum() < 2:
        return np.zeros(m, dtype=bool)
    centres = board_pts.mean(1)
    changed = True
    while changed:  # markers a global homography misses under strong distortion, placed by their neighbours
        changed = False
        for k in np.flatnonzero(~best):
            near = best & (np.linalg.norm(centres - centres[k], axis=-1) < 2.5)
            if near.sum() < 2:
                continue
            h = _fit(image_pts[near], board_pts[near])
            if h is not None and np.linalg.norm(_map(h, image_pts[k]) - board_pts[k], axis=-1).max() < LOCAL_TOLERANCE:
                best[k] = changed = True
    return best


@dataclass
class CharucoMarkers:
    """The board's markers found on one image: corners ``(M, 4, 2)`` px, ids ``(M,)``, their board corners
    ``(M, 4, 2)`` in squares, the image variant they were decoded on, the layout (legacy or not) they fit, how many
    markers were decoded, and where the board's given layout is the worse fit the other one (``better_layout``) and
    the markers it explains (``better_count``); ``ambiguous``: both layouts explain the view's markers alike;
    ``known``: the decoded markers (on that variant) whose ids the board has, on its lattice or not."""

    corners: np.ndarray
    ids: np.ndarray
    board_corners: np.ndarray
    variant: str
    legacy: bool
    decoded: int
    better_layout: bool | None = None
    better_count: int = 0
    ambiguous: bool = False
    known: int = 0

    @property
    def off_lattice(self) -> bool:
        """More of the board's marker ids decoded off its lattice than on it (at least 3): the markers belong to
        another board (a wrong board size), so no id of this one can be trusted."""
        return self.known - len(self.ids) >= max(3, len(self.ids) + 1)


def layout_fits(gray8: np.ndarray, board: CharucoBoard, detector: cv2.aruco.ArucoDetector | None = None
                ) -> dict[bool, CharucoMarkers]:
    """The board's markers on a ``uint8`` grey image, per layout (``{legacy: markers}``; one entry where both layouts
    place every marker alike, as on boards with an odd ``squares_y``): decoded on every variant
    (:data:`VARIANTS`), checked against the board's lattice, the variant with the most consistent markers kept."""
    detector = _detector(board.dictionary) if detector is None else detector
    new, old = _board_markers(board, False), _board_markers(board, True)
    same = new.keys() == old.keys() and all(np.allclose(new[k], old[k]) for k in new)
    layouts = {False: new} if same else {False: new, True: old}
    best = {legacy: CharucoMarkers(np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64), np.zeros((0, 4, 2)), "plain",
                                   legacy, 0) for legacy in layouts}
    for variant in VARIANTS:
        pts, ids = _decode(gray8, detector, variant)
        for legacy, markers in layouts.items():
            known = np.array([int(i) in markers for i in ids], dtype=bool)
            _, first = np.unique(ids, return_index=True)  # an id decoded twice: the first only
            known &= np.isin(np.arange(len(ids)), first)
            if known.sum() <= len(best[legacy].ids):
                continue  # cannot beat the best consistent set
            p, i = pts[known], ids[known]
            obj = np.stack([markers[int(k)] for k in i])
            keep = _lattice(p, obj)
            if keep.sum() > len(best[legacy].ids):
                best[legacy] = CharucoMarkers(p[keep], i[keep], obj[keep], variant, legacy, len(ids),
                                              known=int(known.sum()))
    return best


def charuco_markers(gray8: np.ndarray, board: CharucoBoard, detector: cv2.aruco.ArucoDetector | None = None,
                    fits: dict[bool, CharucoMarkers] | None = None, layout: bool | None = None) -> CharucoMarkers:
    """The board's markers on a ``uint8`` grey image in the layout that fits (:func:`layout_fits`).

    The two layouts of a board with an even ``squares_y`` differ by a one-square shift of most markers, so the wrong
    one gives consistent-looking but shifted ids: a board given a layout (``legacy`` not ``None``) keeps it and, where
    the other layout explains more markers, :attr:`CharucoMarkers.better_layout` says so; a board of unknown layout
    takes the one explaining more markers, on a tie ``layout`` (e.g. the layout most views of a set fit) or else
    none (no markers, :attr:`CharucoMarkers.ambiguous`).

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> m = charuco_markers(board.render(60, margin=30), board)
        >>> len(m.ids), m.variant, m.legacy
        (17, 'plain', False)
    """
    fits = layout_fits(gray8, board, detector) if fits is None else fits
    if len(fits) == 1:
        (only,) = fits.values()
        return only if board.legacy is None else replace(only, legacy=bool(board.legacy))
    if board.legacy is not None:
        chosen, other = fits[bool(board.legacy)], fits[not board.legacy]
        if len(other.ids) > len(chosen.ids):
            chosen = replace(chosen, better_layout=not board.legacy, better_count=len(other.ids))
        return chosen
    if len(fits[True].ids) != len(fits[False].ids):
        return fits[True] if len(fits[True].ids) > len(fits[False].ids) else fits[False]
    if layout is not None or not len(fits[False].ids):
        return fits[bool(layout)]
    empty = fits[False]
    return replace(empty, corners=empty.corners[:0], ids=empty.ids[:0], board_corners=empty.board_corners[:0],
                   ambiguous=True)


def _set_layout(fits: list[dict[bool, CharucoMarkers]]) -> bool | None:
    """The layout most views that tell the two apart fit (``None``: no view does, or as many each way)."""
    votes = [len(f[True].ids) > len(f[False].ids) for f in fits
             if len(f) == 2 and len(f[True].ids) != len(f[False].ids)]
    if not votes or 2 * sum(votes) == len(votes):
        return None
    return 2 * sum(votes) > len(votes)


def refine_marked_corners(images: torch.Tensor, initial: np.ndarray, spacing: np.ndarray, factor: float
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """Steps 4 and 5 for corners placed by markers: the refined corners :math:`(B, N, 2)` and which are accepted
    :math:`(B, N)`, from ``initial`` :math:`(B, N, 2)` px (NaN: not placed) and the local grid ``spacing``
    :math:`(B, N)` px; the window's half-size is ``factor`` spacings (at least 1.5 px, at most :data:`MAX_RADIUS`).
    A corner is accepted where the refinement confirmed it, its window lies on the image and it moved by at most
    :data:`MAX_MOVE` spacings."""
    _, _, h, w = images.shape
    seen = torch.from_numpy(np.isfinite(initial).all(-1))
    start = torch.from_numpy(np.nan_to_num(initial)).float()
    space = torch.from_numpy(np.nan_to_num(spacing, nan=1.0)).float()
    radius = (float(factor) * space).clamp(1.5, MAX_RADIUS)
    refined, ok = refine_corners(images.detach().float().cpu(), start, seen, radius, "symmetric",
                                 max_radius=MAX_RADIUS, return_ok=True)
    moved = (refined - start).norm(dim=-1)
    # the window must lie on the image: at the frame the border's replicated pixels pull a corner off by px
    inside = (refined >= radius[..., None]).all(-1)
    inside &= (refined[..., 0] <= w - 1 - radius) & (refined[..., 1] <= h - 1 - radius)
    accept = seen & ok & inside & (moved <= MAX_MOVE * space) & refined.isfinite().all(-1)
    return refined, accept


def _initial_corners(markers: CharucoMarkers, board: CharucoBoard, image_size: tuple[int, int]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each inner corner from a local homography of the markers around it: ids ``(K,)``, points ``(K, 2)`` px, grid
    spacing ``(K,)`` px (the nearest of the four grid neighbours the same homography places)."""
    cols, rows = board.board_size
    if len(markers.ids) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0)
    centres = markers.board_corners.mean(1)
    w, h = image_size
    ids, points, spacing = [], [], []
    steps = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    for row in range(rows):
        for col in range(cols):
            c = np.array([col + 1.0, row + 1.0])
            d = np.linalg.norm(centres - c, axis=-1)
            if not (d < 0.75).any():
                continue  # no decoded marker touches this corner
            near = d < NEIGHBOUR_RADIUS
            hom = _fit(markers.board_corners[near], markers.corners[near])
            if hom is None:
                continue
            p = _map(hom, np.concatenate([c[None], c + steps]))
            if not (np.isfinite(p).all() and 0 <= p[0, 0] <= w - 1 and 0 <= p[0, 1] <= h - 1):
                continue
            ids.append(row * cols + col)
            points.append(p[0])
            spacing.append(float(np.linalg.norm(p[1:] - p[0], axis=-1).min()))
    return np.array(ids, dtype=np.int64), np.array(points).reshape(-1, 2), np.array(spacing)


def detect_charuco(
    images: torch.Tensor,
    board: CharucoBoard,
    min_corners: int = 6,
    radius_factor: float | None = None,
    num_workers: int | None = None,
) -> DetectionResult:
    r"""ChArUco corners with their ids on a batch of images (the module docstring gives the steps).

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        board: the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard`.
        min_corners: a view with fewer accepted corners is not found.
        radius_factor: refinement window in grid spacings; ``None``: :func:`marked_radius_factor`.
        num_workers: threads over the images for the marker decoding; ``None``: ``min(8, cpu count)``.

    Returns:
        :class:`DetectionResult`: corners :math:`(B, N, 2)` with ``N`` the board's inner corners in id order (NaN
        where a corner id is not seen; zeros on views not found), found :math:`(B,)`, reasons (markers, variant,
        corners, or why not found).

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> img = torch.from_numpy(board.render(60, margin=30)).float()[None, None] / 255
        >>> out = detect_charuco(img, board)
        >>> out.corners.shape, out.found.tolist(), int(out.valid.sum())
        (torch.Size([1, 24, 2]), [True], 24)
        >>> bool(((out.corners[0, 0] - torch.tensor([89.5, 89.5])).abs() < 0.05).all())
        True
    """
    if images.dim() != 4 or images.shape[1] != 1:
        raise ValueError(f"Expected grey images of shape (B, 1, H, W), got {tuple(images.shape)}.")
    if min_corners < 1:
        raise ValueError(f"min_corners must be >= 1, got {min_corners}.")
    b, _, h, w = images.shape
    n = board.num_corners
    arrays = (images.detach()[:, 0].float().clamp(0, 1) * 255.0).round().to(torch.uint8).cpu().numpy()

    workers = min(8, os.cpu_count() or 1) if num_workers is None else num_workers
    if workers > 1 and b > 1:
        with ThreadPoolExecutor(max_workers=min(workers, b)) as pool:
            fits = list(pool.map(lambda a: layout_fits(a, board, _detector(board.dictionary)), arrays))
    else:
        fits = [layout_fits(a, board, _detector(board.dictionary)) for a in arrays]
    layout = _set_layout(fits) if board.legacy is None else None
    outputs = []
    for gray8, fit in zip(arrays, fits):
        markers = charuco_markers(gray8, board, fits=fit, layout=layout)
        outputs.append((markers, _initial_corners(markers, board, (w, h))))

    initial = np.full((b, n, 2), np.nan)
    spacing = np.full((b, n), np.nan)
    for k, (_, (ids, pts, sp)) in enumerate(outputs):
        initial[k, ids], spacing[k, ids] = pts, sp
    factor = marked_radius_factor(board) if radius_factor is None else float(radius_factor)
    refined, accept = refine_marked_corners(images, initial, spacing, factor)
    count = accept.sum(-1)
    refused = torch.tensor([m.better_layout is not None or m.off_lattice for m, _ in outputs], dtype=torch.bool)
    found = (count >= min_corners) & ~refused
    corners = torch.where(accept[..., None], refined, torch.full_like(refined, float("nan")))
    corners = torch.where(found[:, None, None], corners, torch.zeros_like(corners))
    reasons = []
    for k, (markers, _) in enumerate(outputs):
        what = f"{len(markers.ids)} {board.dictionary} markers"
        if markers.variant != "plain":
            what += f" ({markers.variant})"
        if markers.better_layout is not None:
            name = "legacy" if markers.better_layout else "new (non-legacy)"
            reasons.append(f"the markers fit the {name} layout better ({markers.better_count} against "
                           f"{len(markers.ids)} markers): wrong layout?")
        elif markers.off_lattice:
            reasons.append(f"{markers.known - len(markers.ids)} of the board's {board.dictionary} markers are not where "
                           f"a {board.squares_x}x{board.squares_y} board puts them ({len(markers.ids)} are): wrong "
                           "board size?")
        elif markers.ambiguous:
            reasons.append("the markers fit the new and the legacy layout alike (a board with an even number of rows "
                           "of squares, seen in part): give the layout")
        elif not len(markers.ids):
            reasons.append(f"no {board.dictionary} marker of the board found")
        elif bool(found[k]):
            reasons.append(f"charuco: {what}, {int(count[k])} of {n} corners")
        else:
            reasons.append(f"only {int(count[k])} corners from {what} (at least {min_corners} needed)")
    return DetectionResult(corners.to(images.device), found.to(images.device), reasons)


class MarkerBoardDetector(ChessboardDetector):
    """A board whose corners the decoded markers name, with the chessboard detectors' interface: ``board_size`` must
    be the board's corner grid (``board.board_size``); unseen corner ids are NaN. Subclasses give the detection
    (:meth:`detect_board`) and say what the grid is (:attr:`grid_name`, :meth:`layout`).

    It decodes and refines at full resolution (``selects_scale``: the pipeline does not downscale its images).

    Args:
        board: the board description (:mod:`~ccs_kornia.modules.detection.boards`).
        min_corners: corners a view needs to count as found.
        radius_factor, num_workers: of the detection function.
    """

    selects_scale = True
    #: the grid's name in the error for a wrong ``board_size``
    grid_name = "the board's corner grid"

    def __init__(self, board, min_corners: int = 6, radius_factor: float | None = None,
                 num_workers: int | None = None) -> None:
        super().__init__()
        self.board = board
        self.min_corners = int(min_corners)
        self.radius_factor = radius_factor
        self.num_workers = num_workers

    def layout(self) -> str:
        """The board in its own counts, for messages (e.g. ``5x7 squares``)."""
        raise NotImplementedError

    def detect_board(self, images: torch.Tensor) -> DetectionResult:
        """The detection of ``images`` :math:`(B, 1, H, W)` with this detector's board and options."""
        raise NotImplementedError

    def forward(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        board_size = self._check_inputs(images, board_size)
        if board_size != self.board.board_size:
            raise ValueError(f"board_size {board_size} is not {self.grid_name} {self.board.board_size} "
                             f"({self.layout()}).")
        return self.detect_board(images)


class CharucoDetector(MarkerBoardDetector):
    """ChArUco detector with the chessboard detectors' interface (:func:`detect_charuco`): ``board_size`` is the
    board's inner grid ``(squares_x - 1, squares_y - 1)``; unseen corner ids are NaN.

    It decodes and refines at full resolution (``selects_scale``: the pipeline does not downscale its images).

    Args:
        board: the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard`.
        min_corners, radius_factor, num_workers: as :func:`detect_charuco`.

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> det = CharucoDetector(board)
        >>> out = det(torch.zeros(2, 1, 64, 64), board.board_size)
        >>> out.corners.shape, out.found.tolist()
        (torch.Size([2, 24, 2]), [False, False])
    """

    grid_name = "the ChArUco board's inner grid"

    def layout(self) -> str:
        return f"{self.board.squares_x}x{self.board.squares_y} squares"

    def detect_board(self, images: torch.Tensor) -> DetectionResult:
        return detect_charuco(images, self.board, self.min_corners, self.radius_factor, self.num_workers)


def dictionary_hint(images: list[np.ndarray], board: CharucoBoard, least: int = 3) -> str:
    """Why no marker was found, for ``uint8`` grey ``images`` where the board's dictionary finds none: the predefined
    dictionary that finds ``least`` markers (on any variant) in most of the first 8 images, and in how many, e.g.
    ``"no DICT_4X4_250 marker in any image; DICT_6X6_250 markers in 4 of them: wrong --dictionary?"``.

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> wrong = CharucoBoard(5, 7, 0.04, 0.02, "DICT_4X4_250")
        >>> dictionary_hint([board.render(60, margin=30)], wrong)
        'no DICT_4X4_250 marker in any image; DICT_6X6_250 markers in 1 of them: wrong --dictionary?'
    """
    counts: dict[str, int] = {}
    for name in ARUCO_DICTIONARIES:
        if name == board.dictionary:
            continue
        det = _detector(name)
        hits = 0
        for img in images[:8]:
            if any(len(_decode(img, det, v)[1]) >= least for v in VARIANTS):
                hits += 1
        if hits:
            counts[name] = hits
    head = f"no {board.dictionary} marker in any image"
    if not counts:
        return f"{head}; no other predefined ArUco dictionary finds markers either: is it a ChArUco board?"
    # a family's dictionaries share their first codes (DICT_6X6_50's are DICT_6X6_250's): its _250 one is named
    top = max(counts.values())
    tied = [k for k, v in counts.items() if v == top]
    name = next((k for k in tied if k.endswith("_250")), tied[0])
    return f"{head}; {name} markers in {top} of them: wrong --dictionary?"


def squares_hint(images: list[np.ndarray], board: CharucoBoard, largest: int = 16) -> str:
    """Why a ChArUco board whose markers were decoded gave no view, for ``uint8`` grey ``images``: the board size
    (squares ``3..largest`` each way, either layout) whose lattice explains more of the markers in the first 3 images
    than the given one, e.g. ``"the DICT_6X6_250 markers fit a 5x7 board (34 markers), not 6x8 (4): wrong
    --charuco?"``; ``""`` when the given board explains them best.

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> squares_hint([board.render(60, margin=30)], CharucoBoard(6, 8, 0.04, 0.02, "DICT_6X6_250"))[:55]
        'the DICT_6X6_250 markers fit a 5x7 board (17 markers), '
    """
    detector = _detector(board.dictionary)
    decoded = []
    for img in images[:3]:
        tries = [_decode(img, detector, v) for v in VARIANTS]
        pts, ids = max(tries, key=lambda t: len(t[1]))
        _, first = np.unique(ids, return_index=True)
        decoded.append((pts[first], ids[first]))
    if not any(len(ids) for _, ids in decoded):
        return ""
    top = max(int(ids.max()) for _, ids in decoded if len(ids))

    def explained(candidate: CharucoBoard) -> tuple[int, bool]:
        best = (0, False)
        for legacy in candidate.layouts():
            markers = _board_markers(candidate, legacy)
            total = 0
            for pts, ids in decoded:
                known = np.array([int(i) in markers for i in ids], dtype=bool)
                if known.sum() >= 2:
                    obj = np.stack([markers[int(k)] for k in ids[known]])
                    total += int(_lattice(pts[known], obj).sum())
            if total > best[0]:  # the new layout on a tie
                best = (total, legacy)
        return best

    given, _ = explained(board)
    found = (given, board.squares_x, board.squares_y, False)
    for sx in range(3, largest + 1):
        for sy in range(3, largest + 1):
            if (sx * sy) // 2 <= top or (sx, sy) == (board.squares_x, board.squares_y):
                continue  # too few markers for the ids decoded
            count, legacy = explained(replace(board, squares_x=sx, squares_y=sy, legacy=None))
            if count > found[0]:
                found = (count, sx, sy, legacy)
    if found[0] <= max(given, 3):
        return ""
    count, sx, sy, legacy = found
    layout = " (legacy layout)" if legacy else ""
    return (f"the {board.dictionary} markers fit a {sx}x{sy} board{layout} ({count} markers), not "
            f"{board.squares_x}x{board.squares_y} ({given}): wrong --charuco?")
