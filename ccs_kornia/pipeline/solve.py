"""The solver stage of :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` (paper Sec. III-C) on its detections.

Per image size, one batched solve over the cameras; with ``model="auto"`` every candidate model solves every
camera and :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection` picks one per camera; where the
image evidence asked for the lens correction, the corrected-frame calibration then competes with the usual one.
Kept apart from ``pipeline/calibration_pipeline.py`` so that file stays the composition; the functions take the pipeline's solvers and
solver options as one value (:class:`Solving`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Mapping

import torch

from ccs_kornia.modules.calibration import corrected_frame
from ccs_kornia.modules.calibration.model_selection import ModelSelection
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.modules.detection.base import measured_corners
from ccs_kornia.modules.detection.boards import grid_object_points
from ccs_kornia.pipeline.result import (
    PipelineResult,
    camera_reason,
    concat_results,
    corner_weights_of,
    diagnose_cameras,
    positive_size,
    same_size_views,
    scatter_cameras,
    select_result,
)
from ccs_kornia.pipeline.workers import worker_pool, workers_on

__all__ = ["Solving", "diagnose_solved", "solve_detections", "solve_group"]


@dataclass(frozen=True)
class Solving:
    """The solver stage's settings: the pipeline's solvers and options (see
    :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline`, which makes one with its ``solving`` property).

    Attributes:
        model: the model name, or ``"auto"``.
        solvers: a :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` per model (``model="auto"``:
            every candidate).
        solver: the solver of ``model`` (``"auto"``: the stage alone's).
        selection: the :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection` of ``model="auto"``.
        weigh_corners: weight the refinements by the corners' precision.
        workers: processes solving the candidate models at once on CPU.
        joint_iters, free_distortion_centre, max_rms_ratio: of the corrected-frame calibration.
        board: the detector's board description (:mod:`~ccs_kornia.modules.detection.boards`; ``None``: a
            chessboard), whose object points the solves take (an AprilGrid's corners are not evenly spaced).
    """

    model: str
    solvers: Mapping[str, CalibrationSolver]
    solver: CalibrationSolver
    selection: ModelSelection | None
    weigh_corners: bool
    workers: int
    joint_iters: int
    free_distortion_centre: bool
    max_rms_ratio: float
    board: Any = None


def _merge(parts: list[CalibrationResult], order: list[torch.Tensor], count: int) -> CalibrationResult:
    """Parts over disjoint camera indices back in camera order."""
    device = order[0].device
    inverse = torch.empty(count, dtype=torch.long, device=device)
    inverse[torch.cat(order)] = torch.arange(count, device=device)
    return select_result(concat_results(parts), inverse)


def solve_detections(solving: Solving, out: PipelineResult, board_size: tuple[int, int], square: float,
                     keep_models: bool = False) -> tuple[PipelineResult, SubsetSolutions]:
    """:meth:`CalibrationPipeline.solve <ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.solve>`:
    ``out`` with ``calibration``, ``corrected``, ``correction``, ``camera_reasons`` and ``model_selection``, and the
    model selection's cross-validations (for :func:`diagnose_solved`).

    With ``keep_models`` (``model="auto"``, after a first solve), each camera is solved again with the model chosen
    in ``out.model_selection`` instead of choosing again: the solve after the second look, whose few recovered views
    would cost a whole cross-validation of every model (a tenth of a run, ``docs/benchmarks.md``, section 5) to
    confirm the choice that sent the camera to the look. The tables say on how many views the choice was made."""
    if not square > 0:
        raise ValueError(f"square must be positive, got {square}.")
    det = out.detections
    c = det.found.shape[0]
    device = det.corners.device
    sizes = out.image_size
    usable = det.found & same_size_views(out)
    parts, order = [], []
    corrected = torch.zeros(c, dtype=torch.bool, device=device)
    correction = out.correction
    selection: list[dict | None] = [None] * c
    previous = out.model_selection if keep_models and solving.model == "auto" else None
    # the model selection's cross-validations, kept for the diagnostics of the same calibrations (diagnose_solved)
    subsets = SubsetSolutions()
    for size in dict.fromkeys(sizes):
        sel = torch.tensor([s == size for s in sizes], device=device).nonzero().flatten()
        tried = None if out.correction_tried is None else out.correction_tried[sel]
        models = None if previous is None else [(previous[ci] or {}).get("chosen") for ci in sel.tolist()]
        calib, refined, applied, table = solve_group(
            solving, det.corners[sel], usable[sel], board_size, square, positive_size(size),
            None if correction is None else correction[sel], tried, None if det.sigma is None else det.sigma[sel],
            models, subsets)
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
                   model_selection=selection if solving.model == "auto" else None, camera_reasons=reasons), subsets


def diagnose_solved(solving: Solving, out: PipelineResult, board_size: tuple[int, int], square: float,
                    subsets: SubsetSolutions | None = None) -> PipelineResult:
    """``out``, a result :func:`solve_detections` solved, with its ``diagnostics`` (``subsets``: that solve's
    cross-validations, reused where the inputs are the same)."""
    usable = out.detections.found & same_size_views(out)
    return replace(out, diagnostics=diagnose_cameras(solving.solvers, out, usable, board_size, square,
                                                     solving.weigh_corners, subsets, board=solving.board))


def _chosen_before(table: dict | None, views: int) -> dict | None:
    """A model-selection table of a first solve (its ``views``: those the choice saw), noting that the second look
    changed the views (recovered missed ones, or re-detected rejected ones) and how many the calibration uses."""
    if table is None:
        return None
    return {**table, "note": f"chosen on the {table.get('views')} views of the first solve, before the second look "
                             f"on the calibrated lens; the final calibration uses {views}"}


def solve_group(solving: Solving, corners: torch.Tensor, found: torch.Tensor, board_size: tuple[int, int],
                square: float, image_size: tuple[int, int], correction: torch.Tensor | None, tried: torch.Tensor | None,
                sigma: torch.Tensor | None = None, models: list[str | None] | None = None,
                subsets: SubsetSolutions | None = None):
    """Cameras of one image size: ``(calibration, correction, applied, model_selection)`` (the last two ``None``
    without a correction / without ``model="auto"``). ``sigma``: the corners'
    :math:`(C, V, N)` precision, weighting the solves where the pipeline weighs corners. ``models``
    (``model="auto"`` only): a model name per camera to solve with instead of choosing (the table is then ``None``;
    a camera without a name gets the first candidate). ``subsets``: where the model selection keeps its
    cross-validations. ``board_size``: checked ``(cols, rows)`` (the pipeline's edge)."""
    obj = grid_object_points(solving.board, board_size, float(square), device=corners.device, dtype=torch.float64)
    valid = measured_corners(corners, found)
    weights = corner_weights_of(sigma, valid) if solving.weigh_corners else None
    if solving.model != "auto":
        with torch.inference_mode():
            usual = solving.solver(corners.to(torch.float64), valid, obj, image_size, weights=weights)
        return (*_compete(solving, solving.solver, usual, corners, found, board_size, square, image_size, correction, tried),
                None)
    if models is None:
        with torch.inference_mode():
            results, chosen, table = solving.selection(
                corners.to(torch.float64), valid, obj, image_size, weights=weights,
                map_models=_map_in_workers(workers_on(corners.device, solving.workers)), solutions=subsets)
        fallback = next(iter(results))  # cameras no model calibrated keep that model's (failed) result
        names = [n or fallback for n in chosen]
    else:
        names, table = [n or next(iter(solving.solvers)) for n in models], None
        # each chosen model solves every camera of the group, as in the selection: the solver's RANSAC draws depend on
        # the batch, and a camera must get the calibration its choice was made on (docs/measurements.md)
        with torch.inference_mode():
            results = {name: solving.solvers[name](corners.to(torch.float64), valid, obj, image_size, weights=weights)
                       for name in dict.fromkeys(names)}
    parts, order = [], []
    applied = None if correction is None else torch.zeros(corners.shape[0], dtype=torch.bool, device=corners.device)
    for name in dict.fromkeys(names):
        sel = torch.tensor([n == name for n in names], device=corners.device).nonzero().flatten()
        calib, refined, kept = _compete(
            solving, solving.solvers[name], select_result(results[name], sel), corners[sel], found[sel], board_size, square,
            image_size, None if correction is None else correction[sel], None if tried is None else tried[sel],
        )
        if correction is not None:
            correction = correction.clone()
            correction[sel] = refined
            applied[sel] = kept
        parts.append(calib)
        order.append(sel)
    return _merge(parts, order, corners.shape[0]), correction, applied, table


def _compete(solving: Solving, solver: CalibrationSolver, usual: CalibrationResult, corners, found, board_size, square, image_size,
             correction, tried):
    """Where the evidence asked for it, the corrected-frame calibration against the usual one (kept where it fits
    the observed corners clearly better); returns ``(calibration, correction, applied)``."""
    # (the corrected frame's radial model is a pinhole lens's: not for fisheye cameras)
    if correction is None or tried is None or not bool(tried.any()) or solver.camera.is_fisheye:
        return usual, correction, None if correction is None or tried is None else torch.zeros_like(tried)
    # only the cameras the evidence points to, and only those the usual solve could calibrate, go the corrected
    # way (a camera refused as degenerate stays refused)
    sel = (tried.to(usual.success.device) & usual.success).nonzero().flatten()
    applied = torch.zeros_like(tried)
    if sel.numel() == 0:
        return usual, correction, applied
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
