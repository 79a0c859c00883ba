r"""AprilGrid corners with partial views: OpenCV's tag ids, this package's corners.

Kalibr's AprilGrid (:class:`~ccs_kornia.modules.detection.boards.AprilGrid`) puts a small black square beside every
corner of its AprilTags, so each tag corner is an X-junction between the tag's black border and that square: the
same saddle the chessboard refinement measures. The steps are the shared ones of
:mod:`~ccs_kornia.modules.detection.markers.marker_board`, with the grid's own geometry:

1. **tags**: ``cv2.aruco.ArucoDetector`` (``DICT_APRILTAG_36h11``, two border bits as Kalibr prints them) decodes
   the tags on the image, its inverse (white-on-black prints) and both mirrored (a board seen from its back);
2. **lattice**: the decoded tags must sit where the grid puts their ids (a homography grown from each tag, tags
   within :data:`~ccs_kornia.modules.detection.markers.marker_board.LATTICE_TOLERANCE` tag sides; at least two tags: a
   lone tag cannot be checked); ids beyond the grid's tags are dropped; the variant with the most consistent tags is
   kept; a view with more of the grid's tags off its lattice than on it is refused (the tags of another grid: a wrong
   ``tagCols``/``tagRows``);
3. **initial corners**: each corner of a consistent tag from a homography of the tags around it
   (:data:`NEIGHBOUR_RADIUS` grid pitches);
4. **refinement and check**: :func:`~ccs_kornia.modules.detection.markers.marker_board.refine_marked_corners` with a
   window inside the clear X-junction (:func:`aprilgrid_radius_factor`): a corner the refinement did not confirm,
   whose window leaves the image or that moved too far is dropped;
5. **growth**: OpenCV's tag corners can be a px or two off, more than that small window forgives, and a tag that did
   not decode (blur, low light) places none: a corner not accepted is placed
   (:func:`~ccs_kornia.modules.detection.markers.marker_board.grow_corners`) by a homography of at least
   :data:`GROWTH_SUPPORT` accepted corners around it (:data:`NEIGHBOUR_RADIUS` pitches) and refined and checked as
   in step 4, for :data:`GROWTH_ROUNDS` rounds. Its id is its place in the lattice those corners fix; the saddle it
   lands on must lie within a quarter of a tag side of that place (the nearest other corner is ``tag_spacing``
   tag sides away).

These steps are the **marker path**. The **lattice path** (:mod:`~ccs_kornia.modules.detection.markers.lattice_path`)
groups the heatmap network's corner peaks into the small squares between the tags, organises those into a lattice
and names it from the tags that agree, those OpenCV decodes and those read on the lattice's squares
(:func:`aprilgrid_lattice_board`; a grid needs at least 4 x 4 tags: 3 x 3 small squares between them). Both paths
run by default and are merged per corner (:func:`~ccs_kornia.modules.detection.markers.corner_merge.merge_corners`).

The result is the package's :class:`~ccs_kornia.modules.detection.base.DetectionResult` with one slot per corner id
in Kalibr's numbering, NaN where a corner is not seen.
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.boards import (
    APRILGRID_BORDER_BITS,
    AprilGrid,
    aruco_dictionary,
)
from ccs_kornia.modules.detection.markers.corner_merge import (
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
    VARIANTS,
    BoardMarkers,
    MarkerBoardDetector,
    decode_markers,
    fit_homography,
    markers_on_board,
    place_from,
    refine_and_grow,
)
from ccs_kornia.modules.detection.refine.saddle_refine import POLISH_WINDOW
from ccs_kornia.runtime.checks import check_grey_images

__all__ = ["GROUP", "GROWTH_ROUNDS", "GROWTH_SUPPORT", "NEIGHBOUR_RADIUS", "AprilGridDetector",
           "aprilgrid_lattice", "aprilgrid_lattice_board", "aprilgrid_paths", "aprilgrid_radius_factor",
           "aprilgrid_tags", "board_tags",
           "detect_aprilgrid", "tag_detector"]

#: tags whose centre lies within this many grid pitches (tag side plus gap) of a corner place it: its own tag and the
#: three others around it
NEIGHBOUR_RADIUS = 1.2
#: a corner not placed by its tag (or placed too far off) is placed by at least this many accepted corners around it
GROWTH_SUPPORT = 6
#: rounds of that growth (each can place corners next to the ones the round before accepted)
GROWTH_ROUNDS = 3
#: the lattice path groups corner peaks closer than these many times the median nearest-peak distance into one small
#: square (its corners are ``tag_spacing`` apart, the next corners a tag side; :func:`~ccs_kornia.modules.detection.
#: markers.lattice_path.group_peaks`)
GROUP = (1.3, 1.6)


def tag_detector(board: AprilGrid) -> cv2.aruco.ArucoDetector:
    """OpenCV's marker detector for the grid's tags (its dictionary, :data:`APRILGRID_BORDER_BITS` border bits)."""
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = APRILGRID_BORDER_BITS
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(aruco_dictionary(board.dictionary), params)


def aprilgrid_radius_factor(board: AprilGrid) -> float:
    """The refinement window's half-size in tag sides: the saddle fit's window and the symmetry polish's
    (:data:`~ccs_kornia.modules.detection.refine.saddle_refine.POLISH_WINDOW` times larger) stay inside the X-junction, whose
    arms are the tag's border (two of its ten bits) and the corner square (``tag_spacing``).

    Example:
        >>> round(aprilgrid_radius_factor(AprilGrid(6, 6, 0.088, 0.3)), 3)
        0.107
    """
    border = APRILGRID_BORDER_BITS / (6.0 + 2 * APRILGRID_BORDER_BITS)
    return float(0.8 * min(border, float(board.tag_spacing)) / POLISH_WINDOW)


def board_tags(board: AprilGrid) -> dict[int, np.ndarray]:
    """Tag id -> its corners ``(4, 2)`` on the board in tag sides, in OpenCV's corner order for the tag as Kalibr
    prints it (OpenCV's marker turned by 180 degrees: bottom right, bottom left, top left, top right).

    Example:
        >>> board_tags(AprilGrid(4, 3, 0.05, 0.3))[0].tolist()
        [[1.0, 0.0], [0.0, 0.0], [0.0, 1.0], [1.0, 1.0]]
    """
    obj = board.object_points().numpy()[:, :2] / float(board.tag_size)
    out = {}
    for t in range(board.num_tags):
        bl, br, tr, tl = board.tag_corner_ids(t)
        out[t] = obj[[br, bl, tl, tr]]
    return out


def aprilgrid_tags(gray8: np.ndarray, board: AprilGrid, detector: cv2.aruco.ArucoDetector | None = None
                   ) -> BoardMarkers:
    """The grid's tags on a ``uint8`` grey image (steps 1 and 2): corners ``(M, 4, 2)`` px, ids, their board corners
    in tag sides, the image variant they were decoded on.

    Example:
        >>> g = AprilGrid(4, 3, 0.05, 0.3)
        >>> tags = aprilgrid_tags(g.render(6), g)
        >>> len(tags.ids), tags.variant
        (12, 'plain')
    """
    detector = tag_detector(board) if detector is None else detector
    tags = board_tags(board)
    best = BoardMarkers.none()
    for variant in VARIANTS:
        pts, ids = decode_markers(gray8, detector, variant)
        got = markers_on_board(pts, ids, tags, variant, len(best.ids))
        best = best if got is None else got
    return best


def _initial_corners(tags: BoardMarkers, board: AprilGrid, image_size: tuple[int, int]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each corner of a consistent tag from a homography of the tags around it: ids ``(K,)``, points ``(K, 2)`` px,
    one tag side ``(K,)`` px there (the nearest of the four points a tag side away that the homography places)."""
    if len(tags.ids) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0)
    obj = board.object_points().numpy()[:, :2] / float(board.tag_size)
    centres = tags.board_corners.mean(1)
    reach = NEIGHBOUR_RADIUS * (1.0 + float(board.tag_spacing))
    w, h = image_size
    ids, points, spacing = [], [], []
    for tag in tags.ids:
        for cid in board.tag_corner_ids(int(tag)):
            c = obj[cid]
            near = np.linalg.norm(centres - c, axis=-1) < reach
            hom = fit_homography(tags.board_corners[near], tags.corners[near])
            if hom is None:
                continue
            p, space = place_from(hom, c)
            if not (np.isfinite(p).all() and 0 <= p[0] <= w - 1 and 0 <= p[1] <= h - 1):
                continue
            ids.append(cid)
            points.append(p)
            spacing.append(space)
    return np.array(ids, dtype=np.int64), np.array(points).reshape(-1, 2), np.array(spacing)


@functools.lru_cache(maxsize=8)
def aprilgrid_lattice(board: AprilGrid) -> BoardLattice:
    """The grid's lattice for naming (:mod:`~ccs_kornia.modules.detection.markers.lattice_names`): the small black
    squares between its tags, ``(tag_cols + 1) x (tag_rows + 1)`` of them, square ``(i, j)`` centred at
    ``(i, j) * (1 + tag_spacing) - tag_spacing / 2`` tag sides; its tags (:func:`board_tags`).

    Example:
        >>> lat = aprilgrid_lattice(AprilGrid(4, 3, 0.05, 0.3))
        >>> lat.size, lat.origin, round(lat.pitch, 2)
        ((5, 4), (-0.15, -0.15), 1.3)
    """
    s = float(board.tag_spacing)
    tags = board_tags(board)
    codes = MarkerCodes.of(board.dictionary, sorted(tags), APRILGRID_BORDER_BITS)
    return BoardLattice((board.tag_cols + 1, board.tag_rows + 1), (-0.5 * s, -0.5 * s), 1.0 + s, {False: tags},
                        CodeTemplates(codes))


def aprilgrid_lattice_board(board: AprilGrid, radius_factor: float | None = None) -> LatticeBoard:
    """The grid as the lattice path sees it (:class:`~ccs_kornia.modules.detection.markers.lattice_path.
    LatticeBoard`): its lattice points are the small squares, each the centre of the (up to four) corner peaks around
    it (:data:`GROUP`); a tag takes ``1 / (1 + tag_spacing)`` of a lattice square; the refinement window is
    :func:`aprilgrid_radius_factor`'s and the growth the marker path's.

    Example:
        >>> aprilgrid_lattice_board(AprilGrid(4, 3, 0.05, 0.3)).corners[:3].tolist()
        [[0.0, 0.0], [1.0, 0.0], [1.3, 0.0]]
    """
    obj = board.object_points().numpy()[:, :2].astype(np.float64) / float(board.tag_size)
    factor = aprilgrid_radius_factor(board) if radius_factor is None else float(radius_factor)
    s = float(board.tag_spacing)
    return LatticeBoard(aprilgrid_lattice(board), obj, 1.0 / (1.0 + s), factor, NEIGHBOUR_RADIUS * (1.0 + s),
                        GROWTH_SUPPORT, GROUP)


def detect_aprilgrid(
    images: torch.Tensor,
    board: AprilGrid,
    min_corners: int = 6,
    radius_factor: float | None = None,
    num_workers: int | None = None,
    paths: MarkerPaths = MarkerPaths.BOTH,
) -> DetectionResult:
    r"""AprilGrid corners with their ids on a batch of images (the module docstring gives the steps).

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        board: the :class:`~ccs_kornia.modules.detection.boards.AprilGrid`.
        min_corners: a view with fewer accepted corners is not found.
        radius_factor: refinement window in tag sides; ``None``: :func:`aprilgrid_radius_factor`.
        num_workers: threads over the images for the tag decoding; ``None``: ``min(8, cpu count)``.
        paths: the marker path (the steps above), the lattice path or both merged
            (:class:`~ccs_kornia.modules.detection.markers.corner_merge.MarkerPaths`).

    Returns:
        :class:`DetectionResult`: corners :math:`(B, N, 2)`, ``N = 4 * tags`` in Kalibr's corner order (NaN where
        a corner is not seen; zeros on views not found), found :math:`(B,)`, reasons.

    Example:
        >>> g = AprilGrid(4, 3, 0.05, 0.3)
        >>> art, a = g.texture(6)
        >>> out = detect_aprilgrid(torch.from_numpy(art).float()[None, None] / 255, g)
        >>> out.corners.shape, out.found.tolist(), int(out.valid.sum())
        (torch.Size([1, 48, 2]), [True], 48)
        >>> truth = torch.from_numpy(g.object_points().numpy()[:, :2] @ a[:, :2].T + a[:, 2]).float()
        >>> bool(((out.corners[0] - truth).abs() < 0.05).all())
        True
    """
    paths = MarkerPaths(paths)
    return aprilgrid_paths(images, board, min_corners, radius_factor, num_workers, (paths,))[paths]


def aprilgrid_paths(
    images: torch.Tensor,
    board: AprilGrid,
    min_corners: int = 6,
    radius_factor: float | None = None,
    num_workers: int | None = None,
    paths: tuple[MarkerPaths, ...] = tuple(MarkerPaths),
) -> dict[MarkerPaths, DetectionResult]:
    r""":func:`detect_aprilgrid` for each of ``paths`` from one run (each path computed once): ``{path: result}``.

    Example:
        >>> g = AprilGrid(4, 4, 0.05, 0.3)  # the lattice path needs 3 x 3 small squares between the tags
        >>> art, _ = g.texture(6)
        >>> out = aprilgrid_paths(torch.from_numpy(art).float()[None, None] / 255, g)
        >>> [int(out[p].valid.sum()) for p in MarkerPaths]
        [64, 64, 64]
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
            found_tags = list(pool.map(lambda a: aprilgrid_tags(a, board, tag_detector(board)), arrays))
    else:
        found_tags = [aprilgrid_tags(a, board, tag_detector(board)) for a in arrays]
    refused = torch.tensor([tags.off_lattice for tags in found_tags], dtype=torch.bool)
    factor = aprilgrid_radius_factor(board) if radius_factor is None else float(radius_factor)

    nan = torch.full((b, n, 2), float("nan"))
    marked, lattice, notes = nan, nan.clone(), [""] * b
    veto = torch.zeros(b, n, dtype=torch.bool)
    if any(p.markers for p in paths):
        initial = np.full((b, n, 2), np.nan)
        spacing = np.full((b, n), np.nan)
        for k, tags in enumerate(found_tags):
            ids, pts, sp = _initial_corners(tags, board, (w, h))
            initial[k, ids], spacing[k, ids] = pts, sp
        obj = board.object_points().numpy()[:, :2] / float(board.tag_size)
        reach = NEIGHBOUR_RADIUS * (1.0 + float(board.tag_spacing))
        refined, accept = refine_and_grow(images, initial, spacing, factor, obj, reach, GROWTH_SUPPORT, GROWTH_ROUNDS)
        marked = torch.where(accept[..., None], refined, nan)
    todo = (~refused).nonzero().flatten().tolist()
    if any(p.lattice for p in paths) and todo:
        seen = [[(c, int(i), found_tags[k].variant.endswith("inverted")) for c, i in
                 zip(found_tags[k].corners, found_tags[k].ids)] for k in todo]
        known = None if MarkerPaths.LATTICE in paths else marked[todo]  # the lattice path's own corners not asked for
        got = lattice_corners(images[todo], aprilgrid_lattice_board(board, factor), seen, known=known)
        lattice[todo], veto[todo] = got.corners, got.disputed
        for j, k in enumerate(todo):
            if got.named[j] is not None and got.named[j].naming is not None:
                notes[k] = f"; {got.reasons[j]}"
    out = {}
    for path in paths:
        if path is MarkerPaths.BOTH:
            corners = merge_corners(marked, lattice, veto)[0]
        else:
            corners = marked if path is MarkerPaths.MARKERS else lattice
        named = path_counts(marked, lattice) if path is MarkerPaths.BOTH else None
        out[path] = _aprilgrid_result(images, board, corners, found_tags, notes if path.lattice else [""] * b,
                                      refused, min_corners, named)
    return out


def _aprilgrid_result(images: torch.Tensor, board: AprilGrid, corners: torch.Tensor, found_tags: list,
                      notes: list[str], refused: torch.Tensor, min_corners: int,
                      named: list[tuple[int, int]] | None = None) -> DetectionResult:
    """The views found (enough corners, not refused) and the reason for each; ``named``: per view, the corners the
    marker path and the lattice path named before they were merged (:func:`~ccs_kornia.modules.detection.markers.
    corner_merge.paths_note`, at the end of a found view's reason)."""
    n = board.num_corners
    count = corners.isfinite().all(-1).sum(-1)
    found = (count >= min_corners) & ~refused
    corners = torch.where(found[:, None, None], corners, torch.zeros_like(corners))
    reasons = []
    for k, tags in enumerate(found_tags):
        what = f"{len(tags.ids)} tags" + (f" ({tags.variant})" if tags.variant != "plain" else "") + notes[k]
        if tags.off_lattice:
            reasons.append(f"{tags.known - len(tags.ids)} of the grid's tags are not where a {board.tag_cols}x"
                           f"{board.tag_rows} AprilGrid puts them ({len(tags.ids)} are): wrong tagCols or tagRows?")
        elif bool(found[k]):
            reasons.append(f"aprilgrid: {what}, {int(count[k])} of {n} corners"
                           + ("" if named is None else paths_note(*named[k])))
        elif not len(tags.ids) and not notes[k]:
            reasons.append(f"no two {board.dictionary} tags of the grid found where it puts them")
        else:
            reasons.append(f"only {int(count[k])} corners from {what} (at least {min_corners} needed)")
    return DetectionResult(corners.to(images.device), found.to(images.device), reasons)


class AprilGridDetector(MarkerBoardDetector):
    """AprilGrid detector with the chessboard detectors' interface (:func:`detect_aprilgrid`): ``board_size`` is the
    corner grid ``(2 * tag_cols, 2 * tag_rows)``; unseen corner ids are NaN.

    It decodes and refines at full resolution (``selects_scale``: the pipeline does not downscale its images).

    Args:
        board: the :class:`~ccs_kornia.modules.detection.boards.AprilGrid`.
        min_corners, radius_factor, num_workers, paths: as :func:`detect_aprilgrid`.

    Example:
        >>> g = AprilGrid(6, 6, 0.088, 0.3)
        >>> out = AprilGridDetector(g)(torch.zeros(2, 1, 64, 64), g.board_size)
        >>> out.corners.shape, out.found.tolist()
        (torch.Size([2, 144, 2]), [False, False])
    """

    grid_name = "the AprilGrid's corner grid"

    def layout(self) -> str:
        return f"{self.board.tag_cols}x{self.board.tag_rows} tags"

    def detect_board(self, images: torch.Tensor) -> DetectionResult:
        return detect_aprilgrid(images, self.board, self.min_corners, self.radius_factor, self.num_workers, self.paths)
