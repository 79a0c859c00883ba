"""Which screened frames go to the full detector: still boards in poses not seen yet, at most ``max_frames``.

The screening pass (:mod:`~ccs_kornia.pipeline.screening`) says, for every frame of a recording, whether the board is
there and its rough outline. A minute at 30 frames/s holds hundreds of sightings, most of them near copies of one
another, some of them of a board in motion (blurred, and bent by a rolling shutter); the full detector costs a few
frames a second. :func:`choose_frames` keeps a bounded set:

1. **still**: a board's *motion* is how far its outline moves per frame period between neighbouring screened frames
   (the larger of the two sides); a frame moving more than ``max_motion`` is left out (``moving``), unless fewer than
   :data:`MIN_STILL` still frames remain (then the stillest moving ones are admitted), or unless the still frames do
   not cover the poses: where the board planes of a camera's still frames (:func:`outline_normals`, from each
   outline's vanishing line) lie within :data:`MIN_TILT_SPREAD` of each other, its moving frames that move at most
   ``max_moving`` are admitted where they spread the planes wider, by a quarter of that angle at least (a board that
   never stops in the poses that matter still calibrates the camera): the choice below weighs each frame by its
   stillness, so of two poses alike the stiller comes first, and the corners' own precision weighs the blur that is
   left in the solve;
2. **new and spread out**: the frames are taken greedily, each time the one farthest (in outline distance,
   :func:`outline_distance`, as a fraction of the board's size in the image: the smaller outline's RMS distance of
   its corners from their centre) from those taken already, weighted by its stillness and, for a rig, by the cameras
   that see it; a frame within ``min_change`` of a taken one is a ``near copy`` and stays out (with ``copies``: waits
   until every new pose is taken, then fills what is left of ``max_frames``, farthest first); at most ``max_frames``.
   Measured against the board, not the image: a small board far away moves little in the image when it turns to a
   new pose. Another still frame of a pose is another measurement of it: the detector's and the renderer's noise on
   one frame average over its copies, which is what the frame selection takes them for.

A rig is chosen by *instants* (its cameras' frames paired by :mod:`~ccs_kornia.pipeline.frame_matching`): an instant
is as new as the newest pose it shows one of the cameras that see it (its distance to the nearest chosen instant
that camera sees), and an instant seen by more cameras weighs more, so the frames that tie the cameras together come
first. A recording of at most ``max_frames`` instants keeps them all (the full detector
decides, and no frame the screen missed is lost); where the screen saw no board at all, :data:`NO_BOARD_LOOKS`
instants (at most ``max_frames``) spread evenly over the recording go to the full detector (a board the quick look
misses may still be found).

The choice records, per camera and instant, why a frame was left out; a later frame choice (the corners' own
precision, the projection uncertainty) can start from :attr:`FrameChoice.chosen` and these records.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ccs_kornia.modules.detection.screening import Sighting

__all__ = ["CANDIDATES_PER_FRAME", "DEFAULT_MAX_FRAMES", "FrameChoice", "MAX_MOTION", "MAX_MOVING_MOTION",
           "MIN_STILL", "MIN_TILT_SPREAD", "NO_BOARD_LOOKS", "board_motion", "choose_frames", "detector_frames",
           "outline_distance", "outline_normals", "plane_spread"]

#: frames of a recording (instants of a rig) sent to the full detector at most, by default
DEFAULT_MAX_FRAMES = 60
#: with the frame selection (:mod:`~ccs_kornia.pipeline.frame_selection`), the full detector sees this many frames per
#: frame kept at most: the selection chooses among them
CANDIDATES_PER_FRAME = 1.5
#: largest board motion of a still frame, as a fraction of the image diagonal per frame period (1.5 px at 1280x720): a
#: rolling shutter bends a board that moves, which no corner precision shows, and even 2-3 px a frame costs the camera
#: more than the poses it adds (``docs/video.md``; the frame selection weighs the motion that passes:
#: :func:`~ccs_kornia.pipeline.frame_selection.motion_weight`)
MAX_MOTION = 0.001
#: two frames whose outlines differ by less than this fraction of the board's size in the image (mean corner
#: distance against the smaller outline's RMS distance of its corners from their centre) are copies
MIN_CHANGE = 0.1
#: still frames needed before moving ones are left out
MIN_STILL = 12
#: a camera's still frames whose board planes lie within this angle of each other (deg, the largest between two) do
#: not cover the poses: its moving frames come in (the solver warns of nearly parallel boards below the same angle:
#: :class:`~ccs_kornia.modules.calibration.quality.degeneracy.DegeneracyThresholds`)
MIN_TILT_SPREAD = 20.0
#: largest board motion of a moving frame admitted to cover the poses, as a fraction of the image diagonal per frame
#: period (15 px at 1280x720: a board exposed for a third of the frame period smears about as far as the corner
#: detector's window reaches)
MAX_MOVING_MOTION = 0.01
#: frames of a recording in which the screen saw no board that the full detector looks at all the same (spread over
#: the recording): a board the quick look misses is found in some of them, and a recording without one costs a few
#: detector calls, not one per frame
NO_BOARD_LOOKS = 10


def detector_frames(max_frames: int, selecting: bool) -> int:
    """Frames of a recording sent to the full detector: ``max_frames``, or with the frame selection
    :data:`CANDIDATES_PER_FRAME` times as many (the selection keeps ``max_frames`` of them at most).

    Example:
        >>> detector_frames(60, False), detector_frames(60, True)
        (60, 90)
    """
    return int(max_frames) if not selecting else int(math.ceil(CANDIDATES_PER_FRAME * int(max_frames)))


def outline_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean distance between the corners of two outlines :math:`(4, 2)`, the better of their four cyclic orders (a
    symmetric board's corners can come numbered from another end).

    Example:
        >>> a = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])
        >>> outline_distance(a, np.roll(a, 2, axis=0)), outline_distance(a, a + [1.0, 0.0])
        (0.0, 1.0)
    """
    return float(min(np.linalg.norm(a - np.roll(b, r, axis=0), axis=-1).mean() for r in range(4)))


def outline_normals(outlines: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """The board planes' normals :math:`(F, 3)` in the camera of outlines :math:`(F, 4, 2)` (NaN rows where not
    seen), from each outline's vanishing line: the board's two pairs of parallel sides meet at two vanishing points,
    and the line through them, in the image normalized by a pinhole camera with its principal point at the image
    centre, is the plane's normal. The focal length is the median over the outlines of what their two vanishing
    points say (the board's sides are at right angles), within 0.3 to 3 image diagonals; where no outline says
    (boards all nearly fronto-parallel), one image diagonal. Rough (a focal length guessed, the principal point
    assumed, the outline the screen's): enough to tell boards tilted alike from boards tilted 20 deg apart.

    Example:
        >>> box = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0], [0.0, 30.0]])
        >>> np.abs(outline_normals(box[None] + 300.0, (640, 480))).round(3).tolist()
        [[0.0, 0.0, 1.0]]
    """
    pts = np.asarray(outlines, dtype=np.float64).reshape(-1, 4, 2)
    w, h = image_size
    diag = math.hypot(w, h)
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    hom = np.concatenate([(pts - centre) / diag, np.ones(pts.shape[:2] + (1,))], -1)  # in diagonals from the centre
    p0, p1, p2, p3 = (hom[:, i] for i in range(4))
    v1 = np.cross(np.cross(p0, p1), np.cross(p3, p2))  # the rows' vanishing point
    v2 = np.cross(np.cross(p0, p3), np.cross(p1, p2))  # the columns'
    with np.errstate(divide="ignore", invalid="ignore"):
        f2 = -(v1[:, 0] * v2[:, 0] + v1[:, 1] * v2[:, 1]) / (v1[:, 2] * v2[:, 2])
    says = np.isfinite(f2) & (f2 > 0.3 ** 2) & (f2 < 3.0 ** 2)
    f = math.sqrt(float(np.median(f2[says]))) if says.any() else 1.0
    line = np.cross(v1, v2)  # the vanishing line in diagonals; in the normalized image (x / f): (a f, b f, c)
    normal = np.stack([line[:, 0] * f, line[:, 1] * f, line[:, 2]], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        normal = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.where(np.isfinite(normal).all(-1, keepdims=True), normal, np.nan)


def plane_spread(normals: np.ndarray) -> float:
    """The largest angle (deg) between two of the planes with normals :math:`(F, 3)` (NaN rows left out; 0 for fewer
    than two).

    Example:
        >>> n = np.array([[0.0, 0.0, 1.0], [0.0, np.sin(0.3), np.cos(0.3)], [np.nan] * 3])
        >>> round(plane_spread(n), 1)
        17.2
    """
    n = np.asarray(normals, dtype=np.float64)
    n = n[np.isfinite(n).all(-1)]
    if len(n) < 2:
        return 0.0
    return float(np.degrees(np.arccos(np.clip(np.abs(n @ n.T).min(), 0.0, 1.0))))


def board_motion(indices: Sequence[int], sightings: Sequence[Sighting]) -> list[float | None]:
    """Per frame, how far the board's outline moves per frame period: the larger of its moves to the previous and the
    next screened frame that show the board, each divided by the frames between (``None``: no neighbour shows it).

    Args:
        indices: the frames' indices in the video, ascending (``--every`` leaves gaps).
        sightings: the screen's sighting of each.

    Example:
        >>> box = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])
        >>> seen = [Sighting(True, box), Sighting(True, box + [2.0, 0.0]), Sighting(False), Sighting(True, box)]
        >>> board_motion([0, 1, 2, 3], seen)
        [2.0, 2.0, None, None]
    """
    out: list[float | None] = [None] * len(sightings)
    for k, seen in enumerate(sightings):
        if not seen.found:
            continue
        moves = []
        for j in (k - 1, k + 1):
            if 0 <= j < len(sightings) and sightings[j].found:
                gap = max(1, abs(int(indices[j]) - int(indices[k])))
                moves.append(outline_distance(seen.outline, sightings[j].outline) / gap)
        out[k] = max(moves) if moves else None
    return out


@dataclass
class FrameChoice:
    """The frames chosen for the full detector.

    Attributes:
        chosen: the instants (frames of one camera) kept, ascending.
        reasons: per camera, per instant, ``""`` for a kept frame, else why it stays out: ``no board at screening``, ``moving (9.3 px/frame)``, ``near copy of frame 412``, ``over --max-frames``.
        motion: per camera, per instant, the board's motion in px per frame period (``None``: unknown).
        still: per camera, how many of its frames are still (the board seen, moving at most ``max_motion``;
            ``None``: not judged, every instant kept).
        still_spread_deg: per camera, the largest angle between the board planes of the frames it took as still
            (:func:`plane_spread`: the still ones, and the stillest moving ones where fewer than :data:`MIN_STILL`
            are still; ``None``: not judged).
        moving: the chosen instants whose board moves more than ``max_motion`` in some camera.
    """

    chosen: list[int]
    reasons: list[list[str]]
    motion: list[list[float | None]]
    still: list[int | None] | None = None
    still_spread_deg: list[float | None] | None = None
    moving: list[int] | None = None


def choose_frames(
    sightings: Sequence[Sequence[Sighting | None]],
    labels: Sequence[Sequence[str | None]],
    motion: Sequence[Sequence[float | None]],
    image_sizes: Sequence[tuple[int, int]],
    max_frames: int = 60,
    max_motion: float = MAX_MOTION,
    min_change: float = MIN_CHANGE,
    copies: bool = True,
    frame_rates: Sequence[float] | None = None,
    max_moving: float | Sequence[float] = MAX_MOVING_MOTION,
) -> FrameChoice:
    """Choose the instants whose frames go to the full detector.

    Args:
        sightings: per camera, per instant, the screen's sighting (``None``: the camera has no frame there).
        labels: per camera, per instant, the frame's name in messages (its index in the video).
        motion: per camera, per instant, :func:`board_motion` of the frame.
        image_sizes: per camera ``(W, H)``.
        max_frames: instants kept at most (>= 1).
        max_motion: fraction of each camera's image diagonal per frame period.
        min_change: mean corner distance as a fraction of the board's size in the image.
        copies: near copies fill what is left of ``max_frames`` once every new pose is taken (else they stay out).
        frame_rates: per camera its frames per second (a rig of several rates): the motions are compared per frame
            period of the fastest camera (a slower camera's frame period is longer, not its board faster). ``None``
            or a rate of 0: per each camera's own frame period.
        max_moving: fraction of each camera's image diagonal per frame period (one, or one per camera): the fastest
            moving frame admitted where the still frames do not cover the poses (:data:`MIN_TILT_SPREAD`).

    A rig shares the budget: every camera keeps at least its share of ``max_frames`` (``max_frames // C``, or all the
    instants it sees where fewer) and of the still frames (:data:`MIN_STILL` each), instants that several cameras see
    counting for each of them; a camera seen in fewer instants never leaves the others without their pairs.

    Returns:
        :class:`FrameChoice`.

    Example:
        >>> box = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0], [0.0, 30.0]])
        >>> seen = [[Sighting(True, box + [dx, 0.0]) for dx in (0, 20, 40, 60, 80, 100, 1)]]
        >>> c = choose_frames(seen, [[str(k) for k in range(7)]], [[0.0] * 7], [(640, 480)], max_frames=3)
        >>> c.chosen, c.reasons[0][1], c.reasons[0][6]
        ([0, 2, 5], 'over --max-frames', 'near copy of frame 0')
        >>> [choose_frames(seen, [[str(k) for k in range(7)]], [[0.0] * 7], [(640, 480)], max_frames=5,
        ...                min_change=1.0, copies=fill).chosen for fill in (False, True)]  # new poses, then copies
        [[0, 2, 5], [0, 1, 2, 3, 5]]
    """
    if max_frames < 1:
        raise ValueError(f"max_frames must be >= 1, got {max_frames}.")
    c = len(sightings)
    f = len(sightings[0]) if c else 0
    if any(len(s) != f for s in sightings):
        raise ValueError("every camera needs one entry per instant.")
    diag = [math.hypot(*size) for size in image_sizes]
    seen = np.array([[s is not None and s.found for s in cam] for cam in sightings], dtype=bool).reshape(c, f)
    moves = np.array([[np.nan if m is None else m / diag[k] for m in cam] for k, cam in enumerate(motion)],
                     dtype=np.float64).reshape(c, f)
    pace = moves  # the motions compared, per frame period of the fastest camera
    rates = np.asarray(frame_rates if frame_rates is not None else [0.0] * c, dtype=np.float64)
    if c > 1 and (rates > 0).all():
        pace = moves * (rates / rates.max())[:, None]
    reasons = [["" if seen[k, i] else ("no board at screening" if sightings[k][i] is not None else "")
                for i in range(f)] for k in range(c)]
    if f and not seen.any():  # the screen saw no board: the full detector looks at a few frames spread over the time
        spread = sorted({int(round(x)) for x in np.linspace(0, f - 1, min(max_frames, NO_BOARD_LOOKS))})
        for k in range(c):
            for i in spread:
                reasons[k][i] = ""
        return FrameChoice(spread, reasons, [list(m) for m in motion])
    if f <= max_frames:  # every instant goes: the full detector decides
        return FrameChoice(list(range(f)), [[""] * f for _ in range(c)], [list(m) for m in motion])
    cameras_seeing = seen.sum(0)
    worst = np.where(seen, pace, np.nan)
    worst = np.array([np.nanmax(col) if np.isfinite(col).any() else np.nan for col in worst.T])
    pool = np.flatnonzero(cameras_seeing > 0)
    still = pool[~(worst[pool] > max_motion)]  # unknown motion counts as still
    still_count: list[int | None] = [int(seen[k, still].sum()) for k in range(c)]
    for k in range(c):  # each camera its still frames: the stillest moving ones it sees where too few are still
        mine = int(seen[k, still].sum())
        if mine < MIN_STILL:
            moving = np.setdiff1d(pool[seen[k, pool] & (worst[pool] > max_motion)], still)
            still = np.concatenate([still, moving[np.argsort(worst[moving], kind="stable")][:MIN_STILL - mine]])
    outlines = _Outlines(sightings, seen)
    normals = [outline_normals(outlines.points[k], image_sizes[k]) for k in range(c)]
    still_spread: list[float | None] = [plane_spread(normals[k][still[seen[k, still]]]) for k in range(c)]
    fastest = np.broadcast_to(np.asarray(max_moving, dtype=np.float64), (c,))
    for k in range(c):  # each camera whose still frames do not cover the poses: its moving ones that widen them
        if still_spread[k] >= MIN_TILT_SPREAD:
            continue
        moving = np.setdiff1d(pool[seen[k, pool] & (worst[pool] > max_motion) & (worst[pool] <= fastest[k])], still)
        # (by more than the rough outlines' error: a quarter of the spread wanted)
        if plane_spread(normals[k][np.concatenate([still[seen[k, still]], moving])]) > \
                still_spread[k] + MIN_TILT_SPREAD / 4:
            still = np.concatenate([still, moving])
    for i in np.setdiff1d(pool, still):
        for k in range(c):
            if seen[k, i]:
                reasons[k][i] = f"moving ({moves[k, i] * diag[k]:.1f} px/frame)"
    chosen = _spread(still, outlines, cameras_seeing, np.nan_to_num(worst[still] / max_motion), max_frames, min_change,
                     copies)
    near, distance = _nearest(still, chosen, outlines)
    novelty = np.where(seen[:, still], distance, -np.inf).max(0)
    for n, i in enumerate(still):
        if i in chosen:
            continue
        for k in range(c):
            if not seen[k, i]:
                continue
            j = int(near[k, n])
            label = labels[k][j] if j >= 0 and labels[k][j] is not None else j
            reasons[k][i] = f"near copy of frame {label}" if novelty[n] < min_change and j >= 0 else \
                "over --max-frames"
    moving_chosen = [i for i in sorted(chosen) if worst[i] > max_motion]
    return FrameChoice(sorted(chosen), reasons, [list(m) for m in motion], still_count, still_spread, moving_chosen)


class _Outlines:
    """Every camera's outlines :math:`(C, F, 4, 2)` (NaN where not seen) and their sizes :math:`(C, F)` (RMS distance
    of the four corners from their centre), and per camera the distance of instants to one instant as a fraction of
    the smaller outline's size (infinite where the camera does not see both)."""

    def __init__(self, sightings, seen: np.ndarray) -> None:
        c, f = seen.shape
        self.seen = seen
        self.points = np.full((c, f, 4, 2), np.nan)
        self.size = np.full((c, f), np.nan)
        for k in range(c):
            for i in np.flatnonzero(seen[k]):
                outline = np.asarray(sightings[k][i].outline, dtype=np.float64)
                self.points[k, i] = outline
                self.size[k, i] = np.sqrt(((outline - outline.mean(0)) ** 2).sum(-1).mean())

    def to(self, j: int, among: np.ndarray) -> np.ndarray:
        """Distances :math:`(C, len(among))` of the instants ``among`` to instant ``j``, per camera."""
        pts, ref = self.points[:, among], self.points[:, j][:, None]
        d = np.min([np.linalg.norm(pts - np.roll(ref, r, axis=2), axis=-1).mean(-1) for r in range(4)], axis=0)
        size = np.fmin(self.size[:, among], self.size[:, j][:, None])
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(size > 0, d / np.where(size > 0, size, 1.0), np.where(d > 0, np.inf, 0.0))
        return np.where(self.seen[:, among] & self.seen[:, j][:, None], rel, np.inf)


#: the novelty of an instant a camera sees before any of its instants is chosen: farther than any pose
_UNSEEN = 1e6


def _spread(pool: np.ndarray, outlines: _Outlines, cameras_seeing: np.ndarray, slowness: np.ndarray,
            max_frames: int, min_change: float, copies: bool) -> list[int]:
    """Farthest-point choice over ``pool``: an instant's novelty is the largest, over the cameras that see it, of its
    distance to the nearest chosen instant that camera sees (:data:`_UNSEEN` where it sees none yet); weighted by the
    cameras that see it and its stillness. Instants less novel than ``min_change`` come only with ``copies``, after
    every novel one. While a camera has fewer than its share of ``max_frames`` (:func:`choose_frames`), the instants
    it sees come first."""
    if not len(pool):
        return []
    seen = outlines.seen[:, pool]
    weight = cameras_seeing[pool] / (1.0 + slowness)
    nearest = np.full(seen.shape, _UNSEEN)
    first = int(np.lexsort((slowness, -weight))[0])
    chosen = [int(pool[first])]
    taken = np.zeros(len(pool), dtype=bool)
    taken[first] = True
    nearest = np.minimum(nearest, outlines.to(chosen[0], pool))
    floor = min_change
    # each camera's share of the budget: the instants it sees count until it has its share
    quota = np.minimum(max_frames // seen.shape[0], seen.sum(1))
    while len(chosen) < max_frames:
        gap = np.where(seen, nearest, -np.inf).max(0)
        open_ = (gap >= floor) & ~taken
        needy = seen[:, taken].sum(1) < quota
        if needy.any() and (open_ & seen[needy].any(0)).any():
            open_ &= seen[needy].any(0)  # a camera short of its share first
        score = np.where(open_, gap * weight, -1.0)
        k = int(np.argmax(score))
        if score[k] < 0:
            if copies and floor > 0:
                floor = 0.0  # every new pose is taken: the copies, farthest first
                continue
            break
        chosen.append(int(pool[k]))
        taken[k] = True
        nearest = np.minimum(nearest, outlines.to(chosen[-1], pool))
    return chosen


def _nearest(pool: np.ndarray, chosen: list[int], outlines: _Outlines) -> tuple[np.ndarray, np.ndarray]:
    """Per camera and instant of ``pool``, the nearest chosen instant that camera sees (-1: none) and its distance
    (infinite: none), both :math:`(C, len(pool))`."""
    c = outlines.seen.shape[0]
    if not chosen or not len(pool):
        return np.full((c, len(pool)), -1), np.full((c, len(pool)), np.inf)
    d = np.stack([outlines.to(j, pool) for j in chosen])  # (chosen, C, pool)
    best = d.argmin(0)
    return np.where(np.isfinite(d.min(0)), np.asarray(chosen)[best], -1), d.min(0)
