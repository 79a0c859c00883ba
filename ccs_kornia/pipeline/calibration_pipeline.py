"""Chessboard images in, camera calibration out: the one composition of the paper's three stages.

:meth:`CalibrationPipeline.run` is the only place where the stages are put in order; ``forward`` (tensors), the
command line (files, :class:`~ccs_kornia.pipeline.sources.FileSource`), ``calibrate-many`` (Lightning predict) and the
benchmarks all call it:

1. **correct** (paper Sec. III-A): the :class:`~ccs_kornia.modules.correction.distortion_net.DistortionNet`
   predicts a radial correction per view; a camera's views share its lens, so the predictions are pooled into one
   correction per camera (:mod:`~ccs_kornia.modules.correction.pooling`);
2. **detect** (Sec. III-B): the board is looked for on every image as it is (the first look); then each of the
   pipeline's ``looks`` (by default :data:`~ccs_kornia.pipeline.looks.LOOKS`) on the views missed so far: for a
   camera whose pooled correction is
   large, on corrected copies; for a camera calibrated with the fisheye model, on virtual pinhole views of the
   calibrated lens; last, on the detector's foreshortened levels; corners mapped back to the original images;
3. **solve** (Sec. III-C): per image size, one batched solver call over the cameras
   (:class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`: homographies, Zhang, image-level RANSAC,
   joint Levenberg-Marquardt). Where the pooled correction is large, the camera is also calibrated in the
   corrected frame (:mod:`~ccs_kornia.modules.calibration.corrected_frame`) and that calibration is kept only where
   it fits the observed corners clearly better (``max_rms_ratio``) than the usual one: the image's corners referee,
   not the network's estimate (which misfires on undistorted lenses and can miss a strong one's shape). A lens
   without distortion therefore keeps the calibration it gets without the correction.

Views are read through a :class:`~ccs_kornia.pipeline.sources.ViewSource` in batches of one size, bounded in number and in
pixels (only corners are kept between passes). No command line, no Lightning here.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import replace
from typing import Callable

import torch
from torch import nn

from ccs_kornia.modules._checks import check_board_size
from ccs_kornia.modules.calibration.model_selection import AUTO_MODELS, ModelSelection
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.modules.correction.distortion_net import load_distortion_net
from ccs_kornia.modules.correction.pooling import (
    aggregate_corrections,
    correction_displacement,
)
from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    Fallbacks,
    measured_corners,
)
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_uncertainty
from ccs_kornia.modules.detection.refine.patch_refine import refine_on_patches
from ccs_kornia.modules.detection.refine.saddle_refine import CornerRefiner
from ccs_kornia.modules.detection.warps.warped_detection import Downscale, detect_warped
from ccs_kornia.pipeline.differentiable import differentiable_detect, differentiable_run
from ccs_kornia.pipeline.frame_selection import FrameSelection, select_views
from ccs_kornia.pipeline.looks import CALIBRATED, FIRST, LOOKS, Look, Tools
from ccs_kornia.pipeline.result import (
    PipelineResult,
    main_size,
    module_device,
    positive_size,
    select_result,
)
from ccs_kornia.pipeline.solve import (
    Solving,
    diagnose_solved,
    solve_detections,
    solve_group,
)
from ccs_kornia.pipeline.solver_input import SolverInput
from ccs_kornia.pipeline.sources import (  # noqa: F401
    DEFAULT_MAX_BATCH_PIXELS,
    SIZE_TOLERANCE_PX,
    TensorSource,
    ViewSource,
)
from ccs_kornia.pipeline.workers import default_workers, map_batches, workers_on
from ccs_kornia.runtime.timing import stage

__all__ = ["PipelineResult", "CalibrationPipeline"]


class CalibrationPipeline(nn.Module):
    """Detect chessboard corners and calibrate the camera(s): correct -> detect -> solve (:meth:`run`).

    Args:
        detector: a detector name for :func:`~ccs_kornia.modules.detection.factory.make_detector`
            (``"opencv"`` or ``"learned"``) or a :class:`ChessboardDetector` instance.
        model: ``opencv5`` (k1, k2, p1, p2, k3), ``k1k2``, ``rational``, ``none``, ``fisheye`` (cv2.fisheye's) or
            ``auto`` (one of :data:`~ccs_kornia.modules.calibration.model_selection.AUTO_MODELS` per camera, by
            cross-validation; ``PipelineResult.model_selection`` says which and why).
        auto_models: the candidates of ``model="auto"`` (default all of ``AUTO_MODELS``), e.g. without ``rational``
            for a camera whose calibration goes to a format that cannot hold it (Kalibr's camchain).
        use_ransac: reject inconsistent views with image-level RANSAC before the refinement.
        seed: seed of the RANSAC sampling (results are deterministic for a given seed).
        detection_batch_size: most images handed to the detector at once.
        workers: processes that detect a source's views on CPU (:mod:`~ccs_kornia.pipeline.workers`: forked, one thread
            each, the same batches and results with any number; ``"auto"``: one per core, at most 4).
        max_batch_pixels: most pixels loaded and detected at once (bounds memory; at least one image).
        max_detection_side: images whose longer side exceeds this are detected on a downscaled copy and refined at
            full resolution (``None`` or 0: always detect at full resolution). A detector that picks its own
            detection level (``selects_scale``: the learned one with ``scale="auto"``) gets the full images, and the
            corrected copies of large images are warped at this size.
        distortion_correction: ``True`` (the shipped network), ``False`` (off), a weight-file path or a
            ``DistortionNet``.
        min_correction: a camera's pooled correction counts as large when it moves some pixel by more than this
            fraction of the half image diagonal (0.02: 8 px at 640x480); only then is the correction used at all.
        max_rms_ratio: the corrected-frame calibration is kept only if its radial model's RMS on the observed
            corners is at most this times that of the usual calibration (same parameter count for ``opencv5``).
        joint_iters: accepted LM steps at most of the corrected-frame joint refinement (the core runs up to 10x
            as many iterations): distorted held-out cameras need 6-18 iterations; on undistorted ones, where the free
            distortion centre is unobservable, it crawls for 30-500 (up to 0.5 s per camera) to gain a fraction of a
            percent of RMS, and such a camera keeps the usual calibration anyway.
        free_distortion_centre: the corrected-frame refinement also estimates the distortion centre.
        looks: the looks after the first, in order (:class:`~ccs_kornia.pipeline.looks.Look` values; default
            :data:`~ccs_kornia.pipeline.looks.LOOKS`).
        calibrated_look: keep the calibrated look among ``looks``
            (:data:`~ccs_kornia.pipeline.looks.CALIBRATED`: views missed on the originals of a camera calibrated with
            a fisheye model looked for again on virtual pinhole views of the calibrated lens, and the camera solved
            again with them).
        diagnostics: also compute each camera's quality figures and verdict (``PipelineResult.diagnostics``; see
            :func:`~ccs_kornia.modules.calibration.quality.diagnostics.diagnose`: several more solves per camera).
        weigh_corners: measure each detected corner's precision on its image
            (:func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_uncertainty`, ``DetectionResult.sigma``)
            and weight the solver's refinements by it, so a view's soft or shaded corners count less
            (:func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_weights`).
        frame_selection: keep only the views that make the best camera
            (:class:`~ccs_kornia.pipeline.frame_selection.FrameSelection`: still, sharp, new, informative) and solve
            again on them after the last solve (``PipelineResult.frame_choice`` says which and why); ``None``: every
            view counts.
        differentiable: :meth:`forward`, :meth:`detect` and :meth:`calibrate` return corners and cameras with
            gradients to the images and the heatmap network (:mod:`~ccs_kornia.pipeline.differentiable`: the usual
            pipeline takes every decision and gives the values, in one process; the corners of found boards and the
            solve are then differentiated; ``docs/gradients.md``). Off: no autograd anywhere, as before.
        solver_kwargs: further options of :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`.

    Example:
        >>> from ccs_kornia.data.scenes import make_calibration_set
        >>> K = torch.tensor([[300., 0, 160], [0, 300, 120], [0, 0, 1]], dtype=torch.float64)
        >>> views = make_calibration_set(K, (6, 4), 0.025, (320, 240), num_views=5, seed=1, supersample=1)
        >>> out = CalibrationPipeline("opencv")(views.images, (6, 4), 0.025)
        >>> out.K.shape, out.found.shape, out.view_rms.shape, bool(out.calibration.success)
        (torch.Size([3, 3]), torch.Size([5]), torch.Size([5]), True)
        >>> bool((out.K - K).abs().max() < 3.0), bool(out.corrected)
        (True, False)
    """

    def __init__(
        self,
        detector: str | ChessboardDetector = "learned",
        model: str = "opencv5",
        use_ransac: bool = True,
        seed: int = 0,
        detection_batch_size: int = 16,
        workers: int | str = 1,
        max_batch_pixels: int | None = DEFAULT_MAX_BATCH_PIXELS,
        max_detection_side: int | None = 2048,
        distortion_correction=True,
        min_correction: float = 0.02,
        max_rms_ratio: float = 0.9,
        joint_iters: int = 4,
        free_distortion_centre: bool = True,
        diagnostics: bool = False,
        looks: Sequence[Look] | None = None,
        calibrated_look: bool = True,
        weigh_corners: bool = True,
        differentiable: bool = False,
        auto_models: Sequence[str] = AUTO_MODELS,
        frame_selection: FrameSelection | None = None,
        **solver_kwargs,
    ) -> None:
        super().__init__()
        self.detector = make_detector(detector) if isinstance(detector, str) else detector
        if not isinstance(self.detector, ChessboardDetector):
            raise ValueError(f"detector must be a name or a ChessboardDetector, got {type(detector).__name__}.")
        if detection_batch_size < 1:
            raise ValueError(f"detection_batch_size must be >= 1, got {detection_batch_size}.")
        if max_detection_side is not None and max_detection_side != 0 and max_detection_side < 64:
            raise ValueError(f"max_detection_side must be >= 64 (or None/0 to disable), got {max_detection_side}.")
        if joint_iters < 0:
            raise ValueError(f"joint_iters must be >= 0, got {joint_iters}.")
        for name, value in (("min_correction", min_correction), ("max_rms_ratio", max_rms_ratio)):
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value}.")
        candidates = tuple(dict.fromkeys(auto_models))
        if not candidates or any(m not in AUTO_MODELS for m in candidates):
            raise ValueError(f"auto_models must be some of {', '.join(AUTO_MODELS)}, got {list(auto_models)}.")
        names = candidates if model == "auto" else (model,)
        self.solvers = nn.ModuleDict({m: CalibrationSolver(model=m, use_ransac=use_ransac, seed=seed, **solver_kwargs)
                                      for m in names})
        # the stage alone's (auto: opencv5 where it is a candidate)
        self.solver = self.solvers[("opencv5" if "opencv5" in names else names[0]) if model == "auto" else model]
        self.selection = ModelSelection(dict(self.solvers)) if model == "auto" else None
        self.model, self.diagnostics = model, bool(diagnostics)
        #: the looks after the first, in order
        self.looks: tuple[Look, ...] = tuple(look for look in (LOOKS if looks is None else looks)
                                             if calibrated_look or look is not CALIBRATED)
        self.detection_batch_size = int(detection_batch_size)
        if workers != "auto" and not (isinstance(workers, int) and workers >= 1):
            raise ValueError(f"workers must be an int >= 1 or 'auto', got {workers!r}.")
        self.workers = default_workers("cpu") if workers == "auto" else workers
        if differentiable:  # autograd's graph lives in this process: no worker processes
            self.workers = 1
        self.max_batch_pixels = max_batch_pixels
        self.max_detection_side = int(max_detection_side) if max_detection_side else None
        self.refiner = CornerRefiner()
        self.distortion_net = load_distortion_net(distortion_correction)
        self.min_correction = float(min_correction)
        self.max_rms_ratio = float(max_rms_ratio)
        self.joint_iters = int(joint_iters)
        self.free_distortion_centre = bool(free_distortion_centre)
        self.weigh_corners = bool(weigh_corners)
        self.differentiable = bool(differentiable)
        self.frame_selection = frame_selection

    # ------------------------------------------------------------------------------------------
    # the composition
    # ------------------------------------------------------------------------------------------

    def forward(self, images: torch.Tensor, board_size: tuple[int, int], square: float = 1.0) -> PipelineResult:
        """Detect and calibrate: :meth:`run` on images in memory.

        Args:
            images: :math:`(V, 1, H, W)` (one camera) or :math:`(C, V, 1, H, W)` (``C`` cameras) float in ``[0, 1]``.
            board_size: ``(cols, rows)`` inner corners.
            square: square side in world units.

        Returns:
            :class:`~ccs_kornia.pipeline.result.PipelineResult` (no camera dimension for 4-D input).
        """
        if self.differentiable:
            usual = self._usual(images, board_size, square, calibrate=True)
            return differentiable_run(usual, images, board_size, square, self.detector, self.solving)
        out = self.run(TensorSource(images), board_size, square)
        return out.select(0) if images.dim() == 4 else out

    def _usual(self, images: torch.Tensor, board_size: tuple[int, int], square: float,
               calibrate: bool) -> PipelineResult:
        """:meth:`run` on ``images`` (V, 1, H, W) or (C, V, 1, H, W) without autograd: the decisions and values that
        the differentiable path (:mod:`~ccs_kornia.pipeline.differentiable`) then differentiates."""
        batched = images if images.dim() == 5 else images[None]
        with torch.no_grad():
            return self.run(TensorSource(batched.detach()), board_size, square, calibrate=calibrate)

    def run(
        self,
        source: ViewSource | None,
        board_size: tuple[int, int],
        square: float = 1.0,
        calibrate: bool = True,
        progress: Callable[[int], None] | None = None,
        *,
        first: PipelineResult | None = None,
        on_batch: Callable[[list[tuple[int, int]], torch.Tensor], None] | None = None,
    ) -> PipelineResult:
        """The stages in order, correct -> detect -> solve, on every camera of ``source``: one loop over the looks.
        The first look streams every view once (:meth:`detect_views`: the network's correction and the board on the
        image as it is), the corrections are pooled per camera; each of :attr:`looks` runs on the views still missed,
        the cameras solved before a look that needs them; a final solve where a look found boards since, then the
        diagnostics.

        Args:
            source: the views (:class:`~ccs_kornia.pipeline.sources.TensorSource` or :class:`~ccs_kornia.pipeline.sources.FileSource`;
                ``None`` with ``first``: no look at missed views).
            board_size: ``(cols, rows)`` inner corners.
            square: square side in world units.
            calibrate: ``False`` stops before the solver (``calibration`` is ``None``; :meth:`solve` completes it);
                the looks that need a camera are then skipped.
            progress: called with the number of views handled after every batch of the first look.
            first: the first look's result already at hand (:meth:`detect_views`, or views taken from one,
                :meth:`~ccs_kornia.pipeline.result.PipelineResult.take_views`): the loop starts after it.
            on_batch: see :meth:`detect_views`.

        Returns:
            A batched :class:`~ccs_kornia.pipeline.result.PipelineResult`.
        """
        board = check_board_size(board_size)
        out, pooled, solved, changed, subsets = first, False, False, False, None
        for look in (FIRST, *self.looks):
            if look is FIRST:
                out = self.detect_views(source, board, progress, on_batch=on_batch) if out is None else out
                pooled = out.view_corrections is not None and self.distortion_net is not None
                if pooled:
                    with stage("correction evidence"):
                        out = self._pool(out)
                continue
            if look.needs_correction and not pooled or look.needs_camera and not calibrate:
                continue
            if look.needs_camera and (changed or not solved):
                (out, subsets), solved, changed = self._solve(out, board, square, again=solved), True, False
            out, found = self._look(look, source, out, board)
            changed = found or changed
        if calibrate and (changed or not solved):
            out, subsets = self._solve(out, board, square, again=solved)
        if calibrate and self.frame_selection is not None:
            with stage("frame selection"):
                out, subsets = select_views(self.solving, out, board, square, self.frame_selection, source)
        if calibrate and self.diagnostics:
            with stage("solver"):
                out = diagnose_solved(self.solving, out, board, square, subsets)
        return out

    def detect_views(
        self, source: ViewSource, board_size: tuple[int, int], progress: Callable[[int], None] | None = None,
        *, on_batch: Callable[[list[tuple[int, int]], torch.Tensor], None] | None = None,
    ) -> PipelineResult:
        """One streamed pass over the views: the network's lens correction of each view (stage 1) and the board on
        each image as it is (stage 2); :meth:`finish` does the rest.

        ``progress`` is called with the number of views handled after every batch; ``on_batch`` with the batch's
        ``(camera, view)`` keys and whether the board was found on each, :math:`(B,)` bool: it may raise to stop the
        run (a caller that sees the first views miss the board it was given).

        Returns:
            A batched :class:`~ccs_kornia.pipeline.result.PipelineResult` without calibration; ``view_corrections``
            holds the per-view network predictions (``None`` when the correction is off).
        """
        cols, rows = board = check_board_size(board_size)
        device = module_device(self)
        c, v, n = source.num_cameras, source.max_views, cols * rows
        corners = torch.zeros(c, v, n, 2, dtype=torch.float64, device=device)
        sigma = torch.full((c, v, n), float("nan"), dtype=torch.float32, device=device) if self.weigh_corners else None
        found = torch.zeros(c, v, dtype=torch.bool, device=device)
        present = torch.zeros(c, v, dtype=torch.bool, device=device)
        sizes = torch.zeros(c, v, 2, dtype=torch.long)
        reasons = [[""] * v for _ in range(c)]
        per_view = None
        if self.distortion_net is not None:
            per_view = torch.full((c, v, 5), float("nan"), dtype=torch.float64, device=device)
        # batches of views, in forked worker processes on CPU (pipeline/workers.py: the same batches for any number)
        for batch in map_batches(functools.partial(self._detect_batch, board=board, device=device), source,
                                 FIRST.select(None, self.detector),
                                 self.detection_batch_size, self.max_batch_pixels,
                                 workers_on(device, self.workers)):
            for (ci, vi), why in batch.failed:
                reasons[ci][vi] = f"unreadable: {why}"
            if batch.size is None:
                continue
            corrections, det = batch.value
            cam = torch.tensor([k[0] for k in batch.keys], device=device)
            view = torch.tensor([k[1] for k in batch.keys], device=device)
            if per_view is not None:
                per_view[cam, view] = corrections.to(device)
            corners[cam, view], found[cam, view] = det.corners.to(device).double(), det.found.to(device)
            present[cam, view] = True
            if sigma is not None and det.sigma is not None:
                sigma[cam, view] = det.sigma.to(sigma)
            sizes[cam.cpu(), view.cpu()] = torch.tensor(batch.size)
            for k, (ci, vi) in enumerate(batch.keys):
                reasons[ci][vi] = (det.reasons[k] if det.reasons else "") or ("" if det.found[k] else "board not found")
            if progress is not None:
                progress(len(batch.keys) + len(batch.failed))
            if on_batch is not None:
                on_batch(list(batch.keys), det.found.cpu())
        image_size = [main_size(sizes[ci], found[ci].cpu(), present[ci].cpu()) for ci in range(c)]
        return PipelineResult(DetectionResult(corners, found, [r for rs in reasons for r in rs], sigma), None, image_size,
                              present, sizes.to(device), camera_reasons=[""] * c, view_corrections=per_view)

    def _detect_batch(self, images: torch.Tensor, keys: list, board: tuple[int, int], device: torch.device):
        """One batch of :meth:`detect_views`: the network's correction of each view (or ``None``) and the detection."""
        images = images.to(device)
        corrections = self.view_corrections(images) if self.distortion_net is not None else None
        # (the detector's costly last resort, boards at a grazing angle, waits for the views the other looks miss)
        return corrections, FIRST.run(self.tools, None, images, keys, board)

    def finish(
        self,
        out: PipelineResult,
        board_size: tuple[int, int],
        square: float = 1.0,
        source: ViewSource | None = None,
        calibrate: bool = True,
    ) -> PipelineResult:
        """:meth:`run` from after its first look (:meth:`detect_views`, ``first=out``): the network's corrections
        pooled per camera, then the pipeline's :attr:`looks` in turn, each on the views missed
        so far (read again from ``source``), the cameras solved before a look that needs them, and solved again at the
        end where a look found boards since.

        Args:
            out: a batched result of :meth:`detect_views` (or views taken from one, see
                :meth:`~ccs_kornia.pipeline.result.PipelineResult.take_views`).
            board_size, square: the board.
            source: where the views can be read again (``None``: no look at missed views).
            calibrate: run the solver (``False``: the looks that need no camera only).
        """
        return self.run(source, board_size, square, calibrate, first=out)

    def _look(self, look: Look, source: ViewSource | None, out: PipelineResult,
              board: tuple[int, int]) -> tuple[PipelineResult, bool]:
        """``look`` at the views it selects (none without a ``source``), in the pipeline's batches: ``out`` with the
        boards found written into its detections (and what the look measures after, ``Look.after``), and whether
        there were any."""
        # (the corrected look is charged to the profile's correction stage; the others, to their own stages inside)
        with stage("correction evidence") if look.needs_correction else nullcontext():
            keys = [] if source is None else look.select(out, self.detector)
            det, found = out.detections, False
            device = det.corners.device
            tools = self.tools
            for batch in map_batches(functools.partial(look.run, tools, out, board_size=board), source, keys,
                                     self.detection_batch_size, self.max_batch_pixels,
                                     workers_on(device, self.workers) if look.in_workers else 1) if keys else ():
                if batch.size is None:
                    continue
                cam = torch.tensor([k[0] for k in batch.keys], device=device)
                view = torch.tensor([k[1] for k in batch.keys], device=device)
                found = bool(det.fill((cam, view), batch.value).any()) or found
            if look.after is not None:
                out = look.after(out, board)
        return out, found

    def _solve(self, out: PipelineResult, board: tuple[int, int], square: float,
               again: bool) -> tuple[PipelineResult, SubsetSolutions]:
        """The solver on ``out``'s detections; ``again`` (a look found boards since the last solve): with the models
        chosen then (the looks add a few views), unless a camera had none (too few views). Returns the solved result
        and the solve's cross-validation subsets (for the diagnostics)."""
        chosen = again and (out.model_selection is None or all((m or {}).get("chosen") for m in out.model_selection))
        with stage("solver"):
            return solve_detections(self.solving, out, board, square, keep_models=chosen)

    @property
    def solving(self) -> Solving:
        """The solver stage's settings (:class:`~ccs_kornia.pipeline.solve.Solving`)."""
        return Solving(self.model, self.solvers, self.solver, self.selection, self.weigh_corners, self.workers,
                       self.joint_iters, self.free_distortion_centre, self.max_rms_ratio, self.detector.board)

    @property
    def tools(self) -> Tools:
        """What the looks detect with (:class:`~ccs_kornia.pipeline.looks.Tools`)."""
        return Tools(self.detect_images, self.refine_on_patches, self.corner_sigma if self.weigh_corners else None,
                     self.detector, self.workers)

    def _pool(self, out: PipelineResult) -> PipelineResult:
        """``out`` with the per-view corrections pooled per camera (``correction`` and ``correction_tried``)."""
        per_view, same = out.view_corrections, out.same_size_views
        c = per_view.shape[0]
        device = per_view.device
        correction = torch.zeros(c, 5, dtype=torch.float64, device=device)
        correction[:, 0] = 1.0
        large = torch.zeros(c, dtype=torch.bool, device=device)
        for size in set(out.image_size):
            sel = torch.tensor([s == size for s in out.image_size], device=device).nonzero().flatten()
            mask = same[sel] & per_view[sel].isfinite().all(-1)
            correction[sel], large[sel] = self.pool_corrections(per_view[sel], positive_size(size), mask)
        # every camera with a large correction goes to the corrected frame, where the observed corners referee it
        # against the usual calibration; a gate on the network's correction straightening the boards (or on the
        # usual model's misfit) kept held-out cameras from it that needed it (docs/benchmarks.md, section 4)
        return replace(out, correction=correction, correction_tried=large)

    def solve(self, out: PipelineResult, board_size: tuple[int, int], square: float = 1.0) -> PipelineResult:
        """The solver stage of :meth:`run` on its detections (:func:`~ccs_kornia.pipeline.solve.solve_detections`):
        one batched solve per image size (per model with ``model="auto"``); where the correction was tried, the
        corrected-frame calibration competes with the usual one.

        Args:
            out: a batched result of ``run(..., calibrate=False)``.
            board_size: ``(cols, rows)``; square: square side in world units.

        Returns:
            ``out`` with ``calibration``, ``corrected``, ``correction`` (re-fitted where kept), ``camera_reasons``,
            ``model_selection`` and ``diagnostics`` (when computed) filled.
        """
        board = check_board_size(board_size)
        out, subsets = solve_detections(self.solving, out, board, square)
        return diagnose_solved(self.solving, out, board, square, subsets) if self.diagnostics else out

    # ------------------------------------------------------------------------------------------
    # the stages, each usable alone
    # ------------------------------------------------------------------------------------------

    def detect(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Stages 1-2 of :meth:`run` (the correction's detection of missed views included) on images in memory.

        The returned result also carries ``correction`` and ``correction_tried`` per camera, so that
        ``calibrate(det.corners, det.found, board, square, size, det.correction, det.correction_tried)`` gives
        exactly what ``pipe(images, board, square)`` gives.

        Args:
            images: :math:`(V, 1, H, W)` or :math:`(C, V, 1, H, W)` float in ``[0, 1]``.
            board_size: ``(cols, rows)`` inner corners.

        Returns:
            :class:`DetectionResult` with the leading dimensions of ``images``.
        """
        if self.differentiable:
            usual = self._usual(images, board_size, 1.0, calibrate=False)
            return differentiable_detect(usual, images, board_size, self.detector)
        out = self.run(TensorSource(images), board_size, calibrate=False)
        det = replace(out.detections, correction=out.correction, correction_tried=out.correction_tried)
        return select_result(det, 0) if images.dim() == 4 else det

    def calibrate(
        self,
        corners: torch.Tensor,
        valid: torch.Tensor,
        board_size: tuple[int, int],
        square: float,
        image_size: tuple[int, int],
        correction: torch.Tensor | None = None,
        correction_tried: torch.Tensor | None = None,
        init_corners: torch.Tensor | None = None,
        initial: CalibrationResult | None = None,
        sigma: torch.Tensor | None = None,
    ) -> CalibrationResult:
        """Stage 3 of :meth:`run`: calibrate from corners.

        Without ``correction`` this is the solver alone; with the ``correction`` and ``correction_tried`` that
        :meth:`detect` returns, the corrected-frame calibration competes as in :meth:`run`; with its ``sigma`` too, the
        corners are weighted as :meth:`run` weighs them, so the result is the whole call's.

        Args:
            corners: :math:`(V, N, 2)` or :math:`(C, V, N, 2)` pixels in grid order.
            valid: :math:`(V, N)` / :math:`(C, V, N)` bool, or per view :math:`(V,)` / :math:`(C, V)`.
            board_size: ``(cols, rows)``; ``N = cols * rows``.
            square: square side in world units (scales the translations only).
            image_size: ``(W, H)``.
            correction, correction_tried: :math:`(5,)` / :math:`(C, 5)` and bool scalar / :math:`(C,)`.
            init_corners, initial: optional start of the solver, see
                :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`.
            sigma: :math:`(V, N)` / :math:`(C, V, N)` each corner's measured precision (``DetectionResult.sigma``):
                the corners are weighted by it where the pipeline weighs corners (``weigh_corners``); ``None``: all
                corners count alike.

        Returns:
            :class:`~ccs_kornia.modules.calibration.result.CalibrationResult`.
        """
        cols, rows = board = check_board_size(board_size)
        if corners.dim() not in (3, 4) or corners.shape[-1] != 2 or corners.shape[-2] != cols * rows:
            raise ValueError(
                f"Expected corners (V, {cols * rows}, 2) or (C, V, {cols * rows}, 2) for a {cols}x{rows} board, "
                f"got {tuple(corners.shape)}."
            )
        if valid.shape == corners.shape[:-2]:
            valid = measured_corners(corners, valid)
        if valid.shape != corners.shape[:-1]:
            raise ValueError(f"valid must have shape {tuple(corners.shape[:-1])}, got {tuple(valid.shape)}.")
        if not square > 0:
            raise ValueError(f"square must be positive, got {square}.")
        size = (int(image_size[0]), int(image_size[1]))
        if sigma is not None and sigma.shape != corners.shape[:-1]:
            raise ValueError(f"sigma must have shape {tuple(corners.shape[:-1])}, got {tuple(sigma.shape)}.")
        solving = self.solving
        object_points = solving.object_points(board, square, corners.device)
        sigma = sigma if solving.weigh_corners else None
        if (correction is not None and correction_tried is not None) or self.model == "auto":
            single = corners.dim() == 3
            batch = (lambda x: None if x is None else x[None]) if single else (lambda x: x)
            # as the run solves: the measured corners of the views with any valid corner
            inputs = SolverInput.from_views(batch(corners).double(), batch(valid).any(-1), object_points, batch(sigma))
            calib = solve_group(solving, inputs, board, square, size,
                                None if correction is None else batch(correction).double(),
                                None if correction_tried is None else batch(torch.as_tensor(correction_tried)))[0]
            return select_result(calib, 0) if single else calib
        inputs = SolverInput.from_corners(corners, valid, object_points, sigma)
        with nullcontext() if self.differentiable else torch.inference_mode():
            return inputs.solve(
                self.solver, size,
                init_corners=None if init_corners is None else init_corners.to(corners.device, torch.float64),
                initial=initial,
            )

    def view_corrections(self, images: torch.Tensor) -> torch.Tensor:
        """The network's radial correction of each view, :math:`(B, 5)` float64, for images :math:`(B, 1, H, W)`."""
        if self.distortion_net is None:
            raise RuntimeError("distortion correction is off for this pipeline.")
        net = self.distortion_net.to(images.device)
        with torch.inference_mode(), stage("distortion network"):
            return torch.cat([net(images[i : i + 16].float()) for i in range(0, images.shape[0], 16)]).double()

    def pool_corrections(
        self, per_view: torch.Tensor, image_size: tuple[int, int], mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One correction per camera from :math:`(C, V, 5)` per-view ones, and whether it is large :math:`(C,)`
        (it moves some pixel by more than ``min_correction`` of the half image diagonal)."""
        correction = aggregate_corrections(per_view.double().nan_to_num(0.0), image_size, mask)
        return correction, self.correction_is_large(correction, image_size)

    def correction_is_large(self, correction: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
        """:math:`(C,)`: the corrections :math:`(C, 5)` move some pixel by more than ``min_correction`` of the half
        image diagonal."""
        half_diagonal = 0.5 * math.hypot(image_size[0], image_size[1])
        return correction_displacement(correction, image_size) > self.min_correction * half_diagonal

    def detect_images(self, images: torch.Tensor, board_size: tuple[int, int],
                      fallbacks: Fallbacks | None = None) -> DetectionResult:
        """The detector on ``(B, 1, H, W)`` images of one size, through a downscaled copy when they are large
        (:class:`~ccs_kornia.modules.detection.warps.warped_detection.Downscale`), with ``fallbacks`` (``None``: the
        detector's own); the corners' precision measured where the pipeline weighs corners."""
        h, w = images.shape[-2:]
        limit = self.max_detection_side
        measure = self.corner_sigma if self.weigh_corners else None
        with torch.inference_mode():
            # a detector that picks its own detection level and refines at full resolution (the learned one with
            # ``scale="auto"``, modules/detection/learned/scale.py) bounds its memory itself
            if limit is None or max(h, w) <= limit or self.detector.selects_scale:
                det = self.detector.detect(images.float(), board_size, fallbacks)
                sigma = None
                if measure is not None:
                    # the learned detector has measured them on these images (its asymmetry check)
                    sigma = det.sigma
                    if sigma is None:
                        sigma = self.corner_sigma(images, det.corners, board_size, det.found)
                return DetectionResult(det.corners, det.found, det.reasons, sigma)
            detect = functools.partial(self.detector.detect, fallbacks=fallbacks)
            return detect_warped(Downscale.to_side((h, w), limit), detect, self.refine_on_patches, images, board_size,
                                 measure)

    def corner_sigma(self, images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int],
                     found: torch.Tensor | None = None) -> torch.Tensor:
        """Per-corner precision :math:`(B, N)` of boards :math:`(B, N, 2)` on ``images`` :math:`(B, 1, H, W)` (NaN where
        ``found`` is false; :func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_uncertainty`)."""
        found = torch.ones(corners.shape[0], dtype=torch.bool, device=corners.device) if found is None else found
        with stage("corner uncertainty"):
            return corner_uncertainty(images.float(), corners.float(), measured_corners(corners, found),
                                      board_size).to(corners.device)

    def refine_on_patches(self, images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
        """Saddle refinement of whole boards :math:`(S, N, 2)` on ``images`` :math:`(S, 1, H, W)`, one small patch per
        corner (:func:`~ccs_kornia.modules.detection.refine.patch_refine.refine_on_patches` with this pipeline's refiner)."""
        r = self.refiner
        with stage("saddle refinement"):
            return refine_on_patches(images.float(), corners.float(), board_size, r.radius_factor, r.max_radius, r.method,
                                     r.iterations, r.smooth_sigma, r.normalize_sigma).to(corners.dtype)

