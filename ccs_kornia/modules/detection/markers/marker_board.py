r"""The skeleton every marker board shares: markers decoded by OpenCV, checked against the board's lattice, corners
placed by the markers around them, refined, checked and grown from their refined neighbours.

:mod:`~ccs_kornia.modules.detection.markers.charuco` and :mod:`~ccs_kornia.modules.detection.markers.aprilgrid` are
its two specialisations: they say where each marker and each corner lies on their board, this module does the rest.

* **decoding** (:func:`decode_markers`): ``cv2.aruco.ArucoDetector`` on the image, its inverse (white-on-black prints)
  and both mirrored (a two-sided board seen from its back: ids decoded on the flipped image, their corners mapped
  back), :data:`VARIANTS`; and on enhanced copies of the image
  (:func:`~ccs_kornia.modules.detection.enhanced_copies.enhanced_copies`: its grey levels stretched to the contrast
  it measures, that copy sharpened, and enlarged; where the markers read are still too small for OpenCV's sampling,
  enlarged further: :func:`small_marker_scale`), their markers added to the image's own
  (:func:`decode_with_copies`): a dim view's markers span a few grey levels, a blurred one's edges are soft and a
  small one's bits a few pixels, where OpenCV's fixed thresholds read none;
* **lattice check** (:func:`consistent_markers`, :func:`markers_on_board`): the decoded markers must sit where the
  board puts their ids: a homography from the image to the board, grown from every single marker in turn, keeps the
  largest consistent set (within :data:`LATTICE_TOLERANCE` board units); markers the global homography misses (strong
  distortion) join where a homography fitted to their consistent neighbours puts them within
  :data:`LOCAL_TOLERANCE`, or their centre within :data:`LOCAL_CENTRE_TOLERANCE`;
* **refinement and check** (:func:`refine_marked_corners`): this package's saddle fit and symmetry polish; a corner the
  refinement did not confirm, whose window leaves the image, or that moved by more than :data:`MAX_MOVE` grid spacings
  from where its markers put it, is dropped (a wrong corner is worse than a missing one);
* **growth** (:func:`grow_corners`, :func:`refine_and_grow`): a corner not accepted is placed again by a homography
  of the accepted corners around it, refined and checked the same way;
* :class:`MarkerBoardDetector`: the chessboard detectors' interface for a board whose corners its markers name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.enhanced_copies import UPSCALE
from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths
from ccs_kornia.modules.detection.refine.saddle_refine import refine_corners

__all__ = [
    "CELL_PX", "COARSE_FACTOR", "LATTICE_TOLERANCE", "LOCAL_CENTRE_TOLERANCE", "LOCAL_TOLERANCE", "MAX_COPY_PIXELS", "MAX_MOVE", "MAX_RADIUS",
    "VARIANTS", "BoardMarkers", "MarkerBoardDetector", "consistent_markers", "decode_markers", "decode_with_copies",
    "fit_homography", "grow_corners", "map_points", "markers_on_board", "place_from",
    "refine_and_grow", "refine_marked_corners", "small_marker_scale",
]

#: a marker belongs to the board's lattice when its corners lie within this many board units (squares, tag sides) of
#: where the homography puts them (a wrong id lands at least 1.3 units away: the next marker of the board)
LATTICE_TOLERANCE = 0.5
#: ... or within this many units of where a homography fitted to its consistent neighbours puts them
LOCAL_TOLERANCE = 0.25
#: ... or, its centre, within this many units of where that homography puts it (its corners within twice
#: :data:`LATTICE_TOLERANCE`): near the frame of a strongly bent lens, a homography of the neighbours on one side
#: bends a marker's far corners off by more than :data:`LOCAL_TOLERANCE`, its centre less (a wrong id's centre lies
#: at least 1.3 units from its slot)
LOCAL_CENTRE_TOLERANCE = 0.5
#: a refined corner farther than this (grid spacings) from where its markers put it is dropped
MAX_MOVE = 0.25
#: largest refinement window half-size (px)
MAX_RADIUS = 12
#: a corner the refinement did not confirm is refined again from where a window of this many grid spacings puts it
#: (markers decoded on a blurred view place corners px off, farther than the narrow window reaches)
COARSE_FACTOR = 0.25
#: the order in which image variants are decoded (the first of equal counts is kept)
VARIANTS = ("plain", "inverted", "mirrored", "mirrored inverted")
#: a marker is read where each of its cells (its bits and its black border) spans this many pixels, as OpenCV samples
#: it (``perspectiveRemovePixelPerCell``); smaller markers get a further copy enlarged until their cells do
CELL_PX = 4.0
#: the largest further enlarged copy (pixels): a bound on its cost
MAX_COPY_PIXELS = 16_000_000


@dataclass
class BoardMarkers:
    """The board's markers found on one image: corners ``(M, 4, 2)`` px, ids ``(M,)``, their board corners ``(M, 4,
    2)`` in board units, the image variant (:data:`VARIANTS`) they were decoded on, how many markers were decoded
    there, and ``known``: the decoded markers whose ids the board has, on its lattice or not."""

    corners: np.ndarray
    ids: np.ndarray
    board_corners: np.ndarray
    variant: str = "plain"
    decoded: int = 0
    known: int = 0

    @staticmethod
    def none(variant: str = "plain") -> BoardMarkers:
        """No marker."""
        return BoardMarkers(np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64), np.zeros((0, 4, 2)), variant)

    @property
    def off_lattice(self) -> bool:
        """More of the board's marker ids decoded off its lattice than on it (at least 3): the markers belong to
        another board (a wrong board size), so no id of this one can be trusted."""
        return self.known - len(self.ids) >= max(3, len(self.ids) + 1)


def decode_markers(gray8: np.ndarray, detector: cv2.aruco.ArucoDetector, variant: str = "plain"
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Marker corners ``(M, 4, 2)`` (in the image's own coordinates) and ids ``(M,)`` that ``detector`` decodes on one
    variant (:data:`VARIANTS`) of the ``uint8`` grey image.

    Example:
        >>> from ccs_kornia.modules.detection.boards import CharucoBoard, aruco_dictionary
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> det = cv2.aruco.ArucoDetector(aruco_dictionary(board.dictionary))
        >>> pts, ids = decode_markers(255 - board.render(60, margin=30), det, "inverted")
        >>> pts.shape, sorted(ids.tolist())[:3]
        ((17, 4, 2), [0, 1, 2])
    """
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; expected one of {', '.join(VARIANTS)}")
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


def small_marker_scale(side_px: float, cells: int, shape: tuple[int, int]) -> float:
    """The scale of a further enlarged decoding copy for a view whose decoded markers measure ``side_px`` (their
    median side, px) across ``cells`` cells (the bits and the black border): the power of two that brings a cell to
    :data:`CELL_PX` pixels, where that is more than the first enlarged copy's :data:`UPSCALE` and the copy of an image
    of ``shape`` ``(H, W)`` stays within :data:`MAX_COPY_PIXELS` (halved until it does); 0 where no further copy is
    needed or affordable. The size comes from the markers read, so a view with no marker pays nothing.

    Example:
        >>> small_marker_scale(8.0, 6, (288, 512)), small_marker_scale(30.0, 6, (288, 512))
        (4.0, 0.0)
        >>> small_marker_scale(4.0, 6, (720, 1280))  # 8x would be 59 Mpx: 4x
        4.0
    """
    if not side_px > 0:
        return 0.0
    scale = 2.0 ** math.ceil(math.log2(CELL_PX * cells / side_px))
    while scale > UPSCALE and scale * scale * shape[0] * shape[1] > MAX_COPY_PIXELS:
        scale /= 2.0
    return scale if scale > UPSCALE else 0.0


def decode_with_copies(decoded: tuple[np.ndarray, np.ndarray], copies: list[tuple[np.ndarray, float]],
                       detector: cv2.aruco.ArucoDetector, variant: str = "plain") -> tuple[np.ndarray, np.ndarray]:
    """The markers ``decoded`` on the image (corners ``(M, 4, 2)``, ids ``(M,)``: :func:`decode_markers`) followed by
    those decoded on the same variant of its ``copies``
    (:func:`~ccs_kornia.modules.detection.enhanced_copies.enhanced_copies`), their corners in the image's pixels
    (an id decoded twice is the first: :func:`markers_on_board` keeps it once).

    Example:
        >>> from ccs_kornia.modules.detection.boards import CharucoBoard, aruco_dictionary
        >>> from ccs_kornia.modules.detection.enhanced_copies import enhanced_copies
        >>> board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
        >>> dim = (board.render(60, margin=30) * 0.03).astype(np.uint8)  # 8 grey levels
        >>> det = cv2.aruco.ArucoDetector(aruco_dictionary(board.dictionary))
        >>> mine = decode_markers(dim, det)
        >>> len(mine[1]), len(np.unique(decode_with_copies(mine, enhanced_copies(dim), det)[1]))
        (0, 17)
    """
    pts, ids = [decoded[0]], [decoded[1]]
    for image, scale in copies:
        p, i = decode_markers(image, detector, variant)
        pts.append((p + 0.5) / scale - 0.5)
        ids.append(i)
    return np.concatenate(pts), np.concatenate(ids)


def map_points(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points ``(..., 2)`` through the homography ``h`` ``(3, 3)``.

    Example:
        >>> map_points(np.diag([2.0, 2.0, 1.0]), np.array([[1.0, 3.0]])).tolist()
        [[2.0, 6.0]]
    """
    q = np.concatenate([pts, np.ones_like(pts[..., :1])], -1) @ np.asarray(h).T
    return q[..., :2] / q[..., 2:3]


def fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """The least-squares homography ``src`` -> ``dst`` (points ``(..., 2)``, at least 4), ``None`` where degenerate.

    Example:
        >>> src = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        >>> np.allclose(fit_homography(src, 3 * src + 1), [[3, 0, 1], [0, 3, 1], [0, 0, 1]])
        True
    """
    src, dst = np.asarray(src, dtype=np.float64).reshape(-1, 2), np.asarray(dst, dtype=np.float64).reshape(-1, 2)
    if len(src) < 4:
        return None
    h, _ = cv2.findHomography(src, dst, 0)
    return h if h is not None and np.isfinite(h).all() and abs(np.linalg.det(h)) > 1e-12 else None


def consistent_markers(image_pts: np.ndarray, board_pts: np.ndarray) -> np.ndarray:
    """Mask ``(M,)`` of the markers (corners ``(M, 4, 2)`` px, on the board ``(M, 4, 2)``) consistent with the board:
    the largest set a homography (image -> board) grown from each single marker explains within
    :data:`LATTICE_TOLERANCE`, then the markers a homography of their consistent neighbours explains within
    :data:`LOCAL_TOLERANCE` (or their centre within :data:`LOCAL_CENTRE_TOLERANCE`). At least two markers: a lone
    marker cannot be checked.

    Example:
        >>> board = np.array([[[0, 0], [1, 0], [1, 1], [0, 1]], [[2, 0], [3, 0], [3, 1], [2, 1]],
        ...                   [[0, 2], [1, 2], [1, 3], [0, 3]]], dtype=float)
        >>> image = board * 40 + 10
        >>> image[2] += 80  # a third marker where the board puts another id
        >>> consistent_markers(image, board).tolist()
        [True, True, False]
    """
    m = len(image_pts)
    best = np.zeros(m, dtype=bool)
    if m < 2:
        return best
    for seed in range(m):
        keep = np.zeros(m, dtype=bool)
        keep[seed] = True
        for _ in range(4):
            h = fit_homography(image_pts[keep], board_pts[keep])
            if h is None:
                break
            err = np.linalg.norm(map_points(h, image_pts) - board_pts, axis=-1).max(-1)
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
            h = fit_homography(image_pts[near], board_pts[near])
            if h is None:
                continue
            placed = map_points(h, image_pts[k])
            err = np.linalg.norm(placed - board_pts[k], axis=-1).max()
            if err < LOCAL_TOLERANCE or (err < 2.0 * LATTICE_TOLERANCE and np.linalg.norm(
                    placed.mean(0) - centres[k]) < LOCAL_CENTRE_TOLERANCE):
                best[k] = changed = True
    return best


def markers_on_board(pts: np.ndarray, ids: np.ndarray, layout: dict[int, np.ndarray], variant: str = "plain",
                     beat: int = 0) -> BoardMarkers | None:
    """The decoded markers (corners ``pts`` ``(M, 4, 2)``, ``ids`` ``(M,)``) that the board ``layout`` (marker id ->
    its corners ``(4, 2)`` on the board) has, each id once, and that sit on its lattice (:func:`consistent_markers`);
    ``None`` where they are no more than ``beat`` markers.

    Example:
        >>> layout = {0: np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float), 1: np.array([[2, 0], [3, 0], [3, 1],
        ...           [2, 1]], float)}
        >>> m = markers_on_board(np.stack([layout[0], layout[1]]) * 30, np.array([0, 1]), layout)
        >>> m.ids.tolist(), m.known
        ([0, 1], 2)
    """
    known = np.array([int(i) in layout for i in ids], dtype=bool)
    _, first = np.unique(ids, return_index=True)  # an id decoded twice: the first only
    known &= np.isin(np.arange(len(ids)), first)
    if known.sum() <= beat:
        return None  # cannot beat the best consistent set
    p, i = pts[known], ids[known]
    obj = np.stack([layout[int(k)] for k in i])
    keep = consistent_markers(p, obj)
    if keep.sum() <= beat:
        return None
    return BoardMarkers(p[keep], i[keep], obj[keep], variant, len(ids), int(known.sum()))


def refine_marked_corners(images: torch.Tensor, initial: np.ndarray, spacing: np.ndarray, factor: float
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """Refinement and check of corners placed by markers: the refined corners :math:`(B, N, 2)` and which are accepted
    :math:`(B, N)`, from ``initial`` :math:`(B, N, 2)` px (NaN: not placed) and the local grid ``spacing``
    :math:`(B, N)` px; the window's half-size is ``factor`` spacings (at least 1.5 px, at most :data:`MAX_RADIUS`).
    A corner is accepted where the refinement confirmed it, its window lies on the image and it moved by at most
    :data:`MAX_MOVE` spacings. A corner the window does not confirm is refined once more from where a wider window
    (:data:`COARSE_FACTOR` spacings) takes it, the narrow window again deciding.

    Example:
        >>> img = torch.zeros(1, 1, 40, 40)
        >>> img[..., :20, :20] = img[..., 20:, 20:] = 1.0
        >>> out, ok = refine_marked_corners(img, np.array([[[19.0, 20.0]]]), np.array([[20.0]]), 0.2)
        >>> ok.tolist(), [round(v, 2) for v in out[0, 0].tolist()]
        ([[True]], [19.5, 19.5])
    """
    _, _, h, w = images.shape
    seen = torch.from_numpy(np.isfinite(initial).all(-1))
    start = torch.from_numpy(np.nan_to_num(initial)).float()
    space = torch.from_numpy(np.nan_to_num(spacing, nan=1.0)).float()
    radius = (float(factor) * space).clamp(1.5, MAX_RADIUS)
    gray = images.detach().float().cpu()
    refined, ok = refine_corners(gray, start, seen, radius, "symmetric", max_radius=MAX_RADIUS, return_ok=True)
    coarse = (COARSE_FACTOR * space).clamp(1.5, MAX_RADIUS)
    retry = seen & ~ok & (coarse > radius)
    if retry.any():
        # the wide window only brings the corner within the narrow one's reach; the narrow one decides
        near, found = refine_corners(gray, start, retry, coarse, "symmetric", max_radius=MAX_RADIUS, return_ok=True)
        again, sure = refine_corners(gray, near, retry & found, radius, "symmetric", max_radius=MAX_RADIUS,
                                     return_ok=True)
        take = retry & found & sure
        refined = torch.where(take[..., None], again, refined)
        ok = ok | take
    moved = (refined - start).norm(dim=-1)
    # the window must lie on the image: at the frame the border's replicated pixels pull a corner off by px
    inside = (refined >= radius[..., None]).all(-1)
    inside &= (refined[..., 0] <= w - 1 - radius) & (refined[..., 1] <= h - 1 - radius)
    accept = seen & ok & inside & (moved <= MAX_MOVE * space) & refined.isfinite().all(-1)
    return refined, accept


_STEPS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def place_from(hom: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, float]:
    """Where the homography ``hom`` (board -> image) puts the board ``point`` ``(2,)``, and the grid spacing there (px
    per board unit: the nearest of the four points a unit away)."""
    p = map_points(hom, np.concatenate([point[None], point + _STEPS]))
    return p[0], float(np.linalg.norm(p[1:] - p[0], axis=-1).min())


def grow_corners(refined: np.ndarray, skip: np.ndarray, accept: np.ndarray, board_points: np.ndarray, reach: float,
                 support: int) -> tuple[np.ndarray, np.ndarray]:
    """Corners not accepted (nor in ``skip``) placed :math:`(B, N, 2)` (NaN elsewhere) by a homography of the accepted
    ``refined`` corners :math:`(B, N, 2)` within ``reach`` board units of them on the board (``board_points``
    :math:`(N, 2)`), at least ``support`` of them, and the grid spacing there in px :math:`(B, N)`.

    Example:
        >>> board = np.stack(np.meshgrid(np.arange(4.0), np.arange(3.0)), -1).reshape(-1, 2)
        >>> refined = (board * 20 + 5)[None]
        >>> accept = np.ones((1, 12), dtype=bool)
        >>> accept[0, 5] = False
        >>> placed, space = grow_corners(refined, accept, accept, board, 1.5, 6)
        >>> placed[0, 5].round(3).tolist(), float(space[0, 5])
        ([25.0, 25.0], 20.0)
    """
    near = np.linalg.norm(board_points[:, None] - board_points[None], axis=-1) < reach
    out = np.full(refined.shape, np.nan)
    space = np.full(refined.shape[:2], np.nan)
    for k in range(refined.shape[0]):
        counts = near[:, accept[k]].sum(-1)
        for i in np.flatnonzero(~skip[k] & (counts >= support)):
            use = near[i] & accept[k]
            hom = fit_homography(board_points[use], refined[k, use])
            if hom is None:
                continue
            p, s = place_from(hom, board_points[i])
            if np.isfinite(p).all():
                out[k, i], space[k, i] = p, s
    return out, space


def refine_and_grow(images: torch.Tensor, initial: np.ndarray, spacing: np.ndarray, factor: float,
                    board_points: np.ndarray, reach: float, support: int, rounds: int,
                    fixed: np.ndarray | None = None, blocked: np.ndarray | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`refine_marked_corners`, then ``rounds`` of :func:`grow_corners` (each corner not accepted placed by its
    accepted neighbours once at most), each refined and checked the same way: the corners :math:`(B, N, 2)` and which
    are accepted :math:`(B, N)`. ``fixed`` :math:`(B, N, 2)`: corners accepted as they are (refined already; NaN
    elsewhere), in place of ``initial``; ``blocked`` :math:`(B, N)`: corners the growth never places.

    Example:
        >>> img = torch.zeros(1, 1, 80, 100)
        >>> for i in range(5):
        ...     for j in range(4):
        ...         if (i + j) % 2 == 0:
        ...             img[..., 10 + 15 * j:25 + 15 * j, 10 + 15 * i:25 + 15 * i] = 1.0
        >>> board = np.stack(np.meshgrid(np.arange(4.0), np.arange(3.0)), -1).reshape(-1, 2)
        >>> initial = board[None] * 15 + 24.5
        >>> initial[0, [5, 6]] = np.nan  # two corners left for the growth
        >>> out, ok = refine_and_grow(img, initial, np.full((1, 12), 15.0), 0.2, board, 1.5, 6, 2)
        >>> bool(ok.all()), [round(v, 2) for v in out[0, 5].tolist()]
        (True, [39.5, 39.5])
    """
    if fixed is not None:
        have = np.isfinite(fixed).all(-1)
        initial = np.where(have[..., None], np.nan, initial)
    refined, accept = refine_marked_corners(images, initial, spacing, factor)
    if fixed is not None:
        refined = torch.where(torch.from_numpy(have)[..., None], torch.from_numpy(fixed).to(refined), refined)
        accept = accept | torch.from_numpy(have)
    # a corner placed first but not accepted may be placed again
    tried = np.zeros(accept.shape, dtype=bool) if blocked is None else np.asarray(blocked, dtype=bool).copy()
    for _ in range(rounds):
        again, space = grow_corners(refined.double().numpy(), tried | accept.numpy(), accept.numpy(), board_points,
                                    reach, support)
        placed = np.isfinite(again).all(-1)
        if not placed.any():
            break
        tried |= placed
        refined2, accept2 = refine_marked_corners(images, again, space, factor)
        accept2 &= torch.from_numpy(placed)
        refined = torch.where(accept2[..., None], refined2, refined)
        accept = accept | accept2
    return refined, accept


class MarkerBoardDetector(ChessboardDetector):
    """A board whose corners the decoded markers name, with the chessboard detectors' interface: ``board_size`` must
    be the board's corner grid (``board.board_size``); unseen corner ids are NaN. Subclasses give the detection
    (:meth:`detect_board`) and say what the grid is (:attr:`grid_name`, :meth:`layout`).

    It decodes and refines at full resolution (``selects_scale``: the pipeline does not downscale its images).

    Args:
        board: the board description (:mod:`~ccs_kornia.modules.detection.boards`).
        min_corners: corners a view needs to count as found.
        radius_factor, num_workers: of the detection function.
        paths: the marker path, the lattice path or both merged (the default;
            :class:`~ccs_kornia.modules.detection.markers.corner_merge.MarkerPaths`).
    """

    selects_scale = True
    #: the grid's name in the error for a wrong ``board_size``
    grid_name = "the board's corner grid"

    def __init__(self, board, min_corners: int = 6, radius_factor: float | None = None,
                 num_workers: int | None = None, paths: MarkerPaths = MarkerPaths.BOTH) -> None:
        super().__init__()
        self.board = board
        self.min_corners = int(min_corners)
        self.radius_factor = radius_factor
        self.num_workers = num_workers
        self.paths = MarkerPaths(paths)

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
