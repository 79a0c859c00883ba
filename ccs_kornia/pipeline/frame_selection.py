r"""Frame selection: of the views the detector found the board in, keep those that make the best camera.

After the full detector and a first solve on every candidate view (a recording's frames chosen at screening, a
folder's photos), :func:`choose_frames` keeps the views that are

1. **still**: a moving board is smeared over the exposure and bent by a rolling shutter, errors no corner precision
   shows. The board's speed in the image (a recording's screening measures it between neighbouring frames:
   :meth:`~ccs_kornia.pipeline.sources.ViewSource.speed`) weighs a view's information down
   (:func:`motion_weight`: half at ``speed_scale`` image diagonals per second); faster than ``max_speed`` it is
   ``moving`` and left out, unless the frames that pass do not cover the poses (two or more whose board planes,
   from the first solve, lie within :data:`~ccs_kornia.pipeline.frame_candidates.MIN_TILT_SPREAD` of each other in
   some camera): then that camera's moving frames come in where they spread the planes wider by a quarter of that
   angle at least, their information weighed down by their speed as any view's. For a rig, the board's motion between its cameras' frames
   of one instant (their time spread times its speed) counts the same way (``sync_scale``, ``max_sync_px``);
2. **sharp**: the median of the corners' own measured precision
   (:func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_uncertainty`) at most ``max_blur`` times the
   candidates' median (blur, defocus and low contrast soften the corners), else ``blurred``;
3. **new**: a near copy of a view kept already (the boards' corners within ``min_change`` of the board's size in
   the image of each other, on average: :func:`near_copies`; a small board far away moves little in the image when it
   turns, so a new pose is measured against the board, not against the image) waits until every new view is taken,
   then counts like any view (another measurement of a pose averages its noise); where ``max_frames`` or the stop
   comes first it is left out as a ``near copy``;
4. **informative**: taken greedily by how much each lowers the camera's predicted projection uncertainty over the
   whole image (the solver's covariance: :mod:`~ccs_kornia.modules.calibration.quality.view_information`), until a
   view lowers it by less than ``min_gain`` (``adds nothing``) or ``max_frames`` are kept. The covariance counts the
   corners' own noise only, which a view's many corners average away; the errors a whole view shares (the rolling
   shutter's bend, the blur, the detector's bias on that board) average over views only, so a distinct view helps
   more than the covariance says, and the covariance holds at the first solve's camera, which a few views less can
   move far where the boards are small. So by default nothing stops the choice but ``max_frames``
   (:data:`MIN_GAIN`): the gates and the near copies thin the frames, the order decides which the cap keeps. Fewer
   than ``min_keep`` kept: the choice goes on, the views left out as moving or blurred admitted.

A rig's frames are judged across its cameras (:func:`choose_frames` with several cameras): a frame is moving when
its board moves too fast in any camera, its views blurred in some cameras are left out of those, its information is
summed over its cameras, plus the link it gives every pair of cameras that see it together.

:func:`select_views` chooses every camera's views of a solved result and solves the cameras again on the views kept
(the model ``--model auto`` chose on every candidate kept). :class:`FrameChoice` says, per candidate, whether it was
kept and why not (``moving (250 px/s)``, ``blurred (corners 2.6x the median)``, ``near copy of frame 412``, ``adds
nothing``, ``over --max-frames``). Measured figures: ``docs/benchmarks.md`` (section 11, recordings).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.quality.view_information import (
    greedy_information,
    image_information,
    view_information,
)
from ccs_kornia.modules.detection.base import measured_corners
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_weights
from ccs_kornia.pipeline.frame_candidates import MIN_TILT_SPREAD, plane_spread
from ccs_kornia.pipeline.result import PipelineResult

__all__ = [
    "MAX_BLUR",
    "MAX_SPEED",
    "MAX_SYNC_PX",
    "MIN_CHANGE",
    "MIN_GAIN",
    "MIN_KEEP",
    "SPEED_SCALE",
    "SYNC_SCALE_PX",
    "CameraViews",
    "FrameChoice",
    "FrameSelection",
    "board_extent",
    "camera_views",
    "choose_frames",
    "keep_views",
    "motion_weight",
    "near_copies",
    "select_views",
    "solve_chosen",
]

#: a view whose median corner precision is worse than this many times the candidates' median is blurred
MAX_BLUR = 2.0
#: a board this fast (image diagonals per second) keeps half its view's information (44 px/s at 1280x720: 1.5 px in
#: a 30 fps frame); faster boards keep less (:func:`motion_weight`)
SPEED_SCALE = 0.03
#: a board faster than this (image diagonals per second: 220 px/s at 1280x720, 7 px a 30 fps frame) is moving
MAX_SPEED = 0.15
#: a rig's board that moved this much between its cameras' frames of one instant (px) keeps half the information
SYNC_SCALE_PX = 1.0
#: a rig's board that moved more than this between its cameras' frames of one instant (px) is moving
MAX_SYNC_PX = 5.0
#: two boards whose corners lie within this fraction of the board's size in the image (the RMS distance of its
#: corners from their centre, the smaller board's) of each other (mean) are near copies
MIN_CHANGE = 0.1
#: a view that lowers the predicted projection uncertainty by less than this fraction adds nothing; none by default:
#: the covariance counts only the corners' own noise and holds at the first solve's camera, so a small predicted gain
#: is no proof that a view is useless (the module docstring; how it was chosen: ``docs/video.md``)
MIN_GAIN = 0.0
#: views kept at least (the gates admit the stillest and sharpest left out, the greedy choice goes on, up to this)
MIN_KEEP = 8


@dataclass(frozen=True)
class FrameSelection:
    """The frame selection's settings (see the module docstring).

    Attributes:
        max_frames: views (a rig's frames) kept at most (``None``: no cap).
        min_gain, max_blur, speed_scale, max_speed, sync_scale, max_sync_px, min_change, min_keep:
            :data:`MIN_GAIN`, :data:`MAX_BLUR`, :data:`SPEED_SCALE`, :data:`MAX_SPEED`, :data:`SYNC_SCALE_PX`,
            :data:`MAX_SYNC_PX`, :data:`MIN_CHANGE`, :data:`MIN_KEEP`.
        grid: ``(across, down)`` pixels over which the projection uncertainty is predicted.
    """

    max_frames: int | None = None
    min_gain: float = MIN_GAIN
    max_blur: float = MAX_BLUR
    speed_scale: float = SPEED_SCALE
    max_speed: float = MAX_SPEED
    sync_scale: float = SYNC_SCALE_PX
    max_sync_px: float = MAX_SYNC_PX
    min_change: float = MIN_CHANGE
    min_keep: int = MIN_KEEP
    grid: tuple[int, int] = (16, 12)

    def __post_init__(self) -> None:
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max_frames must be >= 1 or None, got {self.max_frames}.")
        for name in ("min_gain", "max_blur", "speed_scale", "max_speed", "sync_scale", "max_sync_px", "min_change"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}.")


@dataclass
class CameraViews:
    """One camera's candidate views, as the frame selection needs them (:func:`camera_views` makes one).

    Attributes:
        camera: the first solve's camera (one, float64, with its image size).
        rvec, tvec: :math:`(V, 3)` each view's board pose from the first solve.
        corners: :math:`(V, N, 2)`; valid: :math:`(V, N)` bool; weights: :math:`(V, N)` the solver's weights.
        object_points: :math:`(N, 3)`.
        used: :math:`(V,)` bool, the candidates (views the first solve used).
        sharpness: :math:`(V,)` each view's median corner precision (px, relative; NaN: not measured).
        speed: per view the board's speed (px/s), ``None`` where not known.
        rms: the first solve's RMS reprojection error (px): the scale of the predicted uncertainty.
    """

    camera: Camera
    rvec: torch.Tensor
    tvec: torch.Tensor
    corners: torch.Tensor
    valid: torch.Tensor
    weights: torch.Tensor
    object_points: torch.Tensor
    used: torch.Tensor
    sharpness: torch.Tensor
    speed: list[float | None]
    rms: float

    @property
    def image_size(self) -> tuple[int, int]:
        """``(W, H)``."""
        return self.camera.image_size

    @property
    def diagonal(self) -> float:
        return math.hypot(*self.image_size)


def camera_views(out: PipelineResult, object_points: torch.Tensor, weigh_corners: bool = True,
                 speed: Sequence[float | None] | None = None) -> CameraViews | None:
    """The candidate views of one solved camera (``out``: one camera, no camera dimension); ``None`` when it has no
    calibration."""
    cal = out.calibration
    if cal is None or not bool(cal.success):
        return None
    det = out.detections
    corners = det.corners.double().cpu()
    valid = measured_corners(corners, det.found.cpu())
    sigma = None if det.sigma is None else det.sigma.cpu()
    weights = corner_weights(sigma, valid) if (weigh_corners and sigma is not None) else None
    weights = valid.double() if weights is None else weights.double() * valid
    if sigma is None:
        sharp = torch.full((corners.shape[0],), float("nan"), dtype=torch.float64)
    else:
        s = torch.where(valid, sigma.double(), torch.full_like(sigma, float("nan"), dtype=torch.float64))
        sharp = s.nanmedian(-1).values
    v = corners.shape[0]
    speeds = list(speed) if speed is not None else [None] * v
    camera = Camera(cal.camera.models, cal.camera.params.double().cpu(), tuple(int(x) for x in out.image_size))
    return CameraViews(camera, cal.rvec.double().cpu(), cal.tvec.double().cpu(),
                       torch.where(valid[..., None], corners, torch.zeros_like(corners)), valid, weights,
                       object_points.double().cpu(), cal.used.cpu().bool() & det.found.cpu(), sharp,
                       speeds + [None] * (v - len(speeds)), float(cal.rms))


def board_extent(corners: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """:math:`(V,)` each board's size in the image: the RMS distance (px) of its corners from their centre (0: no
    corner).

    Example:
        >>> c = torch.tensor([[[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]])
        >>> board_extent(c, torch.ones(1, 4, dtype=torch.bool))
        tensor([1.4142])
    """
    shown = valid[..., None]
    n = valid.sum(-1).clamp_min(1).to(corners.dtype)  # (V,)
    centre = torch.where(shown, corners, torch.zeros_like(corners)).sum(-2) / n[:, None]
    spread = torch.where(shown, corners - centre[:, None], torch.zeros_like(corners)).pow(2).sum((-1, -2))
    return (spread / n).sqrt()


def near_copies(corners: torch.Tensor, valid: torch.Tensor, min_change: float, min_common: int = 4) -> torch.Tensor:
    """:math:`(V, V)` bool: the boards of two views lie within ``min_change`` times the smaller board's size in the
    image (:func:`board_extent`) of each other (mean distance of the corners both show, at least ``min_common`` of
    them; a view is not its own copy).

    Example:
        >>> c = torch.tensor([[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0]]).repeat(3, 1, 1)
        >>> c[1] += 0.5; c[2] += 10.0  # the board's size is 14.1 px: moved 0.7 px it is a copy at 0.1, 14 px not
        >>> near_copies(c, torch.ones(3, 4, dtype=torch.bool), 0.1).int().tolist()
        [[0, 1, 0], [1, 0, 0], [0, 0, 0]]
    """
    both = valid[:, None] & valid[None]  # (V, V, N)
    d = (corners[:, None] - corners[None]).norm(dim=-1)
    n = both.sum(-1)
    mean = torch.where(both, d, torch.zeros_like(d)).sum(-1) / n.clamp_min(1)
    size = board_extent(corners, valid)
    out = (n >= min_common) & (mean < min_change * torch.minimum(size[:, None], size[None]))
    out.fill_diagonal_(False)
    return out


@dataclass
class FrameChoice:
    """What the frame selection kept, over the candidate frames (views of one camera, or a rig's instants).

    Attributes:
        kept: per frame, kept.
        reasons: per frame, ``""`` where kept or not a candidate, else why it was left out.
        view_reasons: per camera, per view, why the view is left out of the calibration by the choice (``""``: not).
        copy_of: per frame, the kept frame it nearly copies (-1: none).
        speed_px_s: per frame, the board's fastest speed over its cameras (px/s; ``None``: not known).
        sharpness: per frame, the largest ratio of a view's median corner precision to its camera's median.
        gain: per frame, its relative gain when taken or when the choice stopped (``None``: not judged).
        order: the frames kept, in the order taken.
        uncertainty_px: per camera, the predicted RMS projection uncertainty over the image (px) before the first
            frame and after each.
        candidates: frames that were candidates (a view the first solve used).
    """

    kept: list[bool]
    reasons: list[str]
    view_reasons: list[list[str]]
    copy_of: list[int]
    speed_px_s: list[float | None]
    sharpness: list[float | None]
    gain: list[float | None]
    order: list[int]
    uncertainty_px: list[list[float]]
    candidates: int

    def view_kept(self, camera: int) -> list[bool]:
        """Per view of ``camera``, whether it stays in the calibration."""
        return [not r for r in self.view_reasons[camera]]

    def record(self, labels: Sequence[str]) -> dict[str, Any]:
        """The JSON's ``selection``: the counts, the predicted uncertainty as frames were taken, and per candidate
        frame (named by ``labels``) ``kept``, ``reason``, ``speed_px_s``, ``sharpness``, ``gain``."""
        frames = []
        for f, label in enumerate(labels):
            if not self.kept[f] and not self.reasons[f]:
                continue  # not a candidate (no board, or the solver's own reason)
            entry: dict[str, Any] = {"frame": label, "kept": self.kept[f]}
            if self.reasons[f]:
                entry["reason"] = self.reasons[f]
            for key, value in (("speed_px_s", self.speed_px_s[f]), ("sharpness", self.sharpness[f]),
                               ("gain", self.gain[f])):
                if value is not None and math.isfinite(value):
                    entry[key] = round(float(value), 4)
            frames.append(entry)
        return {"candidates": self.candidates, "kept": sum(self.kept),
                "order": [labels[f] for f in self.order],
                "uncertainty_px": [[round(u, 4) for u in cam] for cam in self.uncertainty_px], "frames": frames}


def _label(labels: Sequence[str] | None, f: int) -> str:
    return labels[f] if labels is not None else str(f)


def motion_weight(speed: float | None, diagonal: float, speed_scale: float, sync_px: float | None = None,
                  sync_scale: float = 1.0) -> float:
    """How much of a view's information a moving board keeps: ``1 / (1 + (v / s)^2 + (d / d0)^2)`` for the board's
    speed ``v`` (px/s) against ``speed_scale`` image diagonals per second, and for a rig the board's motion between
    the cameras' frames ``d`` (px) against ``sync_scale`` (px): the smear and the rolling shutter's bend count as
    noise that grows with the speed (an unknown speed counts as still).

    Example:
        >>> motion_weight(None, 1000.0, 0.03), motion_weight(30.0, 1000.0, 0.03), motion_weight(0.0, 1000.0, 0.03, 1.0)
        (1.0, 0.5, 0.5)
    """
    extra = 0.0
    if speed is not None and speed_scale > 0:
        extra += (float(speed) / (speed_scale * diagonal)) ** 2
    if sync_px is not None and sync_scale > 0:
        extra += (float(sync_px) / sync_scale) ** 2
    return 1.0 / (1.0 + extra)


def choose_frames(
    cameras: Sequence[CameraViews | None],
    index: Sequence[Sequence[int | None]] | None = None,
    selection: FrameSelection = FrameSelection(),
    spread: Sequence[float | None] | None = None,
    labels: Sequence[str] | None = None,
    cap_name: str = "--max-frames",
) -> FrameChoice:
    """Choose the frames (see the module docstring).

    Args:
        cameras: per camera its candidate views (:func:`camera_views`; ``None``: a camera without calibration,
            whose views count for nothing).
        index: per camera, per frame, the camera's view of the frame (``None``: none); default for one camera: frame
            ``f`` is view ``f``.
        selection: the settings.
        spread: per frame, the time between its cameras' frames (s; ``None``: not known).
        labels: per frame its name in the reasons (``near copy of frame 412``).
        cap_name: what the reason of a frame over ``max_frames`` names.

    Returns:
        :class:`FrameChoice`.
    """
    C = len(cameras)
    if index is None:
        if C != 1 or cameras[0] is None:
            raise ValueError("index is needed for several cameras.")
        index = [list(range(cameras[0].corners.shape[0]))]
    F = len(index[0]) if C else 0
    views = [[None if cam is None or k is None else int(k) for k in row] for cam, row in zip(cameras, index)]
    usable = torch.zeros(C, F, dtype=torch.bool)
    for c, cam in enumerate(cameras):
        for f, k in enumerate(views[c]):
            usable[c, f] = k is not None and bool(cam.used[k])
    spread = list(spread) if spread is not None else [None] * F
    reasons = ["" for _ in range(F)]
    speed_of: list[float | None] = [None] * F
    sharp_of: list[float | None] = [None] * F
    # per camera, each view's median corner precision against the candidates' median
    ratio = torch.full((C, F), float("nan"), dtype=torch.float64)
    for c, cam in enumerate(cameras):
        if cam is None:
            continue
        med = cam.sharpness[cam.used & cam.sharpness.isfinite()]
        ref = float(med.median()) if med.numel() else float("nan")
        for f, k in enumerate(views[c]):
            if k is not None and usable[c, f] and ref > 0:
                ratio[c, f] = float(cam.sharpness[k]) / ref
    gated = torch.zeros(F, dtype=torch.bool)
    blurred = torch.zeros(C, F, dtype=torch.bool)
    weight = torch.ones(C, F, dtype=torch.float64)
    for f in range(F):
        cams = [c for c in range(C) if usable[c, f]]
        if not cams:
            continue
        speeds = {c: cameras[c].speed[views[c][f]] for c in cams if cameras[c].speed[views[c][f]] is not None}
        sync = None
        if speeds:
            speed_of[f] = max(speeds.values())
            if spread[f] is not None and len(cams) > 1:
                sync = spread[f] * speed_of[f]
            fast = max(speeds, key=lambda c: speeds[c] / cameras[c].diagonal)
            if speeds[fast] > selection.max_speed * cameras[fast].diagonal:
                reasons[f] = f"moving ({speeds[fast]:.0f} px/s)"
            elif sync is not None and sync > selection.max_sync_px:
                reasons[f] = (f"moving ({speed_of[f]:.0f} px/s, its cameras {spread[f] * 1000:.0f} ms apart: "
                              f"{sync:.1f} px)")
        for c in cams:
            weight[c, f] = motion_weight(speeds.get(c), cameras[c].diagonal, selection.speed_scale, sync,
                                         selection.sync_scale)
        r = ratio[cams, f]
        if r.isfinite().any():
            sharp_of[f] = float(r[r.isfinite()].max())
        for c in cams:
            blurred[c, f] = bool(ratio[c, f] > selection.max_blur)
        if not reasons[f] and all(bool(blurred[c, f]) for c in cams):
            reasons[f] = f"blurred (corners {sharp_of[f]:.1f}x the median)"
        gated[f] = bool(reasons[f])
    candidate = usable.any(0)
    sharp_views = usable & ~blurred
    # each camera's information: its views that count, weighed by the board's motion
    P = max((cam.camera.model.num_params for cam in cameras if cam is not None), default=4)
    M = torch.zeros(C, F, P, P, dtype=torch.float64)
    A = torch.zeros(C, P, P, dtype=torch.float64)
    rms = [0.0 if cam is None else cam.rms for cam in cameras]
    for c, cam in enumerate(cameras):
        keep = [(f, k) for f, k in enumerate(views[c]) if k is not None and bool(usable[c, f])]
        if cam is None or not keep:
            continue
        ks = torch.tensor([k for _, k in keep])
        fs = [f for f, _ in keep]
        m = view_information(cam.camera, cam.rvec[ks][None], cam.tvec[ks][None], cam.object_points,
                             cam.weights[ks][None])[0]
        p = m.shape[-1]
        M[c, fs, :p, :p] = m * weight[c, fs][:, None, None]
        A[c, :p, :p] = image_information(cam.camera, grid=selection.grid)[0]
    pad = A.diagonal(dim1=-2, dim2=-1) == 0  # parameters a camera does not have: inert
    M = M + torch.diag_embed(pad.double())[:, None] * usable[..., None, None].double()
    links = C > 1

    def greedy(views_ok: torch.Tensor, available: torch.Tensor, count: int | None, min_gain: float):
        Mv = torch.where(views_ok[..., None, None], M, torch.zeros_like(M))
        conflicts = _copies(cameras, views, views_ok, selection.min_change)
        return greedy_information(Mv, A, available, conflicts, count, min_gain, links=links, link_weights=weight,
                                  copies_last=True)

    passed = candidate & ~gated
    moving = gated & torch.tensor([r.startswith("moving") for r in reasons], dtype=torch.bool)
    passed = passed | _covering(cameras, views, usable, passed, moving)
    choice = greedy(sharp_views, passed, selection.max_frames, selection.min_gain)
    need = min(selection.min_keep, int(candidate.sum()))
    if selection.max_frames is not None:
        need = min(need, selection.max_frames)
    topped_up = len(choice.order) < need
    if topped_up:  # too few: the gated frames may come in too, all views of a frame count
        choice = greedy(usable, candidate, need, 0.0)
    kept = [False] * F
    for f in choice.order:
        kept[f] = True
        reasons[f] = ""
    for f in range(F):
        if kept[f] or not candidate[f] or reasons[f]:
            continue
        why = choice.reason[f]
        # (a choice topped up to min_keep stops at that count: the others add too little, whatever the cap)
        capped = why == "cap" and not (topped_up and len(choice.order) < (selection.max_frames or len(kept)))
        reasons[f] = f"near copy of {_label(labels, choice.copy_of[f])}" if why == "copy" else \
            f"over {cap_name}" if capped else "adds nothing"
    view_reasons = [["" for _ in range(0 if cam is None else cam.corners.shape[0])] for cam in cameras]
    for c, cam in enumerate(cameras):
        for f, k in enumerate(views[c]):
            if k is None or not bool(usable[c, f]):
                continue
            if not kept[f]:
                view_reasons[c][k] = reasons[f]
            elif bool(blurred[c, f]) and bool(sharp_views[:, f].any()):
                view_reasons[c][k] = f"blurred (corners {float(ratio[c, f]):.1f}x the median)"
    gains: list[float | None] = [None if math.isnan(g) else g for g in choice.gain]
    # the residuals' standard deviation per coordinate: the RMS error (over both coordinates) over sqrt(2)
    uncertainty = [[float(u) * rms[c] / math.sqrt(2.0) for u in choice.uncertainty[c].tolist()] for c in range(C)]
    return FrameChoice(kept, reasons, view_reasons, choice.copy_of, speed_of, sharp_of, gains, list(choice.order),
                       uncertainty, int(candidate.sum()))


def _covering(cameras: Sequence[CameraViews | None], views: list[list[int | None]], usable: torch.Tensor,
              passed: torch.Tensor, moving: torch.Tensor) -> torch.Tensor:
    """:math:`(F,)` the ``moving`` frames that come in for a camera whose ``passed`` frames (two at least) have board
    planes (from the first solve) within :data:`~ccs_kornia.pipeline.frame_candidates.MIN_TILT_SPREAD` of each other, where they
    spread that camera's planes wider by a quarter of that angle at least."""
    out = torch.zeros_like(passed)
    for c, cam in enumerate(cameras):
        if cam is None or not bool(moving.any()):
            continue
        normals = exp_so3(cam.rvec)[..., :, 2].numpy()  # (V, 3): the boards' z axes in the camera
        mine = usable[c] & passed
        spread = plane_spread(normals[_views_of(views[c], mine)])
        if int(mine.sum()) < 2 or spread >= MIN_TILT_SPREAD:  # (none passes: ``min_keep`` brings the stillest in)
            continue
        extra = usable[c] & moving
        if plane_spread(normals[_views_of(views[c], mine | extra)]) > spread + MIN_TILT_SPREAD / 4:
            out |= extra
    return out


def _views_of(views: list[int | None], frames: torch.Tensor) -> list[int]:
    """A camera's views of ``frames`` :math:`(F,)` bool (frames it sees)."""
    return [views[f] for f in frames.nonzero().flatten().tolist() if views[f] is not None]


def _copies(cameras: Sequence[CameraViews | None], views: list[list[int | None]], sharp: torch.Tensor,
            min_change: float) -> torch.Tensor:
    """:math:`(F, F)`: frame ``v`` nearly copies frame ``u`` in every camera whose view of ``v`` counts (and that
    camera's view of ``u`` counts too)."""
    _C, F = sharp.shape
    out = torch.ones(F, F, dtype=torch.bool)
    any_view = torch.zeros(F, dtype=torch.bool)
    for c, cam in enumerate(cameras):
        if cam is None:
            continue
        fs = [f for f in range(F) if views[c][f] is not None and bool(sharp[c, f])]
        if not fs:
            continue
        ks = torch.tensor([views[c][f] for f in fs])
        near = near_copies(cam.corners[ks], cam.valid[ks], min_change)
        here = torch.zeros(F, F, dtype=torch.bool)
        idx = torch.tensor(fs)
        here[idx[:, None], idx[None]] = near
        seen = torch.zeros(F, dtype=torch.bool)
        seen[idx] = True
        # where camera c sees v, v must copy u in it; where it does not see v, it says nothing
        out &= here | ~seen[:, None]
        any_view |= seen
    out &= any_view[:, None] & any_view[None]
    out.fill_diagonal_(False)
    return out


def solve_chosen(solving, out: PipelineResult, keep: torch.Tensor, board_size: tuple[int, int],
                 square: float) -> tuple[PipelineResult, Any]:
    """``out`` (a batched result, solved) solved again on the views ``keep`` :math:`(C, V)` only, each camera with
    the model chosen before (``model="auto"``: on every candidate). The detections stay as they were (every view's
    corners), the calibration uses the views kept.

    Returns:
        ``(result, subsets)`` as :func:`~ccs_kornia.pipeline.solve.solve_detections`.
    """
    from ccs_kornia.pipeline.solve import solve_detections

    det = out.detections
    masked = replace(out, detections=replace(det, found=det.found & keep.to(det.found.device)))
    solved, subsets = solve_detections(solving, masked, board_size, square, keep_models=True)
    if solved.model_selection is not None:
        for c, table in enumerate(solved.model_selection):
            if table is not None:
                n = int(keep[c].sum())
                solved.model_selection[c] = {**table, "note": f"chosen on the {table.get('views')} candidate views, "
                                             f"before the frame selection; the calibration uses the {n} kept"}
    return replace(solved, detections=det), subsets


def select_views(solving, out: PipelineResult, board_size: tuple[int, int], square: float,
                 selection: FrameSelection, source=None) -> tuple[PipelineResult, Any]:
    """The frame selection of every camera of ``out`` (batched, solved on every candidate), then the cameras solved
    again on the views kept (:func:`solve_chosen`); the views' speeds and names come from ``source`` where given.

    Returns:
        ``(result, subsets)``: ``result.frame_choice`` per camera (``None`` where the camera had no calibration to
        judge its views by); ``subsets`` as :func:`~ccs_kornia.pipeline.solve.solve_detections` (``None`` when
        nothing was solved again).
    """
    obj = solving.object_points(board_size, square)
    C, V = out.present.shape
    keep = out.detections.found.clone()
    choices: list[FrameChoice | None] = []
    for c in range(C):
        n = source.counts[c] if source is not None else V
        speeds = [source.speed(c, v) for v in range(n)] if source is not None else None
        labels = [source.label(c, v) for v in range(n)] if source is not None else None
        cam = camera_views(out.select(c), obj, solving.weigh_corners, speeds)
        if cam is None:
            choices.append(None)
            continue
        choice = choose_frames([cam], selection=selection, labels=labels)
        for v, why in enumerate(choice.view_reasons[0]):
            if why:
                keep[c, v] = False
        choices.append(choice)
    if all(choice is None for choice in choices):
        return replace(out, frame_choice=choices), None
    solved, subsets = solve_chosen(solving, out, keep, board_size, square)
    return replace(solved, frame_choice=choices), subsets


def keep_views(result: PipelineResult, keep: Sequence[bool]) -> PipelineResult:
    """One camera's result whose calibration no longer uses the views not in ``keep`` (a rig's joint fit takes the
    views its cameras' calibrations used)."""
    if result.calibration is None:
        return result
    mask = torch.as_tensor(list(keep), dtype=torch.bool, device=result.calibration.used.device)
    return replace(result, calibration=replace(result.calibration, used=result.calibration.used & mask))
