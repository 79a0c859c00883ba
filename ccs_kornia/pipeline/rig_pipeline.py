"""Board images of a rig's cameras in, the rig out: each camera as the single-camera pipeline calibrates it, then
one joint fit of every camera and their relative poses.

:class:`RigPipeline` runs :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` on every camera's views (detection,
lens correction, the model choice of ``model="auto"`` per camera, each camera's calibration), matches the views into
frames (:func:`~ccs_kornia.pipeline.frame_matching.match_frames` for files; the same position for tensors), gathers the corners
per camera and frame (the hidden corners of partial boards and the views the camera's own calibration rejected are
left out) and hands them to :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver`, started from the single-camera
calibrations. No command line, no Lightning here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Callable

import torch
from torch import nn

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.modules.detection.base import ChessboardDetector, measured_corners
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_weights
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.pipeline.frame_matching import FrameTable, match_frames
from ccs_kornia.pipeline.frame_selection import FrameSelection
from ccs_kornia.pipeline.result import PipelineResult
from ccs_kornia.pipeline.sources import FileSource, TensorSource, ViewSource

__all__ = ["FLEXIBLE_COVERAGE", "RigPipeline", "RigPipelineResult", "frame_times_of", "rig_observations",
           "unconnected_cameras"]

#: ``models="auto"``: a rig camera whose boards cover less of its image than this gets ``rational`` or ``fisheye``
#: only where no other model ties (``ModelSelection(flexible_coverage=...)``); the degeneracy checks' coverage warning
FLEXIBLE_COVERAGE = 0.20


@dataclass
class RigPipelineResult:
    """What :meth:`RigPipeline.run` returns for one rig.

    Attributes:
        names: camera names.
        cameras: per camera its single-camera :class:`~ccs_kornia.pipeline.result.PipelineResult` (no camera
            dimension; views in the camera's own order).
        frames: the views of each frame (:class:`~ccs_kornia.pipeline.frame_matching.FrameTable`).
        corners: :math:`(C, F, N, 2)` float64 pixels, NaN where not observed.
        valid: :math:`(C, F, N)` bool, the corners handed to the rig solver.
        weights: :math:`(C, F, N)` per-corner weights (``None`` without corner precisions).
        models: the model of each camera (the single-camera choice with a model choice).
        initial: per camera the starting intrinsics (one :class:`~ccs_kornia.geometry.camera.Camera`; the fixed
            ones where given), ``None`` for a camera without calibration.
        rig: the solver's ``RigResult`` (``None`` when the rig could not be solved: see ``reason``).
        reason: ``""`` when solved, else one line naming the cameras (and frames) at fault.
        fixed: per camera, its intrinsics were kept as given.
        frame_choice: with a frame selection, which of ``candidates``' frames were kept and why not the others
            (:class:`~ccs_kornia.pipeline.frame_selection.FrameChoice`); ``frames`` then holds the kept ones.
        candidates: the frames before the frame selection (``None`` without one).
        board_flatness: the board's sag and whether the rig kept it (``None``: not judged).
    """

    names: list[str]
    cameras: list[PipelineResult]
    frames: FrameTable
    corners: torch.Tensor
    valid: torch.Tensor
    weights: torch.Tensor | None
    models: list[Any]
    initial: list[Any]
    rig: Any = None
    reason: str = ""
    fixed: list[bool] | None = None
    frame_choice: Any = None
    candidates: FrameTable | None = None
    board_flatness: dict | None = None

    @property
    def success(self) -> bool:
        return self.rig is not None and bool(self.rig.success)


class _Cameras(ViewSource):
    """Some cameras of another source (the cameras of one model when models differ per camera)."""

    def __init__(self, source: ViewSource, cameras: Sequence[int]) -> None:
        self.source, self.cameras = source, list(cameras)
        self.decodes = getattr(source, "decodes", False)
        self.decode_workers = source.decode_workers
        super().__init__([source.counts[c] for c in self.cameras], [source.names[c] for c in self.cameras])

    def describe(self, camera: int, view: int) -> str:
        return self.source.describe(self.cameras[camera], view)

    def pixels(self, camera: int, view: int) -> int | None:
        return self.source.pixels(self.cameras[camera], view)

    def label(self, camera: int, view: int) -> str:
        return self.source.label(self.cameras[camera], view)

    def speed(self, camera: int, view: int) -> float | None:
        return self.source.speed(self.cameras[camera], view)

    def _load(self, camera: int, view: int):
        return self.source._load(self.cameras[camera], view)

    def given_detections(self, board_size: tuple[int, int], device: torch.device | str = "cpu"):
        given = self.source.given_detections(board_size, device)
        return None if given is None else given.select(self.cameras)


def rig_observations(
    cameras: Sequence[PipelineResult], frames: FrameTable
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Corners per camera and frame from the cameras' single-camera results.

    A view counts where the board was found on an image of the camera's size and, when the camera was calibrated,
    its calibration used the view (views it rejected as inconsistent stay out of the joint fit too); of such a view,
    the corners the image shows (a partial board's hidden corners are NaN) are valid.

    Args:
        cameras: one-camera results (``result.select(c)``).
        frames: which view of each camera belongs to each frame.

    Returns:
        ``corners`` :math:`(C, F, N, 2)` float64 (NaN where not valid), ``valid`` :math:`(C, F, N)` bool, ``weights``
        :math:`(C, F, N)` (``None`` when the detections carry no corner precision).
    """
    c, f = len(cameras), frames.num_frames
    n = cameras[0].detections.corners.shape[-2]
    corners = torch.full((c, f, n, 2), float("nan"), dtype=torch.float64)
    valid = torch.zeros(c, f, n, dtype=torch.bool)
    with_sigma = all(r.detections.sigma is not None for r in cameras)
    weights = torch.zeros(c, f, n, dtype=torch.float64) if with_sigma else None
    for ci, result in enumerate(cameras):
        det, cal = result.detections, result.calibration
        usable = result.usable_views.cpu()
        if cal is not None and bool(cal.success):
            usable &= cal.used.cpu()
        cam_valid = measured_corners(det.corners.cpu(), usable)
        # (the weights relative to the median of the views the rig takes)
        cam_weights = corner_weights(det.sigma.cpu(), cam_valid) if with_sigma else None
        for fi, k in enumerate(frames.index[ci]):
            if k is None or not bool(cam_valid[k].any()):
                continue
            valid[ci, fi] = cam_valid[k]
            corners[ci, fi] = torch.where(cam_valid[k, :, None], det.corners[k].cpu().double(), float("nan"))
            if weights is not None:
                weights[ci, fi] = cam_weights[k].cpu().double()
    return corners, valid, weights


def unconnected_cameras(valid: torch.Tensor, names: Sequence[str], labels: Sequence[str], min_shared: int = 1) -> str:
    """``""`` when every camera is linked to camera 0 through frames both cameras see, else one line naming the
    cameras cut off and the frames each camera saw.

    Args:
        valid: :math:`(C, F, N)` or :math:`(C, F)` bool observations.
        names: camera names; labels: frame names.
        min_shared: frames two cameras must share to be linked.

    Example:
        >>> v = torch.tensor([[True, True, False], [True, False, False], [False, False, True]])
        >>> unconnected_cameras(v, ["a", "b", "c"], ["01", "02", "03"])
        'camera c shares no frame with camera a or the cameras linked to it (a sees frames 01, 02; b: 01; c: 03)'
    """
    seen = valid.any(-1) if valid.dim() == 3 else valid
    shared = (seen[:, None, :] & seen[None, :, :]).sum(-1) >= min_shared
    linked, frontier = {0}, [0]
    while frontier:
        i = frontier.pop()
        for j in shared[i].nonzero().flatten().tolist():
            if j not in linked:
                linked.add(j)
                frontier.append(j)
    cut = [j for j in range(seen.shape[0]) if j not in linked]
    if not cut:
        return ""

    def frames_of(c: int) -> str:
        picks = [labels[k] for k in seen[c].nonzero().flatten().tolist()]
        return ", ".join(picks) if picks else "none"

    who = ", ".join(names[j] for j in cut)
    plural = "s" if len(cut) > 1 else ""
    views = "; ".join(f"{names[c]}: {frames_of(c)}" for c in range(1, seen.shape[0]))
    return (f"camera{plural} {who} share{'' if plural else 's'} no frame with camera {names[0]} or the cameras linked "
            f"to it ({names[0]} sees frames {frames_of(0)}; {views})")


def frame_times_of(frames: FrameTable) -> torch.Tensor | None:
    """The frames' times for the rig solver's board motion: the mean of the cameras' times where the frames were
    paired by time (videos, a timestamps table; NaN for a frame without one), else their numbers where every frame
    label is one (frames matched by the numbers in the file names), else ``None``.

    Example:
        >>> frame_times_of(FrameTable(["0416", "0417"], [[0, 1], [0, 1]], "number")).tolist()
        [416.0, 417.0]
        >>> frame_times_of(FrameTable(["0", "1"], [[0, 1], [0, 1]], "time", [[0.0, 0.1], [0.02, None]])).tolist()
        [0.01, 0.1]
    """
    if frames.times is not None:
        per_frame = [[row[f] for row in frames.times if row[f] is not None] for f in range(frames.num_frames)]
        return torch.tensor([sum(t) / len(t) if t else float("nan") for t in per_frame], dtype=torch.float64)
    try:
        return torch.tensor([float(label) for label in frames.labels], dtype=torch.float64)
    except ValueError:
        return None


def _same_position(counts: Sequence[int]) -> FrameTable:
    """Frames of in-memory views: frame ``f`` is view ``f`` of every camera that has one."""
    frames = max(counts)
    return FrameTable([str(f) for f in range(frames)], [[f if f < n else None for f in range(frames)] for n in counts],
                      "order")


class RigPipeline(nn.Module):
    """Calibrate a rig of ``C`` cameras from board images: each camera alone, then jointly with its pose.

    Args:
        detector: a detector name (``"learned"``, ``"opencv"``) or a :class:`ChessboardDetector` (shared by every
            camera).
        models: one model for every camera or one per camera (a camera model, or a
            :class:`~ccs_kornia.modules.calibration.model_selection.ModelChoice`: each camera's model chosen by the
            single-camera pipeline's cross-validation, ``rational`` and ``fisheye`` only where the boards cover at
            least ``flexible_coverage`` of the image or no other model ties).
        fixed: per camera index, a camera (one :class:`~ccs_kornia.geometry.camera.Camera`) whose intrinsics are kept as they are (e.g. from an earlier
            single-camera calibration).
        solver_kwargs: options of :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver` (``max_iters``, ...).
        board_flatness: also fit the rig with the board's sag and keep it where the held-out epipolar RMS says it
            helps (:func:`~ccs_kornia.modules.rig.rig_flatness.choose_rig_board_warp`; ``RigPipelineResult.
            board_flatness`` says what it found).
        flexible_coverage: see ``models`` (:data:`FLEXIBLE_COVERAGE`; ``None``: the single-camera choice as it is).
        frame_selection: keep only the frames that make the best rig
            (:class:`~ccs_kornia.pipeline.frame_selection.FrameSelection`, each frame judged across its cameras)
            before the joint fit; ``None``: every frame counts.
        pipeline_kwargs: options of :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` (``use_ransac``, ``workers``,
            ``distortion_correction``, ...).

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> pipe = RigPipeline("opencv", models=K1K2, distortion_correction=False)
        >>> [str(m) for m in pipe.pipelines]
        ['k1k2']
    """

    def __init__(
        self,
        detector: str | ChessboardDetector = "learned",
        models: Any = None,
        fixed: dict[int, Any] | None = None,
        solver_kwargs: dict[str, Any] | None = None,
        board_flatness: bool = False,
        flexible_coverage: float | None = FLEXIBLE_COVERAGE,
        frame_selection: FrameSelection | None = None,
        **pipeline_kwargs,
    ) -> None:
        super().__init__()
        shared = make_detector(detector) if isinstance(detector, str) else detector
        models = ModelChoice() if models is None else models
        self.models = models if isinstance(models, (CameraModel, ModelChoice)) else list(models)
        wanted = self._per_camera(1) if not isinstance(self.models, list) else self.models
        self.pipeline_list = nn.ModuleList([CalibrationPipeline(shared, model=m, **pipeline_kwargs)
                                            for m in sorted(set(wanted), key=str)])
        #: the single-camera pipeline of each model (or model choice)
        self.pipelines = {p.settings.model: p for p in self.pipeline_list}
        for pipeline in self.pipelines.values():
            if pipeline.selection is not None:
                pipeline.selection.flexible_coverage = flexible_coverage
        self.fixed = dict(fixed or {})
        self.solver_kwargs = dict(solver_kwargs or {})
        self.board_flatness = bool(board_flatness)
        self.frame_selection = frame_selection

    def _per_camera(self, count: int) -> list[Any]:
        """The model (or model choice) of each of ``count`` cameras."""
        return list(self.models) if isinstance(self.models, list) else [self.models] * count

    def forward(self, images: torch.Tensor | Sequence[torch.Tensor], board_size: tuple[int, int], square: float = 1.0,
                names: Sequence[str] | None = None) -> RigPipelineResult | list[RigPipelineResult]:
        """:meth:`run` on images in memory, frame ``f`` being view ``f`` of every camera.

        Args:
            images: :math:`(C, F, 1, H, W)`, one :math:`(F_c, 1, H_c, W_c)` per camera (sizes may differ), or
                :math:`(B, C, F, 1, H, W)` for ``B`` rigs: their cameras are detected and calibrated in one batched
                pipeline run, then each rig is solved (the rig solver starts every rig from its own cameras).
            board_size: ``(cols, rows)`` inner corners; square: square side in world units.
            names: camera names (default ``cam0``, ``cam1``, ...).

        Returns:
            :class:`RigPipelineResult`, or a list of ``B`` for 6-D input.
        """
        if isinstance(images, torch.Tensor) and images.dim() == 6:
            b, c = images.shape[:2]
            source = TensorSource(images.flatten(0, 1))
            cameras = self.detect_and_calibrate(source, board_size, square, models=self._per_camera(c) * b)
            table = _same_position([images.shape[2]] * c)
            return [self.run(_Cameras(source, range(k * c, (k + 1) * c)), board_size, square, table, names,
                             cameras=cameras[k * c:(k + 1) * c]) for k in range(b)]
        source = TensorSource(images)
        return self.run(source, board_size, square, _same_position(source.counts), names)

    def run_files(self, paths: Sequence[Sequence[str]], board_size: tuple[int, int], square: float,
                  names: Sequence[str] | None = None, progress: Callable[[int], None] | None = None) -> RigPipelineResult:
        """:meth:`run` on image files, one list per camera, matched into frames by
        :func:`~ccs_kornia.pipeline.frame_matching.match_frames` (the last number in the names, else natural order)."""
        return self.run(FileSource(paths, names), board_size, square, match_frames(paths), names, progress)

    def detect_and_calibrate(self, source: ViewSource, board_size: tuple[int, int], square: float,
                             progress: Callable[[int], None] | None = None,
                             models: Sequence[Any] | None = None, *,
                             on_batch: Callable[[list[tuple[int, int]], torch.Tensor], None] | None = None,
                             ) -> list[PipelineResult]:
        """Every camera through the single-camera pipeline of its model (``models``: per camera of ``source``,
        default this pipeline's); one result per camera. The cameras of one model go through one batched run.
        ``on_batch``: as :meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.detect_views`'s, with
        the cameras of ``source``."""
        c = source.num_cameras
        if models is None:
            models = self._per_camera(c)
        if len(models) != c:
            raise ValueError(f"{len(models)} models for {c} cameras.")
        out: list[PipelineResult | None] = [None] * c
        for model, pipeline in self.pipelines.items():
            cams = [i for i in range(c) if models[i] == model]
            part = source if len(cams) == c else _Cameras(source, cams)
            watch = None if on_batch is None else \
                (lambda keys, found, cams=cams: on_batch([(cams[c], v) for c, v in keys], found))
            result = pipeline.run(part, board_size, square, progress=progress, on_batch=watch)
            for k, i in enumerate(cams):
                out[i] = result.select(k)
        return out  # type: ignore[return-value]

    def choose_frames(self, source: ViewSource | None, cameras: list[PipelineResult], frames: FrameTable,
                      board_size: tuple[int, int], square: float) -> tuple[list[PipelineResult], FrameTable, Any]:
        """The frame selection over the rig's frames (:func:`~ccs_kornia.pipeline.frame_selection.choose_frames`,
        each frame judged across its cameras; the boards' speeds from ``source``, the time between a frame's cameras
        from ``frames.times``): the cameras' results with the views left out no longer used, the kept frames, and
        the :class:`~ccs_kornia.pipeline.frame_selection.FrameChoice`."""
        from ccs_kornia.pipeline.frame_selection import (
            camera_views,
            choose_frames,
            keep_views,
        )

        pipeline = next(iter(self.pipelines.values()))
        obj = pipeline.solving.object_points(board_size, square)
        views = []
        for c, result in enumerate(cameras):
            speeds = [source.speed(c, v) for v in range(source.counts[c])] if source is not None else None
            views.append(camera_views(result, obj, pipeline.settings.weigh_corners, speeds))
        choice = choose_frames(views, frames.index, self.frame_selection, frames.spread(),
                               [f"frame {label}" for label in frames.labels])
        kept = [f for f in range(frames.num_frames) if choice.kept[f]]
        cameras = [keep_views(result, choice.view_kept(c)) if views[c] is not None else result
                   for c, result in enumerate(cameras)]
        table = FrameTable([frames.labels[f] for f in kept], [[row[f] for f in kept] for row in frames.index],
                           frames.by, None if frames.times is None else [[row[f] for f in kept] for row in frames.times])
        return cameras, table, choice

    def run(
        self,
        source: ViewSource,
        board_size: tuple[int, int],
        square: float,
        frames: FrameTable,
        names: Sequence[str] | None = None,
        progress: Callable[[int], None] | None = None,
        cameras: list[PipelineResult] | None = None,
    ) -> RigPipelineResult:
        """Detect and calibrate each camera, gather the frames, solve the rig.

        Args:
            source: the cameras' views (:class:`~ccs_kornia.pipeline.sources.FileSource`, :class:`TensorSource`).
            board_size: ``(cols, rows)``; square: square side in world units (the unit of the rig's translations).
            frames: which view of each camera belongs to each frame.
            names: camera names (default ``cam0``, ...).
            progress: called with the number of views handled after every detection batch.
            cameras: single-camera results already computed (skips the detection and the cameras' calibrations).

        Returns:
            :class:`RigPipelineResult`.
        """
        c = source.num_cameras
        names = list(names) if names is not None else [f"cam{i}" for i in range(c)]
        if c < 2:
            raise ValueError(f"a rig needs at least two cameras, got {c}.")
        if len(frames.index) != c or len(names) != c:
            raise ValueError(f"{len(frames.index)} frame lists and {len(names)} names for {c} cameras.")
        from ccs_kornia.modules.rig import RigSolver
        from ccs_kornia.modules.calibration.board_flatness import board_warp_determined
        from ccs_kornia.modules.rig.rig_flatness import choose_rig_board_warp, not_determined
        cameras = cameras if cameras is not None else self.detect_and_calibrate(source, board_size, square, progress)
        choice, candidates = None, None
        if self.frame_selection is not None:
            candidates = frames
            cameras, frames, choice = self.choose_frames(source, cameras, frames, board_size, square)
        corners, valid, weights = rig_observations(cameras, frames)
        models, initial, reason = [], [], ""
        for i, result in enumerate(cameras):
            cal = result.calibration
            if i in self.fixed:
                cam = self.fixed[i].to("cpu", torch.float64)
                models.append(cam.model)
                initial.append(cam)
            elif cal is not None and bool(cal.success):
                models.append(cal.camera.model)
                initial.append(cal.camera.to("cpu", torch.float64))
            else:
                models.append(cal.camera.model if cal is not None else None)
                initial.append(None)
                reason = reason or f"camera {names[i]}: {result.camera_reasons or 'not calibrated'}"
        fixed = [i in self.fixed for i in range(c)]
        out = RigPipelineResult(names, cameras, frames, corners, valid, weights, models, initial, reason=reason,
                                fixed=fixed, frame_choice=choice, candidates=candidates)
        if reason:
            return out
        out.reason = unconnected_cameras(valid, names, frames.labels)
        if out.reason:
            return out
        object_points = next(iter(self.pipelines.values())).solving.object_points(board_size, square)
        solver = RigSolver(models=models, **self.solver_kwargs)
        sizes = [tuple(int(x) for x in r.image_size) for r in cameras]
        try:
            out.rig = solver(corners, valid, object_points, sizes, initial=initial,
                             fixed=fixed if any(fixed) else None, names=names, weights=weights,
                             frame_times=frame_times_of(frames))
        except ValueError as err:  # the solver's refusal (e.g. cameras linked by too few corners), one line
            out.reason = str(err)
            return out
        if out.rig.success and self.board_flatness:
            def bent(**options):
                return RigSolver(models=models, board_warp=True, **(self.solver_kwargs | options))(
                    corners, valid, object_points, sizes, initial=initial, fixed=fixed if any(fixed) else None,
                    names=names, weights=weights, frame_times=frame_times_of(frames))

            # one joint fit first says whether the frames determine a sag at all; only then the whole fit and its
            # held-out folds
            probe = bent(folds=0, frame_passes=0)
            if board_warp_determined(probe.board_warp, probe.board_warp_std, object_points):
                out.rig, out.board_flatness = choose_rig_board_warp(out.rig, bent(), object_points)
            else:
                out.board_flatness = not_determined(probe.board_warp, probe.board_warp_std)
        if not out.rig.success:
            out.reason = out.rig.reason or "the joint fit of the rig failed"
        return out
