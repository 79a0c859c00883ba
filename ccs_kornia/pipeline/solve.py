"""The solver stage of :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` (paper Sec. III-C) on its detections.

Per image size, one batched solve over the cameras; with a :class:`~ccs_kornia.modules.calibration.model_selection.ModelChoice`
every candidate model solves every camera and :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection` picks one per camera; where the
image evidence asked for the lens correction, the corrected-frame calibration then competes with the usual one.
Kept apart from ``pipeline/calibration_pipeline.py`` so that file stays the composition; the functions take the pipeline's solvers and
solver options as one value (:class:`Solving`) and the detections as the solver sees them, built once per solve
(:class:`~ccs_kornia.pipeline.solver_input.SolverInput`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import torch

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import RATIONAL
from ccs_kornia.modules.calibration import corrected_frame
from ccs_kornia.modules.calibration.board_flatness import choose_board_warp
from ccs_kornia.modules.calibration.model_selection import ModelChoice, ModelSelection
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.splined_choice import choose_splined, splined_cameras
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.modules.detection.boards import CircleGrid, grid_object_points
from ccs_kornia.modules.detection.circles.centre_bias import centre_bias
from ccs_kornia.pipeline.result import (
    PipelineResult,
    camera_reason,
    concat_results,
    positive_size,
    scatter_cameras,
    select_result,
)
from ccs_kornia.pipeline.solver_input import SolverInput
from ccs_kornia.pipeline.workers import worker_pool, workers_on

__all__ = ["CENTRE_ROUNDS", "Solving", "diagnose_cameras", "diagnose_solved", "judge_flatness", "solve_detections", "solve_group"]

#: solves that correct a circle grid's centres with the camera and poses of the solve before (after the first, on the
#: measured centres): the correction's change in the second is far below the detector's noise (docs/detection.md)
CENTRE_ROUNDS = 2


@dataclass(frozen=True)
class Solving:
    """The solver stage's settings: the pipeline's solvers and options (see
    :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline`, which makes one with its ``solving`` property).

    Attributes:
        model: the model, or a :class:`~ccs_kornia.modules.calibration.model_selection.ModelChoice`.
        solvers: a :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` per model (a choice: every
            candidate).
        solver: the solver of ``model`` (a choice: the stage alone's).
        selection: the :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection` of a choice.
        weigh_corners: weight the refinements by the corners' precision.
        workers: processes solving the candidate models at once on CPU.
        joint_iters, free_distortion_centre, max_rms_ratio: of the corrected-frame calibration.
        board: the detector's board description (:mod:`~ccs_kornia.modules.detection.boards`; ``None``: a
            chessboard), whose object points the solves take (an AprilGrid's corners are not evenly spaced).
        board_flatness: judge the board's sag after the last solve (:func:`judge_flatness`).
    """

    model: CameraModel | ModelChoice
    solvers: Mapping[CameraModel, CalibrationSolver]
    solver: CalibrationSolver
    selection: ModelSelection | None
    weigh_corners: bool
    workers: int
    joint_iters: int
    free_distortion_centre: bool
    max_rms_ratio: float
    board: Any = None
    board_flatness: bool = False

    def object_points(self, board_size: tuple[int, int], square: float,
                      device: torch.device | str | None = None) -> torch.Tensor:
        """:math:`(N, 3)` float64 the board's points every solve takes
        (:func:`~ccs_kornia.modules.detection.boards.grid_object_points`: an AprilGrid's uneven grid, else the even
        one)."""
        return grid_object_points(self.board, board_size, float(square), device=device, dtype=torch.float64)

    def inputs(self, out: PipelineResult, board_size: tuple[int, int], square: float) -> SolverInput:
        """The solver's input of ``out``'s detections, weighted where the pipeline weighs corners
        (:meth:`~ccs_kornia.pipeline.solver_input.SolverInput.from_result`)."""
        obj = self.object_points(board_size, square, out.detections.corners.device)
        return SolverInput.from_result(out, obj, self.weigh_corners)


def _merge(parts: list[CalibrationResult], order: list[torch.Tensor], count: int) -> CalibrationResult:
    """Parts over disjoint camera indices back in camera order."""
    device = order[0].device
    inverse = torch.empty(count, dtype=torch.long, device=device)
    inverse[torch.cat(order)] = torch.arange(count, device=device)
    return select_result(concat_results(parts), inverse)


def solve_detections(solving: Solving, out: PipelineResult, board_size: tuple[int, int], square: float,
                     keep_models: bool = False) -> tuple[PipelineResult, SubsetSolutions]:
    """:meth:`CalibrationPipeline.solve <ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.solve>`: the
    solve of :func:`_solve_once`; for a circle grid (:class:`~ccs_kornia.modules.detection.boards.CircleGrid`) solved
    :data:`CENTRE_ROUNDS` times more, each on the measured centres less their offset under the camera and poses of the
    solve before (:func:`~ccs_kornia.modules.detection.circles.centre_bias.centre_bias`); the result's
    ``centre_bias`` holds the offset its corners are corrected by."""
    if not isinstance(solving.board, CircleGrid):
        return _solve_once(solving, out, board_size, square, keep_models)
    det = out.detections
    measured = det.corners if out.centre_bias is None else det.corners + out.centre_bias
    base = replace(out, detections=replace(det, corners=measured), centre_bias=None)
    solved, subsets = _solve_once(solving, base, board_size, square, keep_models)
    for _ in range(CENTRE_ROUNDS):
        bias = _circle_bias(solving.board, solved, board_size, square)
        again = replace(base, detections=replace(base.detections, corners=measured - bias), centre_bias=bias)
        solved, subsets = _solve_once(solving, again, board_size, square, keep_models)
    return solved, subsets


def _circle_bias(board: CircleGrid, out: PipelineResult, board_size: tuple[int, int], square: float) -> torch.Tensor:
    """:math:`(C, V, N, 2)` each dot's centre offset under ``out``'s solved cameras and poses (zero where a camera or
    view was not solved)."""
    corners = out.detections.corners
    bias = torch.zeros_like(corners, dtype=torch.float64)
    cal = out.calibration
    obj = grid_object_points(board, board_size, square, dtype=torch.float64)
    radii = board.dot_diameters() / 2
    for c in cal.success.nonzero().flatten().tolist():
        b = centre_bias(cal.camera[c].to("cpu"), cal.rvec[c].cpu(), cal.tvec[c].cpu(), obj, radii)
        bias[c] = torch.where(b.isfinite() & cal.used[c].cpu()[:, None, None], b, 0.0).to(bias.device)
    return bias.to(corners.dtype)


def _solve_once(solving: Solving, out: PipelineResult, board_size: tuple[int, int], square: float,
                keep_models: bool = False) -> tuple[PipelineResult, SubsetSolutions]:
    """:meth:`CalibrationPipeline.solve <ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.solve>`:
    ``out`` with ``calibration``, ``corrected``, ``correction``, ``camera_reasons`` and ``model_selection``, and the
    model selection's cross-validations (for :func:`diagnose_solved`).

    With ``keep_models`` (a model choice, after a first solve), each camera is solved again with the model chosen
    in ``out.model_selection`` instead of choosing again: the solve after the second look, whose few recovered views
    would cost a whole cross-validation of every model (a tenth of a run, ``docs/benchmarks.md``, section 5) to
    confirm the choice that sent the camera to the look. The tables say on how many views the choice was made."""
    if not square > 0:
        raise ValueError(f"square must be positive, got {square}.")
    det = out.detections
    c = det.found.shape[0]
    device = det.corners.device
    sizes = out.image_size
    inputs = solving.inputs(out, board_size, square)
    usable = inputs.usable
    parts, order = [], []
    corrected = torch.zeros(c, dtype=torch.bool, device=device)
    correction = out.correction
    selection: list[dict | None] = [None] * c
    choice = isinstance(solving.model, ModelChoice)
    previous = out.model_selection if keep_models and choice else None
    # the model selection's cross-validations, kept for the diagnostics of the same calibrations (diagnose_solved)
    subsets = SubsetSolutions()
    for size in dict.fromkeys(sizes):
        sel = torch.tensor([s == size for s in sizes], device=device).nonzero().flatten()
        tried = None if out.correction_tried is None else out.correction_tried[sel]
        # the model chosen before: the camera's (a camera no model calibrated has none)
        models = None if previous is None else [out.calibration.camera.models[ci] if (previous[ci] or {}).get("chosen")
                                                else None for ci in sel.tolist()]
        calib, refined, applied, table = solve_group(
            solving, inputs.cameras(sel), board_size, square, positive_size(size),
            None if correction is None else correction[sel], tried, models, subsets)
        if table is None and previous is not None:  # the choice of the first solve, and the views it saw
            table = [_chosen_before(previous[ci], int(usable[ci].sum())) for ci in sel.tolist()]
        if applied is not None:
            corrected[sel] = applied
            correction = correction.clone()
            correction[sel] = refined
        for k, ci in enumerate(sel.tolist()):
            selection[ci] = None if table is None else table[k]
        parts.append(calib)
        order.append(sel)
    calibration = _merge(parts, order, c)
    reasons = [camera_reason(calibration, ci, int(usable[ci].sum()), int(out.present[ci].sum())) for ci in range(c)]
    return replace(out, calibration=calibration, correction=correction,
                   corrected=corrected if correction is not None else None,
                   model_selection=selection if choice else None, camera_reasons=reasons), subsets


def diagnose_solved(solving: Solving, out: PipelineResult, board_size: tuple[int, int], square: float,
                    subsets: SubsetSolutions | None = None) -> PipelineResult:
    """``out``, a result :func:`solve_detections` solved, with its ``diagnostics`` (``subsets``: that solve's
    cross-validations, reused where the inputs are the same)."""
    inputs = solving.inputs(out, board_size, square)
    return replace(out, diagnostics=diagnose_cameras(solving.solvers, out, inputs, subsets))


def diagnose_cameras(solvers: Mapping[CameraModel, torch.nn.Module], out: PipelineResult, inputs: SolverInput,
                     solutions: SubsetSolutions | None = None) -> list[dict | None]:
    """Quality figures and verdict of each camera of a solved ``out`` (one
    :func:`~ccs_kornia.modules.calibration.quality.diagnostics.diagnose` call per image size and model; ``None`` for
    a camera without a computed calibration; the model choice's runner-up in the verdict where there was one). The halves and folds of the cross-validation are solved by
    ``solvers[model]`` (the usual path: a camera calibrated in the corrected frame is cross-validated without it) on
    the solve's ``inputs`` (its views, corners and weights); ``solutions``: the model selection's solved
    cross-validation subsets (:class:`~ccs_kornia.modules.calibration.subset_solutions.SubsetSolutions`), used where
    the inputs are the same."""
    from ccs_kornia.modules.calibration.quality.diagnostics import diagnose

    cal = out.calibration
    count = inputs.usable.shape[0]
    device = inputs.usable.device
    diagnostics: list[dict | None] = [None] * count
    models = cal.camera.models
    for size, model in dict.fromkeys(zip(out.image_size, models)):
        sel = torch.tensor([s == size and m == model for s, m in zip(out.image_size, models)], device=device)
        sel = (sel & cal.success.to(device)).nonzero().flatten()
        if sel.numel() == 0:
            continue
        part = inputs.cameras(sel)
        runner_up = [_runner_up(out.model_selection, ci) for ci in sel.tolist()]
        with torch.inference_mode():
            figures = diagnose(select_result(cal, sel), part.corners, part.valid, part.object_points,
                               positive_size(size), solver=solvers[model] if model in solvers else
                               CalibrationSolver(model=model), weights=part.weights, solutions=solutions,
                               runner_up=runner_up)
        for k, ci in enumerate(sel.tolist()):
            diagnostics[ci] = figures[k]
    return diagnostics


def _runner_up(tables, camera: int) -> dict | None:
    """The model choice's runner-up of ``camera`` as the verdict takes it (``None``: no choice, or no runner-up)."""
    table = tables if isinstance(tables, dict) or tables is None else tables[camera]
    name = None if table is None else table.get("runner_up")
    if name is None:
        return None
    return {"model": name, "halves_rms_px": table["halves_rms_px"].get(name),
            "tied": name in table.get("tied", [])}


def judge_flatness(solving: Solving, out: PipelineResult, board_size: tuple[int, int], square: float) -> PipelineResult:
    """``out`` with each camera's board sag judged
    (:func:`~ccs_kornia.modules.calibration.board_flatness.choose_board_warp`, one call per image size and model):
    ``calibration`` the sag's where held-out views say it helps (``board_warp`` and ``std_board_warp`` filled for
    every camera: 0 and NaN where the board stays flat) and ``board_flatness`` the figures (``None`` for a camera
    not judged: not calibrated, splined, or calibrated in the corrected frame)."""
    cal = out.calibration
    if cal is None:
        return out
    inputs = solving.inputs(out, board_size, square)
    count = inputs.usable.shape[0]
    device = inputs.usable.device
    records: list[dict | None] = [None] * count
    dtype = cal.rvec.dtype
    merged = replace(cal, board_warp=torch.zeros(count, 2, dtype=dtype, device=cal.rvec.device),
                     std_board_warp=torch.full((count, 2), float("nan"), dtype=dtype, device=cal.rvec.device))
    corrected = out.corrected if out.corrected is not None else torch.zeros(count, dtype=torch.bool)
    models = cal.camera.models
    for size, model in dict.fromkeys(zip(out.image_size, models)):
        if model.local_support:  # (a splined camera keeps the board its start had)
            continue
        sel = torch.tensor([s == size and m == model for s, m in zip(out.image_size, models)], device=device)
        sel = (sel & cal.success.to(device) & ~corrected.to(device)).nonzero().flatten()
        if sel.numel() == 0:
            continue
        part = inputs.cameras(sel)
        choice = choose_board_warp(solving.solvers[model], select_result(cal, sel), part.corners, part.valid,
                                   part.object_points, positive_size(size), part.weights)
        merged = scatter_cameras(choice.result, sel, merged)
        for k, ci in enumerate(sel.tolist()):
            records[ci] = choice.record(k)
    return replace(out, calibration=merged, board_flatness=records)


def _chosen_before(table: dict | None, views: int) -> dict | None:
    """A model-selection table of a first solve (its ``views``: those the choice saw), noting that the second look
    changed the views (recovered missed ones, or re-detected rejected ones) and how many the calibration uses."""
    if table is None:
        return None
    return {**table, "note": f"chosen on the {table.get('views')} views of the first solve, before the second look "
                             f"on the calibrated lens; the final calibration uses {views}"}


def solve_group(solving: Solving, inputs: SolverInput, board_size: tuple[int, int], square: float,
                image_size: tuple[int, int], correction: torch.Tensor | None, tried: torch.Tensor | None,
                models: list[CameraModel | None] | None = None, subsets: SubsetSolutions | None = None):
    """Cameras of one image size: ``(calibration, correction, applied, model_selection)`` (the last two ``None``
    without a correction / without a model choice). ``inputs``: the cameras' solver input
    (:class:`~ccs_kornia.pipeline.solver_input.SolverInput`). ``models`` (a model choice only): a model per camera to
    solve with instead of choosing (the table is then ``None``; a camera without one gets the first candidate).
    ``subsets``: where the model selection keeps its cross-validations. ``board_size``: checked ``(cols, rows)`` (the
    pipeline's edge); with ``square``, the board of the corrected-frame calibration."""
    device = inputs.corners.device
    if not isinstance(solving.model, ModelChoice):
        with torch.inference_mode():
            usual = inputs.solve(solving.solver, image_size)
        return (*_compete(solving, solving.solver, usual, inputs, board_size, square, image_size, correction, tried),
                None)
    if models is None:
        with torch.inference_mode():
            results, chosen, table = inputs.solve(
                solving.selection, image_size,
                map_models=_map_in_workers(workers_on(device, solving.workers)), solutions=subsets)
        fallback = next(iter(results))  # cameras no model calibrated keep that model's (failed) result
        names = [n or fallback for n in chosen]
        splined = _splined_choice(solving, results, names, inputs, image_size, table)
    else:
        names, table = [n or next(iter(solving.solvers)) for n in models], None
        # each chosen model solves every camera of the group, as in the selection: the solver's RANSAC draws depend on
        # the batch, and a camera must get the calibration its choice was made on (docs/measurements.md)
        with torch.inference_mode():
            results = {name: inputs.solve(solver_for(solving, name), image_size) for name in dict.fromkeys(names)}
        splined = {}
    parts, order = [], []
    count = inputs.usable.shape[0]
    applied = None if correction is None else torch.zeros(count, dtype=torch.bool, device=device)
    for ci, res in splined.items():  # the cameras auto calibrated splined: as they are (no corrected frame)
        parts.append(res)
        order.append(torch.tensor([ci], device=device))
    names = [None if ci in splined else n for ci, n in enumerate(names)]
    for name in dict.fromkeys(n for n in names if n is not None):
        sel = torch.tensor([n == name for n in names], device=device).nonzero().flatten()
        calib, refined, kept = _compete(
            solving, solver_for(solving, name), select_result(results[name], sel), inputs.cameras(sel), board_size, square,
            image_size, None if correction is None else correction[sel], None if tried is None else tried[sel],
        )
        if correction is not None:
            correction = correction.clone()
            correction[sel] = refined
            applied[sel] = kept
        parts.append(calib)
        order.append(sel)
    return _merge(parts, order, count), correction, applied, table


def solver_for(solving: Solving, model: CameraModel) -> CalibrationSolver:
    """The pipeline's solver of ``model``; a splined model (which ``--model auto`` may choose, its grid from the data)
    gets one of its own, with the options of the pipeline's solvers."""
    if model in solving.solvers:
        return solving.solvers[model]
    base = solving.solvers.get(RATIONAL, solving.solver)
    return CalibrationSolver(model=model, use_ransac=base.use_ransac, seed=base.ransac.seed,
                             fix_aspect_ratio=base.fix_aspect_ratio, fix_principal_point=base.fix_principal_point,
                             min_corners=base.min_corners, min_views=base.min_views, max_iters=base.max_iters)


def _splined_choice(solving: Solving, results: dict, names: list, inputs: SolverInput, image_size: tuple[int, int],
                    table: list[dict]) -> dict[int, CalibrationResult]:
    """``--model auto``'s splined model where held-out views prefer it to the chosen one
    (:func:`~ccs_kornia.modules.calibration.splined_choice.choose_splined`), ``--model splined``'s on every calibrated
    camera (:func:`~ccs_kornia.modules.calibration.splined_choice.splined_cameras`): per camera index the splined
    result kept; each camera's table gets the figures (``splined``) and, where kept, the spline as ``chosen``."""
    kept: dict[int, CalibrationResult] = {}
    device = inputs.corners.device
    for name in dict.fromkeys(names):
        sel = torch.tensor([n == name for n in names], device=device).nonzero().flatten()
        part = inputs.cameras(sel)
        with torch.inference_mode():
            if solving.model.splined:
                spline, records = splined_cameras(select_result(results[name], sel), part.corners, part.valid,
                                                  part.object_points, image_size, part.weights)
            else:
                spline, records = choose_splined(solving.solvers[name], select_result(results[name], sel),
                                                 part.corners, part.valid, part.object_points, image_size,
                                                 part.weights)
        for k, ci in enumerate(sel.tolist()):
            if records[k] is not None:
                table[ci]["splined"] = records[k]
            if spline[k] is not None:
                kept[ci] = spline[k]
                table[ci]["chosen"], table[ci]["runner_up"] = str(spline[k].camera.model), table[ci]["chosen"]
    return kept


def _compete(solving: Solving, solver: CalibrationSolver, usual: CalibrationResult, inputs: SolverInput, board_size,
             square, image_size, correction, tried):
    """Where the evidence asked for it, the corrected-frame calibration against the usual one (kept where it fits
    the observed corners clearly better); returns ``(calibration, correction, applied)``."""
    # (the corrected frame's radial model is a pinhole lens's: not for fisheye cameras)
    if correction is None or tried is None or not bool(tried.any()) or solver.model.is_fisheye:
        return usual, correction, None if correction is None or tried is None else torch.zeros_like(tried)
    # only the cameras the evidence points to, and only those the usual solve could calibrate, go the corrected
    # way (a camera refused as degenerate stays refused)
    sel = (tried.to(usual.success.device) & usual.success).nonzero().flatten()
    applied = torch.zeros_like(tried)
    if sel.numel() == 0:
        return usual, correction, applied
    corners, found = inputs.corners, inputs.usable
    calib, refined, kept = corrected_frame.solve_with_correction(
        solver, select_result(usual, sel), corners[sel], found[sel], correction[sel],
        torch.ones(sel.numel(), dtype=torch.bool, device=corners.device), board_size, square, image_size,
        joint_iters=solving.joint_iters, free_distortion_centre=solving.free_distortion_centre,
        max_rms_ratio=solving.max_rms_ratio,
    )
    keep = torch.zeros_like(usual.success)
    keep[sel] = kept.to(keep.device)
    merged = corrected_frame.select_cameras(keep, scatter_cameras(calib, sel, usual), usual)
    correction = correction.clone()
    correction[sel] = refined.to(correction)
    applied[sel] = kept.to(applied.device)
    return merged, correction, applied


def _map_in_workers(workers: int):
    """``map_models`` of :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection`: the models solved
    by forked worker processes, one thread each (the solver of a few cameras runs on one thread anyway)."""
    def map_models(fn, items: list) -> list:
        with worker_pool(fn, min(workers, len(items))) as run:
            return list(run(items))

    return map_models
