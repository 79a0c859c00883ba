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
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import replace
from typing import Callable

import torch
from torch import nn

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.calibration.model_selection import ModelChoice, ModelSelection
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.modules.correction.distortion_net import load_distortion_net
from ccs_kornia.modules.correction.pooling import correction_is_large, pool_corrections
from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    measured_corners,
)
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_sigma
from ccs_kornia.modules.detection.refine.patch_refine import refine_boards
from ccs_kornia.modules.detection.refine.saddle_refine import CornerRefiner
from ccs_kornia.modules.detection.warps.warped_detection import detect_images
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
from ccs_kornia.pipeline.settings import PipelineSettings
from ccs_kornia.pipeline.solve import (
    Solving,
    diagnose_solved,
    judge_flatness,
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
from ccs_kornia.pipeline.workers import map_batches, workers_on
from ccs_kornia.runtime.checks import check_board_size, check_tensor
from ccs_kornia.runtime.timing import stage

__all__ = ["PipelineResult", "CalibrationPipeline"]


class CalibrationPipeline(nn.Module):
    """Detect chessboard corners and calibrate the camera(s): correct -> detect -> solve (:meth:`run`).

    The keyword arguments are the pipeline's settings, made once into one checked value
    (:class:`~ccs_kornia.pipeline.settings.PipelineSettings`, :attr:`settings`; each option is described there); the
    detector and the distortion network are its components. Its solver stage and its looks' detection tools are
    values made from them once (:attr:`solving`, :attr:`tools`).

    Args:
        detector: a detector name for :func:`~ccs_kornia.modules.detection.factory.make_detector`
            (``"opencv"`` or ``"learned"``) or a :class:`ChessboardDetector` instance.
        distortion_correction: ``True`` (the shipped network), ``False`` (off), a weight-file path or a
            ``DistortionNet``.
        model, use_ransac, seed, detection_batch_size, workers, max_batch_pixels, max_detection_side,
        min_correction, max_rms_ratio, joint_iters, free_distortion_centre, diagnostics, weigh_corners,
        differentiable, frame_selection: the :class:`~ccs_kornia.pipeline.settings.PipelineSettings` of the same
            names (``differentiable``: :meth:`forward`, :meth:`detect` and :meth:`calibrate` return corners and
            cameras with gradients, ``docs/gradients.md``).
        looks: the looks after the first, in order (default :data:`~ccs_kornia.pipeline.looks.LOOKS`).
        calibrated_look: keep the calibrated look among ``looks``
            (:data:`~ccs_kornia.pipeline.looks.CALIBRATED`: views missed on the originals of a camera calibrated with
            a fisheye model looked for again on virtual pinhole views of the calibrated lens, and the camera solved
            again with them).
        solver_kwargs: further options of :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`
            (``PipelineSettings.solver_options``).

    Example:
        >>> from ccs_kornia.data.scenes.scenes import make_calibration_set
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
        model: CameraModel | ModelChoice = OPENCV5,
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
        frame_selection: FrameSelection | None = None,
        board_flatness: bool = False,
        **solver_kwargs,
    ) -> None:
        super().__init__()
        self.detector = make_detector(detector) if isinstance(detector, str) else detector
        if not isinstance(self.detector, ChessboardDetector):
            raise ValueError(f"detector must be a name or a ChessboardDetector, got {type(detector).__name__}.")
        looks = tuple(look for look in (LOOKS if looks is None else looks) if calibrated_look or look is not CALIBRATED)
        #: the options, checked once (:class:`~ccs_kornia.pipeline.settings.PipelineSettings`)
        self.settings = settings = PipelineSettings(
            model=model, use_ransac=use_ransac, seed=seed, solver_options=solver_kwargs,
            detection_batch_size=detection_batch_size, workers=workers, max_batch_pixels=max_batch_pixels,
            max_detection_side=max_detection_side, min_correction=min_correction, max_rms_ratio=max_rms_ratio,
            joint_iters=joint_iters, free_distortion_centre=free_distortion_centre, diagnostics=diagnostics,
            looks=looks,
            weigh_corners=weigh_corners, differentiable=differentiable, frame_selection=frame_selection,
            board_flatness=board_flatness,
        )
        choice = isinstance(model, ModelChoice)
        models = model.candidates if choice else (model,)
        self.solver_list = nn.ModuleList([CalibrationSolver(model=m, use_ransac=use_ransac, seed=seed,
                                                            **settings.solver_options) for m in models])
        #: the solver of each model
        self.solvers = {s.model: s for s in self.solver_list}
        # the stage alone's (a choice: its first candidate)
        self.solver = self.solvers[model.first if choice else model]
        self.selection = ModelSelection(list(self.solver_list)) if choice else None
        self.refiner = CornerRefiner()
        # (a detector whose boards the network never saw runs without it)
        self.distortion_net = load_distortion_net(distortion_correction if self.detector.lens_correction else False)
        #: the solver stage's settings and solvers (:class:`~ccs_kornia.pipeline.solve.Solving`)
        self.solving = Solving(settings.model, self.solvers, self.solver, self.selection, settings.weigh_corners,
                               settings.workers, settings.joint_iters, settings.free_distortion_centre,
                               settings.max_rms_ratio, self.detector.board, settings.board_flatness)
        #: what the looks detect with (:class:`~ccs_kornia.pipeline.looks.Tools`): the detector on the images as they
        #: are or through a downscaled copy, the saddle refinement on patches, the corners' precision where weighed
        measure = corner_sigma if settings.weigh_corners else None
        refine = functools.partial(refine_boards, refiner=self.refiner)
        detect = functools.partial(detect_images, detector=self.detector, max_side=settings.max_detection_side,
                                   refine=refine, measure=measure)
        self.tools = Tools(detect, refine, measure, self.detector, settings.workers)

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
        if self.settings.differentiable:
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
        image as it is), the corrections are pooled per camera; each of the settings' looks runs on the views still
        missed, the cameras solved before a look that needs them; a final solve where a look found boards since, then
        the diagnostics.

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
        # a source that gives its views' detections (a corners file) is the first look; the looks after it have no
        # images to look at
        given = None if first is not None or source is None else source.given_detections(board, module_device(self))
        images = None if given is not None else source
        for look in (FIRST, *self.settings.looks):
            if look is FIRST:
                out = given if out is None else out
                out = self.detect_views(source, board, progress, on_batch=on_batch) if out is None else out
                if self.distortion_net is None:
                    out = out if out.correction is None else replace(out, correction=None)
                elif out.view_corrections is not None:
                    with stage("correction evidence"):
                        out = self._pool(out)
                elif out.correction is not None and out.correction_tried is None:
                    out = self._judge(out)  # a correction given with the detections
                pooled = out.correction is not None
                continue
            if look.needs_correction and not pooled or look.needs_camera and not calibrate:
                continue
            if look.needs_camera and (changed or not solved):
                (out, subsets), solved, changed = self._solve(out, board, square, again=solved), True, False
            out, found = self._look(look, images, out, board)
            changed = found or changed
        if calibrate and (changed or not solved):
            out, subsets = self._solve(out, board, square, again=solved)
        selection = self.settings.frame_selection
        if calibrate and selection is not None:
            with stage("frame selection"):
                out, subsets = select_views(self.solving, out, board, square, selection, source)
        if calibrate and self.settings.board_flatness:
            with stage("solver"):
                out = judge_flatness(self.solving, out, board, square)
        if calibrate and self.settings.diagnostics:
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
        settings = self.settings
        sigma = None
        if settings.weigh_corners:
            sigma = torch.full((c, v, n), float("nan"), dtype=torch.float32, device=device)
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
                                 settings.detection_batch_size, settings.max_batch_pixels,
                                 workers_on(device, settings.workers)):
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
        pooled per camera, then the settings' looks in turn, each on the views missed
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
            settings = self.settings
            for batch in map_batches(functools.partial(look.run, self.tools, out, board_size=board), source, keys,
                                     settings.detection_batch_size, settings.max_batch_pixels,
                                     workers_on(device, settings.workers) if look.in_workers else 1) if keys else ():
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
            correction[sel], large[sel] = pool_corrections(per_view[sel], positive_size(size),
                                                           self.settings.min_correction, mask)
        # every camera with a large correction goes to the corrected frame, where the observed corners referee it
        # against the usual calibration; a gate on the network's correction straightening the boards (or on the
        # usual model's misfit) kept held-out cameras from it that needed it (docs/benchmarks.md, section 4)
        return replace(out, correction=correction, correction_tried=large)

    def _judge(self, out: PipelineResult) -> PipelineResult:
        """``out`` with ``correction_tried``: where its given correction is large (as :meth:`_pool` judges the pooled
        one)."""
        correction = out.correction
        large = torch.zeros(correction.shape[0], dtype=torch.bool, device=correction.device)
        for size in set(out.image_size):
            sel = torch.tensor([s == size for s in out.image_size], device=correction.device).nonzero().flatten()
            large[sel] = correction_is_large(correction[sel], positive_size(size), self.settings.min_correction)
        return replace(out, correction_tried=large)

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
        if self.settings.board_flatness:
            out = judge_flatness(self.solving, out, board, square)
        return diagnose_solved(self.solving, out, board, square, subsets) if self.settings.diagnostics else out

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
        if self.settings.differentiable:
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
        check_tensor(corners, "corners", ["V", "N", "2"], ["C", "V", "N", "2"], what=f"for a {cols}x{rows} board",
                     N=cols * rows)
        if valid.shape == corners.shape[:-2]:
            valid = measured_corners(corners, valid)
        check_tensor(valid, "valid", corners.shape[:-1])
        if not square > 0:
            raise ValueError(f"square must be positive, got {square}.")
        size = (int(image_size[0]), int(image_size[1]))
        if sigma is not None:
            check_tensor(sigma, "sigma", corners.shape[:-1])
        solving = self.solving
        object_points = solving.object_points(board, square, corners.device)
        sigma = sigma if solving.weigh_corners else None
        if (correction is not None and correction_tried is not None) or isinstance(self.settings.model, ModelChoice):
            single = corners.dim() == 3
            batch = (lambda x: None if x is None else x[None]) if single else (lambda x: x)
            # as the run solves: the measured corners of the views with any valid corner
            inputs = SolverInput.from_views(batch(corners).double(), batch(valid).any(-1), object_points, batch(sigma))
            calib = solve_group(solving, inputs, board, square, size,
                                None if correction is None else batch(correction).double(),
                                None if correction_tried is None else batch(torch.as_tensor(correction_tried)))[0]
            return select_result(calib, 0) if single else calib
        inputs = SolverInput.from_corners(corners, valid, object_points, sigma)
        with nullcontext() if self.settings.differentiable else torch.inference_mode():
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
