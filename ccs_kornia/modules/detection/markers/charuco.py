r"""ChArUco corners with partial views: OpenCV's marker ids, this package's corners.

A ChArUco board identifies every corner by the ArUco markers beside it, so a board cut by the image's frame (where
the lens distortion is largest, and where a plain chessboard cannot be identified) still gives corners with their ids.

The shared steps (decoding, lattice check, refinement) are :mod:`~ccs_kornia.modules.detection.markers.marker_board`'s:

1. **markers**: ``cv2.aruco.ArucoDetector`` decodes the markers on the image, on its inverse (white-on-black prints)
   and on both mirrored (a two-sided board seen from its back), and adds those it reads on enhanced copies of the
   image (its contrast stretched, sharpened, enlarged: a dim, blurred or small view; with its measured motion or
   Gaussian blur undone);
2. **lattice**: the decoded markers must sit where the board puts their ids
   (:func:`~ccs_kornia.modules.detection.markers.marker_board.consistent_markers`, in squares). The variant (plain,
   inverted, mirrored) with the most consistent markers is kept, and for a board of unknown layout (``legacy=None``)
   the layout with the most; a view both layouts explain alike (a board with an even number of rows of squares
   differs between them by a one-square shift of most markers) takes the layout most views of the batch fit, or none
   (:func:`charuco_markers`); a view with more of the board's marker ids off its lattice than on it is refused (the
   markers of another board: a wrong board size, :attr:`CharucoMarkers.off_lattice`);
3. **initial corners**: each inner corner from the markers around it (:data:`NEIGHBOUR_RADIUS` squares, one of them
   touching it): a local homography, so the lens distortion matters little; and a second start from the markers
   touching it alone (:func:`_touching_corners`), closer under a strong lens;
4. **refinement and check**: :func:`~ccs_kornia.modules.detection.markers.marker_board.refine_marked_corners` with
   a window that stays in the clear band between the corner and the markers (:func:`marked_radius_factor`): a corner
   the refinement did not confirm, whose window leaves the image, or that moved by more than a quarter square from
   where the markers put it, is dropped (a wrong corner is worse than a missing one); both starts are refined, a
   corner kept where one confirms it, dropped where both do at places more than 1 px apart.

These steps are the **marker path**: a corner exists only where OpenCV decodes a marker beside it. The **lattice
path** (:mod:`~ccs_kornia.modules.detection.markers.lattice_path`) finds every corner of the chessboard lattice the
heatmap network sees and names it from the markers that agree, those OpenCV decodes and those read on the lattice's
own squares (:func:`charuco_lattice_board`); blur, low light and small markers that OpenCV cannot read still name
their squares. Both paths run by default and are merged per corner
(:func:`~ccs_kornia.modules.detection.markers.corner_merge.merge_corners`: a corner they dispute is dropped).

The result is the package's :class:`~ccs_kornia.modules.detection.base.DetectionResult` with one slot per corner id
(``id = row * (squares_x - 1) + col``, OpenCV's), NaN where a corner is not seen; a view is found with at least
``min_corners`` corners.
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.boards import (
    ARUCO_DICTIONARIES,
    CharucoBoard,
    aruco_dictionary,
)
from ccs_kornia.modules.detection.enhanced_copies import (
    UPSCALE,
    deblurring_copies,
    enhanced_copies,
)
from ccs_kornia.modules.detection.gaussian_deblur import (
    MIN_SIGMA,
    deblur_gaussian,
    gaussian_blur_sigma,
)
from ccs_kornia.modules.detection.learned.scale import TARGET_SQUARE
from ccs_kornia.modules.detection.markers.corner_merge import (
    AGREE_PX,
    MarkerPaths,
    merge_corners,
    path_counts,
    paths_note,
)
from ccs_kornia.modules.detection.markers.lattice_names import BoardLattice
from ccs_kornia.modules.detection.markers.lattice_path import (
    LatticeBoard,
    lattice_corners,
)
from ccs_kornia.modules.detection.markers.marker_bits import CodeTemplates, MarkerCodes
from ccs_kornia.modules.detection.markers.marker_board import (
    MAX_MOVE,
    VARIANTS,
    BoardMarkers,
    MarkerBoardDetector,
    consistent_markers,
    decode_markers,
    decode_with_copies,
    fit_homography,
    markers_on_board,
    place_from,
    refine_marked_corners,
    small_marker_scale,
)
from ccs_kornia.modules.detection.motion_deblur import (
    deblur_motion,
    motion_blur,
)
from ccs_kornia.modules.detection.refine.saddle_refine import POLISH_WINDOW
from ccs_kornia.runtime.checks import check_grey_images

__all__ = [
    "MIN_BAND_PX",
    "NEIGHBOUR_RADIUS",
    "CharucoDetector",
    "CharucoMarkers",
    "board_markers",
    "charuco_detector",
    "charuco_lattice",
    "charuco_lattice_board",
    "charuco_markers",
    "charuco_paths",
    "detect_charuco",
    "dictionary_hint",
    "lattice_level_square",
    "layout_fits",
    "marked_radius_factor",
    "marker_square_size",
    "squares_hint",
]

#: markers whose centre lies within this many squares of a corner place it (the two touching ones at 0.71, the next
#: ring at 1.58)
NEIGHBOUR_RADIUS = 1.6


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


def charuco_detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    """OpenCV's marker detector for a ChArUco board's dictionary (sub-pixel marker corners)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)


def board_markers(board: CharucoBoard, legacy: bool) -> dict[int, np.ndarray]:
    """Marker id -> its corners ``(4, 2)`` on the board in squares (OpenCV's corner order), in one layout.

    Example:
        >>> board_markers(CharucoBoard(5, 7, 0.04, 0.02), False)[0].round(4).tolist()
        [[1.25, 0.25], [1.75, 0.25], [1.75, 0.75], [1.25, 0.75]]
    """
    b = board.cv2_board(legacy)
    s = float(board.square)
    ids, corners = b.getIds().reshape(-1), b.getObjPoints()
    return {int(i): np.asarray(p, dtype=np.float64)[:, :2] / s for i, p in zip(ids, corners)}


@dataclass
class CharucoMarkers(BoardMarkers):
    """A ChArUco board's markers on one image (:class:`~ccs_kornia.modules.detection.markers.marker_board.
    BoardMarkers`, board corners in squares) with the layout (legacy or not) they fit and, where the board's given
    layout is the worse fit, the other one (``better_layout``) and the markers it explains (``better_count``);
    ``ambiguous``: both layouts explain the view's markers alike; ``motion``: the straight motion blur measured on the
    view (length px, direction radians: :func:`~ccs_kornia.modules.detection.motion_deblur.motion_blur`),
    where its markers were also read on the view with it undone, and its corners are refined there; ``defocus``: the
    same for a Gaussian blur (sigma px: :func:`~ccs_kornia.modules.detection.gaussian_deblur.
    gaussian_blur_sigma`). Either is kept where the copy with it undone reads more of the board's markers, or where
    none is read at all."""

    legacy: bool = False
    better_layout: bool | None = None
    better_count: int = 0
    ambiguous: bool = False
    motion: tuple[int, float] | None = None
    defocus: float | None = None


def layout_fits(gray8: np.ndarray, board: CharucoBoard, detector: cv2.aruco.ArucoDetector | None = None
                ) -> dict[bool, CharucoMarkers]:
    """The board's markers on a ``uint8`` grey image, per layout (``{legacy: markers}``; one entry where both layouts
    place every marker alike, as on boards with an odd ``squares_y``): decoded on every variant
    (:data:`~ccs_kornia.modules.detection.markers.marker_board.VARIANTS`), checked against the board's lattice, the
    variant with the most consistent markers kept; then the markers of the image's enhanced copies
    (:func:`~ccs_kornia.modules.detection.enhanced_copies.enhanced_copies`: contrast, sharpness, size) added on
    the variant kept (on every variant where none was), kept where more of them sit on the lattice; where any of the
    board's marker ids was decoded, those of copies sharpened harder for a blurred view
    (:func:`~ccs_kornia.modules.detection.enhanced_copies.deblurring_copies`) the same way; where markers are still
    missing, those of a copy with the view's measured motion blur
    (:func:`~ccs_kornia.modules.detection.motion_deblur.motion_blur`) or else Gaussian blur
    (:func:`~ccs_kornia.modules.detection.gaussian_deblur.gaussian_blur_sigma`, at least
    :data:`~ccs_kornia.modules.detection.gaussian_deblur.MIN_SIGMA`) undone and of that copy enlarged; where
    the markers read are too small for OpenCV's sampling, those of a further enlarged copy
    (:func:`~ccs_kornia.modules.detection.markers.marker_board.small_marker_scale`) the same way; a view whose every
    marker is read already skips them."""
    detector = charuco_detector(board.dictionary) if detector is None else detector
    new, old = board_markers(board, False), board_markers(board, True)
    same = new.keys() == old.keys() and all(np.allclose(new[k], old[k]) for k in new)
    layouts = {False: new} if same else {False: new, True: old}
    none = BoardMarkers.none()
    best = {legacy: CharucoMarkers(none.corners, none.ids, none.board_corners, legacy=legacy) for legacy in layouts}

    motion = None
    defocus = None

    def keep(pts: np.ndarray, ids: np.ndarray, variant: str) -> None:
        for legacy, layout in layouts.items():
            got = markers_on_board(pts, ids, layout, variant, len(best[legacy].ids))
            if got is not None:
                best[legacy] = CharucoMarkers(got.corners, got.ids, got.board_corners, got.variant, got.decoded,
                                              got.known, legacy=legacy, motion=motion,
                                              defocus=defocus)

    def read_deblurred(sharp: np.ndarray, variants: list[str], enlarge_on) -> int:
        """Markers of a deblurred copy ``sharp`` added on ``variants``, then of that copy enlarged on the variants
        ``enlarge_on()`` names by then; the most markers a layout now explains."""
        for variant in variants:
            pooled[variant] = decode_with_copies(pooled[variant], [(sharp, 1.0)], detector, variant)
            keep(*pooled[variant], variant)
        on = enlarge_on()
        if on:
            enlarged = cv2.resize(sharp, None, fx=UPSCALE, fy=UPSCALE, interpolation=cv2.INTER_CUBIC)
            for variant in on:
                pooled[variant] = decode_with_copies(pooled[variant], [(enlarged, UPSCALE)], detector, variant)
                keep(*pooled[variant], variant)
        return max(len(m.ids) for m in best.values())

    decoded = {}
    for variant in VARIANTS:
        decoded[variant] = decode_markers(gray8, detector, variant)
        keep(*decoded[variant], variant)
    # the enhanced copies: on the variant whose markers sit on the lattice, on every variant where none do; not where
    # every marker of the board is read already (a copy can then add nothing: the image's own reading wins)
    if any(len(best[legacy].ids) >= len(layout) for legacy, layout in layouts.items()):
        return best
    found = {m.variant for m in best.values() if len(m.ids)}
    copies = enhanced_copies(gray8)
    pooled = {}
    for variant in (v for v in VARIANTS if v in found or not found):
        pooled[variant] = decode_with_copies(decoded[variant], copies, detector, variant)
        keep(*pooled[variant], variant)
    if any(len(best[legacy].ids) >= len(layout) for legacy, layout in layouts.items()):
        return best
    # a blurred view: copies sharpened harder, on the variants where any of the board's marker ids was decoded, on or
    # off the lattice (a view with no such id, as a board-free one, pays nothing)
    board_ids = np.array(sorted({i for layout in layouts.values() for i in layout}))
    read = [v for v in pooled if np.isin(pooled[v][1], board_ids).any()]
    if read:
        deblurred = deblurring_copies(copies[0][0])
        for variant in read:
            pooled[variant] = decode_with_copies(pooled[variant], deblurred, detector, variant)
            keep(*pooled[variant], variant)
        if any(len(best[legacy].ids) >= len(layout) for legacy, layout in layouts.items()):
            return best
    # a straight motion blur measured on the view: its Wiener-filtered copy on the variants where markers were read
    # (on every variant where none were), and that copy enlarged on those where the board's ids are read by then; the
    # view is taken as blurred so (its corners refined, its lattice's codes read, with the blur undone) where the
    # copies read more of the board's markers, or where none is read at all and the edges across the line are blurred
    # (the lattice path reads its squares there): a blur measured where there is none (a board's period can make a
    # cepstrum peak) gives a copy that reads nothing new and edges that are sharp
    blur = motion_blur(copies[0][0])
    if blur is not None:
        before = max(len(m.ids) for m in best.values())
        after = read_deblurred(deblur_motion(copies[0][0], *blur), read or list(pooled),
                               lambda: [v for v in pooled if np.isin(pooled[v][1], board_ids).any()])
        if after > before or (not after and gaussian_blur_sigma(copies[0][0], blur[1]) >= MIN_SIGMA):
            motion = blur
            best = {legacy: replace(m, motion=motion) for legacy, m in best.items()}
        if any(len(best[legacy].ids) >= len(layout) for legacy, layout in layouts.items()):
            return best
    # a Gaussian blur measured on the view (none where a motion blur was taken): its Wiener-filtered copy on the
    # variant whose markers sit on the lattice (on every variant where none do), and that copy enlarged on the variant
    # whose markers sit on it by then; taken as the motion blur is (a sharp view measures below MIN_SIGMA: no copy)
    if motion is None:
        sigma = gaussian_blur_sigma(copies[0][0])
        if sigma >= MIN_SIGMA:
            before = max(len(m.ids) for m in best.values())

            def on_lattice() -> list[str]:
                return [v for v in pooled if any(m.variant == v and len(m.ids) for m in best.values())]

            after = read_deblurred(deblur_gaussian(copies[0][0], sigma), on_lattice() or list(pooled), on_lattice)
            if after > before or not after:
                defocus = sigma
                best = {legacy: replace(m, defocus=defocus) for legacy, m in best.items()}
            if any(len(best[legacy].ids) >= len(layout) for legacy, layout in layouts.items()):
                return best
    # markers read but too small for OpenCV's sampling: a further copy, enlarged from the stretched one until their
    # cells reach it, on the variant they were read on (a view with no marker read pays nothing)
    most = max(best.values(), key=lambda m: len(m.ids))
    if not len(most.ids):
        return best
    side = float(np.median(np.linalg.norm(most.corners - np.roll(most.corners, 1, axis=1), axis=-1)))
    cells = detector.getDictionary().markerSize + 2 * detector.getDetectorParameters().markerBorderBits
    scale = small_marker_scale(side, cells, gray8.shape)
    if scale:
        stretched = copies[0][0]
        enlarged = cv2.resize(stretched, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        keep(*decode_with_copies(pooled[most.variant], [(enlarged, scale)], detector, most.variant), most.variant)
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
    empty = fits[False]  # (its markers sit on the lattice in both layouts: not counted as off it)
    return replace(empty, corners=empty.corners[:0], ids=empty.ids[:0], board_corners=empty.board_corners[:0],
                   known=empty.known - len(empty.ids), ambiguous=True)


def _set_layout(fits: list[dict[bool, CharucoMarkers]]) -> bool | None:
    """The layout most views that tell the two apart fit (``None``: no view does, or as many each way)."""
    votes = [len(f[True].ids) > len(f[False].ids) for f in fits
             if len(f) == 2 and len(f[True].ids) != len(f[False].ids)]
    if not votes or 2 * sum(votes) == len(votes):
        return None
    return 2 * sum(votes) > len(votes)


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
    for row in range(rows):
        for col in range(cols):
            c = np.array([col + 1.0, row + 1.0])
            d = np.linalg.norm(centres - c, axis=-1)
            if not (d < 0.75).any():
                continue  # no decoded marker touches this corner
            near = d < NEIGHBOUR_RADIUS
            hom = fit_homography(markers.board_corners[near], markers.corners[near])
            if hom is None:
                continue
            p, space = place_from(hom, c)
            if not (np.isfinite(p).all() and 0 <= p[0] <= w - 1 and 0 <= p[1] <= h - 1):
                continue
            ids.append(row * cols + col)
            points.append(p)
            spacing.append(space)
    return np.array(ids, dtype=np.int64), np.array(points).reshape(-1, 2), np.array(spacing)


def _touching_corners(markers: CharucoMarkers, board: CharucoBoard, ids: np.ndarray, fallback: np.ndarray
                      ) -> np.ndarray:
    """Corners ``ids`` ``(K,)`` placed by the markers touching them ``(K, 2)`` px: the midpoint of two markers'
    corners facing the corner, or one marker's own homography a fraction of a square beyond its corner (``fallback``
    ``(K, 2)`` where it has none). Under a strong lens a homography of the markers within
    :data:`NEIGHBOUR_RADIUS` bends by more than a large marker's clear band; the touching markers do not reach as far."""
    cols = board.board_size[0]
    centres = markers.board_corners.mean(1)
    out = np.array(fallback, dtype=np.float64, copy=True).reshape(-1, 2)
    for j, i in enumerate(np.asarray(ids).tolist()):
        c = np.array([i % cols + 1.0, i // cols + 1.0])
        touching = np.flatnonzero(np.linalg.norm(centres - c, axis=-1) < 0.75)
        if len(touching) >= 2:
            out[j] = np.mean([markers.corners[k][np.argmin(np.linalg.norm(markers.board_corners[k] - c, axis=-1))]
                              for k in touching], axis=0)
        elif len(touching) == 1:
            own = fit_homography(markers.board_corners[touching], markers.corners[touching])
            if own is not None:
                out[j] = place_from(own, c)[0]
    return out


@functools.lru_cache(maxsize=8)
def charuco_lattice(board: CharucoBoard, layout: bool | None = None) -> BoardLattice:
    """The board's corner lattice for naming (:mod:`~ccs_kornia.modules.detection.markers.lattice_names`): inner
    corner ``(col, row)`` at ``(col + 1, row + 1)`` squares, its markers in the layout ``layout`` (``None``: the
    board's own, or both where it has none and they differ).

    Example:
        >>> lat = charuco_lattice(CharucoBoard(5, 7, 0.04, 0.02))
        >>> lat.size, sorted(lat.layouts), len(lat.templates.codes.ids)
        ((4, 6), [False], 17)
    """
    new, old = board_markers(board, False), board_markers(board, True)
    same = new.keys() == old.keys() and all(np.allclose(new[k], old[k]) for k in new)
    legacy = board.legacy if layout is None else layout
    if same:
        layouts = {False if legacy is None else bool(legacy): new}
    elif legacy is None:
        layouts = {False: new, True: old}
    else:
        layouts = {bool(legacy): old if legacy else new}
    ids = sorted({i for where in layouts.values() for i in where})
    return BoardLattice(board.board_size, (1.0, 1.0), 1.0, layouts,
                        CodeTemplates(MarkerCodes.of(board.dictionary, ids, 1)))


def charuco_lattice_board(board: CharucoBoard, layout: bool | None = None,
                          radius_factor: float | None = None) -> LatticeBoard:
    """The board as the lattice path sees it (:class:`~ccs_kornia.modules.detection.markers.lattice_path.
    LatticeBoard`): its corners are its lattice points, a marker takes ``marker / square`` of its square, the
    refinement window is :func:`marked_radius_factor`'s, and a corner grows from four accepted corners within
    :data:`NEIGHBOUR_RADIUS` squares.

    Example:
        >>> charuco_lattice_board(CharucoBoard(5, 7, 0.04, 0.02)).corners[:2].tolist()
        [[1.0, 1.0], [2.0, 1.0]]
    """
    lattice = charuco_lattice(board, layout)
    corners = board.object_points().numpy()[:, :2] / float(board.square)
    factor = marked_radius_factor(board) if radius_factor is None else float(radius_factor)
    return LatticeBoard(lattice, corners.astype(np.float64), float(board.marker) / float(board.square), factor,
                        NEIGHBOUR_RADIUS, 4)


def detect_charuco(
    images: torch.Tensor,
    board: CharucoBoard,
    min_corners: int = 6,
    radius_factor: float | None = None,
    num_workers: int | None = None,
    paths: MarkerPaths = MarkerPaths.BOTH,
) -> DetectionResult:
    r"""ChArUco corners with their ids on a batch of images (the module docstring gives the steps).

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        board: the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard`.
        min_corners: a view with fewer accepted corners is not found.
        radius_factor: refinement window in grid spacings; ``None``: :func:`marked_radius_factor`.
        num_workers: threads over the images for the marker decoding; ``None``: ``min(8, cpu count)``.
        paths: the marker path (the steps above), the lattice path or both merged
            (:class:`~ccs_kornia.modules.detection.markers.corner_merge.MarkerPaths`).

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
    paths = MarkerPaths(paths)
    return charuco_paths(images, board, min_corners, radius_factor, num_workers, (paths,))[paths]


def charuco_paths(
    images: torch.Tensor,
    board: CharucoBoard,
    min_corners: int = 6,
    radius_factor: float | None = None,
    num_workers: int | None = None,
    paths: tuple[MarkerPaths, ...] = tuple(MarkerPaths),
) -> dict[MarkerPaths, DetectionResult]:
    r""":func:`detect_charuco` for each of ``paths`` from one run (each path computed once): ``{path: result}``.

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> img = torch.from_numpy(board.render(60, margin=30)).float()[None, None] / 255
        >>> out = charuco_paths(img, board)
        >>> [int(out[p].valid.sum()) for p in MarkerPaths]
        [24, 24, 24]
    """
    check_grey_images(images, min_side=0)
    if min_corners < 1:
        raise ValueError(f"min_corners must be >= 1, got {min_corners}.")
    paths = tuple(MarkerPaths(p) for p in paths)
    b, _, h, w = images.shape
    n = board.num_corners
    arrays = (images.detach()[:, 0].float().clamp(0, 1) * 255.0).round().to(torch.uint8).cpu().numpy()

    workers = min(8, os.cpu_count() or 1) if num_workers is None else num_workers
    if workers > 1 and b > 1:
        with ThreadPoolExecutor(max_workers=min(workers, b)) as pool:
            fits = list(pool.map(lambda a: layout_fits(a, board, charuco_detector(board.dictionary)), arrays))
    else:
        fits = [layout_fits(a, board, charuco_detector(board.dictionary)) for a in arrays]
    layout = _set_layout(fits) if board.legacy is None else None
    outputs = []
    for gray8, fit in zip(arrays, fits):
        markers = charuco_markers(gray8, board, fits=fit, layout=layout)
        outputs.append((markers, _initial_corners(markers, board, (w, h))))
    refused = torch.tensor([m.better_layout is not None or m.off_lattice for m, _ in outputs], dtype=torch.bool)
    # a view whose motion blur was measured is refined (and its lattice looked for) with the blur undone: the line's
    # kernel is symmetric, so undoing it moves no corner, and the corners are sharp again
    looked = images
    for k, (markers, _) in enumerate(outputs):
        if markers.motion is not None or markers.defocus is not None:
            looked = looked.clone() if looked is images else looked
            sharp = (deblur_motion(arrays[k], *markers.motion) if markers.motion is not None
                     else deblur_gaussian(arrays[k], markers.defocus))
            looked[k, 0] = torch.from_numpy(sharp).to(looked) / 255.0
    factor = marked_radius_factor(board) if radius_factor is None else float(radius_factor)

    nan = torch.full((b, n, 2), float("nan"))
    marked, lattice, notes = nan, nan, [""] * b
    veto = torch.zeros(b, n, dtype=torch.bool)
    if any(p.markers for p in paths):
        initial = np.full((b, n, 2), np.nan)
        touched = np.full((b, n, 2), np.nan)
        spacing = np.full((b, n), np.nan)
        for k, (markers, (ids, pts, sp)) in enumerate(outputs):
            initial[k, ids], spacing[k, ids] = pts, sp
            touched[k, ids] = _touching_corners(markers, board, ids, pts)
        refined, accept = refine_marked_corners(looked, initial, spacing, factor)
        # refined again from where the markers touching each corner put it: a corner only that start confirms is
        # kept; one both starts confirm at places more than AGREE_PX apart is dropped (one of them settled on a
        # marker's edge beside the corner); one only the first confirms, farther than half the clear band from where
        # the touching markers put it, is doubtful: kept by the marker path, by both merged only where the lattice
        # path agrees
        again, sure = refine_marked_corners(looked, touched, spacing, factor)
        apart = (refined - again).norm(dim=-1) > AGREE_PX
        half_band = 0.25 * (1.0 - float(board.marker) / float(board.square))
        doubtful = accept & ~sure & ((refined - torch.from_numpy(touched).float()).norm(dim=-1) >
                                     half_band * torch.from_numpy(spacing).float())
        refined = torch.where(accept[..., None], refined, again)
        accept = torch.where(accept & sure, ~apart, accept | sure)
        marked = torch.where(accept[..., None], refined, nan)
    if any(p.lattice for p in paths):
        lattice, notes, veto = _lattice_path(looked, board, outputs, layout, factor, refused,
                                       None if MarkerPaths.LATTICE in paths else marked)
    if MarkerPaths.BOTH in paths:
        # a lattice corner farther from where the markers touching it put it than the marker path lets its own move
        # (a heatmap peak beside the corner, named by the lattice): disputed
        placed = torch.from_numpy(touched).float()
        far = (lattice - placed).norm(dim=-1) > MAX_MOVE * torch.from_numpy(spacing).float()
        veto = veto | (far & ~marked.isfinite().all(-1))
        veto = veto | (doubtful & ~((marked - lattice).norm(dim=-1) <= AGREE_PX))
    out = {}
    for path in paths:
        if path is MarkerPaths.BOTH:
            corners = merge_corners(marked, lattice, veto)[0]
        else:
            corners = marked if path is MarkerPaths.MARKERS else lattice
        named = path_counts(marked, lattice) if path is MarkerPaths.BOTH else None
        out[path] = _charuco_result(images, board, corners, outputs, notes if path.lattice else [""] * b, refused,
                                    min_corners, named)
    return out


def _charuco_result(images: torch.Tensor, board: CharucoBoard, corners: torch.Tensor, outputs: list, notes: list[str],
                    refused: torch.Tensor, min_corners: int, named: list[tuple[int, int]] | None = None
                    ) -> DetectionResult:
    """The views found (enough corners, not refused) and the reason for each; ``named``: per view, the corners the
    marker path and the lattice path named before they were merged (:func:`~ccs_kornia.modules.detection.markers.
    corner_merge.paths_note`, at the end of a found view's reason)."""
    n = board.num_corners
    count = corners.isfinite().all(-1).sum(-1)
    found = (count >= min_corners) & ~refused
    corners = torch.where(found[:, None, None], corners, torch.zeros_like(corners))
    reasons = []
    for k, (markers, _) in enumerate(outputs):
        what = f"{len(markers.ids)} {board.dictionary} markers"
        if markers.variant != "plain":
            what += f" ({markers.variant})"
        what += notes[k]
        if markers.better_layout is not None:
            name = "legacy" if markers.better_layout else "new (non-legacy)"
            reasons.append(f"the markers fit the {name} layout better ({markers.better_count} against "
                           f"{len(markers.ids)} markers): wrong layout?")
        elif markers.off_lattice:
            reasons.append(f"{markers.known - len(markers.ids)} of the board's {board.dictionary} markers are not where "
                           f"a {board.squares_x}x{board.squares_y} board puts them ({len(markers.ids)} are): wrong "
                           "board size?")
        elif bool(found[k]):
            reasons.append(f"charuco: {what}, {int(count[k])} of {n} corners"
                           + ("" if named is None else paths_note(*named[k])))
        elif markers.ambiguous:
            reasons.append("the markers fit the new and the legacy layout alike (a board with an even number of rows "
                           "of squares, seen in part): give the layout")
        elif not len(markers.ids) and not notes[k]:
            reasons.append(f"no {board.dictionary} marker of the board found")
        else:
            reasons.append(f"only {int(count[k])} corners from {what} (at least {min_corners} needed)")
    return DetectionResult(corners.to(images.device), found.to(images.device), reasons)


#: the clear band between a corner and the markers beside it spans at least this many px on the lattice path's
#: detection level (the band of a board whose markers take half their square, at the network's 9 px squares)
MIN_BAND_PX = 2.25


def lattice_level_square(board: CharucoBoard) -> float:
    """The square size (px) at which the lattice path's network looks at the board: its target
    (:data:`~ccs_kornia.modules.detection.learned.scale.TARGET_SQUARE`), or larger where the markers leave a band
    narrower than :data:`MIN_BAND_PX` there between a corner and themselves (a corner is only that band's X).

    Example:
        >>> round(lattice_level_square(CharucoBoard(5, 7, 0.04, 0.02)), 3), round(lattice_level_square(CharucoBoard(4, 5, 0.054, 0.0405)), 3)
        (9.0, 18.0)
    """
    band = 0.5 * (float(board.square) - float(board.marker)) / float(board.square)
    return float(max(TARGET_SQUARE, MIN_BAND_PX / max(band, 1e-6)))


def marker_square_size(markers: BoardMarkers) -> float:
    """A view's square size in px measured by its decoded markers (NaN without any): the median over the markers of
    the square root of their image area over their board area (in squares).

    The network's detection level then follows the board, not the scene's texture, which can mislead the scale
    estimate on a real photograph (a small board in a large room).

    Example:
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> round(marker_square_size(charuco_markers(board.render(60, margin=30), board)))
        59
    """
    if not len(markers.ids):
        return float("nan")

    def area(p: np.ndarray) -> np.ndarray:
        x, y = p[..., 0], p[..., 1]
        return 0.5 * np.abs((x * np.roll(y, -1, -1) - np.roll(x, -1, -1) * y).sum(-1))

    ratio = area(np.asarray(markers.corners, dtype=np.float64)) / area(np.asarray(markers.board_corners,
                                                                                  dtype=np.float64))
    return float(np.sqrt(np.median(ratio)))


def _lattice_path(images: torch.Tensor, board: CharucoBoard, outputs: list, layout: bool | None, factor: float,
                  refused: torch.Tensor, known: torch.Tensor | None
                  ) -> tuple[torch.Tensor, list[str], torch.Tensor]:
    """The lattice path's corners :math:`(B, N, 2)` (:mod:`~ccs_kornia.modules.detection.markers.lattice_path`; NaN
    on the views refused), a note per view whose lattice was named, and the corners it found disputed.

    Each view's lattice is named in the layout its markers fit; a view whose markers do not tell (none decoded) is
    named in either layout (the wrong one, shifted by a square, is disputed by half the markers), and where both
    explain it alike, in the batch's (``layout``), as the marker path does. ``known``: the marker path's corners,
    where the lattice path's own are not asked for
    (:func:`~ccs_kornia.modules.detection.markers.lattice_path.lattice_corners`)."""
    lattice = torch.full((images.shape[0], board.num_corners, 2), float("nan"))
    disputed = torch.zeros(images.shape[0], board.num_corners, dtype=torch.bool)
    notes = [""] * images.shape[0]
    groups: dict = {}
    for k in (~refused).nonzero().flatten().tolist():
        markers = outputs[k][0]
        groups.setdefault(bool(markers.legacy) if len(markers.ids) else None, []).append(k)

    def run(view_layout: bool | None, idx: list[int]) -> list[int]:
        spec = charuco_lattice_board(board, view_layout, factor)
        seen = [[(c, int(i), outputs[k][0].variant.endswith("inverted")) for c, i in
                 zip(outputs[k][0].corners, outputs[k][0].ids)] for k in idx]
        square = torch.tensor([marker_square_size(outputs[k][0]) for k in idx], dtype=torch.float64)
        got = lattice_corners(images[idx], spec, seen, known=None if known is None else known[idx],
                              square_size=square, level_square=lattice_level_square(board))
        lattice[idx], disputed[idx] = got.corners, got.disputed
        unnamed = []
        for j, k in enumerate(idx):
            if got.named[j] is not None and got.named[j].naming is not None:
                notes[k] = f"; {got.reasons[j]}"
            elif got.named[j] is not None and got.named[j].runner_up > 0:
                unnamed.append(k)  # two namings alike
        return unnamed

    for view_layout, idx in groups.items():
        alike = run(view_layout, idx)
        if view_layout is None and layout is not None and alike and len(charuco_lattice(board).layouts) > 1:
            run(layout, alike)
    return lattice, notes, disputed


class CharucoDetector(MarkerBoardDetector):
    """ChArUco detector with the chessboard detectors' interface (:func:`detect_charuco`): ``board_size`` is the
    board's inner grid ``(squares_x - 1, squares_y - 1)``; unseen corner ids are NaN.

    It decodes and refines at full resolution (``selects_scale``: the pipeline does not downscale its images).

    Args:
        board: the :class:`~ccs_kornia.modules.detection.boards.CharucoBoard`.
        min_corners, radius_factor, num_workers, paths: as :func:`detect_charuco`.

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
        return detect_charuco(images, self.board, self.min_corners, self.radius_factor, self.num_workers, self.paths)


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
        det = charuco_detector(name)
        hits = 0
        for img in images[:8]:
            if any(len(decode_markers(img, det, v)[1]) >= least for v in VARIANTS):
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
    detector = charuco_detector(board.dictionary)
    decoded = []
    for img in images[:3]:
        tries = [decode_markers(img, detector, v) for v in VARIANTS]
        pts, ids = max(tries, key=lambda t: len(t[1]))
        _, first = np.unique(ids, return_index=True)
        decoded.append((pts[first], ids[first]))
    if not any(len(ids) for _, ids in decoded):
        return ""
    top = max(int(ids.max()) for _, ids in decoded if len(ids))

    def explained(candidate: CharucoBoard) -> tuple[int, bool]:
        best = (0, False)
        for legacy in candidate.layouts():
            markers = board_markers(candidate, legacy)
            total = 0
            for pts, ids in decoded:
                known = np.array([int(i) in markers for i in ids], dtype=bool)
                if known.sum() >= 2:
                    obj = np.stack([markers[int(k)] for k in ids[known]])
                    total += int(consistent_markers(pts[known], obj).sum())
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
