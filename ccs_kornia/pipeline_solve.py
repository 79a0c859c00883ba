"""The solver stage of :class:`~ccs_kornia.pipeline.CalibrationPipeline` (paper Sec. III-C) on its detections.

Per image size, one batched solve over the cameras; with ``model="auto"`` every candidate model solves every
camera and :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection` picks one per camera; where the
image evidence asked for the lens correction, the corrected-frame calibration then competes with the usual one.
Kept apart from ``pipeline.py`` so that file stays the composition; the functions take the pipeline for its
solvers and options.
"""

from __future__ import annotations

import functools
from typing import Any

import torch

from ccs_kornia.batch_workers import map_batches, worker_pool, workers_on
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.modules.correction import corrected_frame
from ccs_kornia.modules.detection.boards import grid_object_points
from ccs_kornia.modules.detection.base import DetectionResult, detector_options, measured_corners
from ccs_kornia.pipeline_result import (
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

__all__ = ["solve_detections", "solve_group"]


#: the learned detector's options on the second looks at missed views (the calibrated lens's virtual views, the
#: corrected copies): only the finer fallback levels pay (without any: ros_fisheye_mono at 0.5x 24 -> 23 boards,
#: boofcv_fisheye_chessboard at 0.5x 26 -> 25; without the 0.25: ros_fisheye_mono at 0.5x 24 -> 23 again); the coarser
#: one, the octaves below and the finest level (detect_at_scale's last tries for a wrong square-size estimate) and
#: OpenCV's candidates (boards with marks) only add their cost to every view without a board (the foreshortened levels
#: wait for look_foreshortened, after every cheaper look): boofcv_fisheye_chessboard's
#: calibrated look 7.5 -> 4.6 s with the same boards and RMS on the fisheye sets and GoPro at 0.5x, 1x and 2x;
#: on the corrected copies: the same boards and RMS on the eight real sets (boofcv_fisheye_chessboard's 3 of 10 found
#: there, 3.4 -> 2.4 s; udacity_gopro_wide's and udacity_camera_cal's missed photo 1.13 -> 0.41 and 0.96 -> 0.28 s) and
#: every figure of bench sections 2 and 4 unchanged
SECOND_LOOK_OPTIONS = {"opencv_retry": False, "scale_fallback": (0.5, 0.25), "scale_finest": False,
                       "foreshortened_retry": False}


def _merge(parts: list[CalibrationResult], order: list[torch.Tensor], count: int) -> CalibrationResult:
    """Parts over disjoint camera indices back in camera order."""
    device = order[0].device
    inverse = torch.empty(count, dtype=torch.long, device=device)
    inverse[torch.cat(order)] = torch.arange(count, device=device)
    return select_result(concat_results(parts), inverse)


def solve_detections(pipe: Any, out: PipelineResult, board_size: tuple[int, int], square: float,
                     diagnostics: bool | None = None, keep_models: bool = False) -> PipelineResult:
    """:meth:`CalibrationPipeline.solve <ccs_kornia.pipeline.CalibrationPipeline.solve>`: fills ``out``'s
    ``calibration``, ``corrected``, ``correction``, ``camera_reasons``, ``model_selection`` and (when
    ``diagnostics``, by default the pipeline's setting) ``diagnostics``.

    With ``keep_models`` (``model="auto"``, after a first solve), each camera is solved again with the model chosen
    in ``out.model_selection`` instead of choosing again: the solve after the second look, whose few recovered views
    would cost a whole cross-validation of every model (1.5 s of udacity_gopro_wide's 13 s) to confirm the choice
    that sent the camera to the look. The tables say on how many views the choice was made."""
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
    previous = out.model_selection if keep_models and pipe.model == "auto" else None
    # the model selection's cross-validations, kept for the diagnostics of the same calibrations (diagnose_solved)
    pipe.subset_solutions = SubsetSolutions()
    for size in dict.fromkeys(sizes):
        sel = torch.tensor([s == size for s in sizes], device=device).nonzero().flatten()
        tried = None if out.correction_tried is None else out.correction_tried[sel]
        models = None if previous is None else [(previous[ci] or {}).get("chosen") for ci in sel.tolist()]
        calib, refined, applied, table = solve_group(
            pipe, det.corners[sel], usable[sel], board_size, square, positive_size(size),
            None if correction is None else correction[sel], tried, None if det.sigma is None else det.sigma[sel],
            models)
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
    out.calibration = _merge(parts, order, c)
    out.correction = correction
    out.corrected = corrected if correction is not None else None
    out.model_selection = selection if pipe.model == "auto" else None
    out.camera_reasons = [camera_reason(out.calibration, ci, int(usable[ci].sum()), int(out.present[ci].sum()))
                          for ci in range(c)]
    if pipe.diagnostics if diagnostics is None else diagnostics:
        out.diagnostics = diagnose_cameras(pipe.solvers, out, usable, board_size, square, pipe.weigh_corners,
                                           pipe.subset_solutions, board=getattr(pipe.detector, "board", None))
    return out


def diagnose_solved(pipe: Any, out: PipelineResult, board_size: tuple[int, int], square: float) -> PipelineResult:
    """The diagnostics of a result :func:`solve_detections` solved without them (fills ``out.diagnostics``)."""
    usable = out.detections.found & same_size_views(out)
    out.diagnostics = diagnose_cameras(pipe.solvers, out, usable, (int(board_size[0]), int(board_size[1])), square,
                                       pipe.weigh_corners, pipe.subset_solutions,
                                       board=getattr(pipe.detector, "board", None))
    return out


def _chosen_before(table: dict | None, views: int) -> dict | None:
    """A model-selection table of a first solve (its ``views``: those the choice saw), noting that the second look
    changed the views (recovered missed ones, or re-detected rejected ones) and how many the calibration uses."""
    if table is None:
        return None
    return {**table, "note": f"chosen on the {table.get('views')} views of the first solve, before the second look "
                             f"on the calibrated lens; the final calibration uses {views}"}


def solve_group(pipe: Any, corners: torch.Tensor, found: torch.Tensor, board_size: tuple[int, int], square: float,
                image_size: tuple[int, int], correction: torch.Tensor | None, tried: torch.Tensor | None,
                sigma: torch.Tensor | None = None, models: list[str | None] | None = None):
    """Cameras of one image size: ``(calibration, correction, applied, model_selection)`` (the last two ``None``
    without a correction / without ``model="auto"``). ``sigma``: the corners'
    :math:`(C, V, N)` precision, weighting the solves where the pipeline weighs corners. ``models``
    (``model="auto"`` only): a model name per camera to solve with instead of choosing (the table is then ``None``;
    a camera without a name gets the first candidate)."""
    cols, rows = int(board_size[0]), int(board_size[1])
    obj = grid_object_points(getattr(pipe.detector, "board", None), (cols, rows), float(square), device=corners.device,
                             dtype=torch.float64)
    valid = measured_corners(corners, found)
    weights = corner_weights_of(sigma, valid) if pipe.weigh_corners else None
    if pipe.model != "auto":
        with torch.inference_mode():
            usual = pipe.solver(corners.to(torch.float64), valid, obj, image_size, weights=weights)
        return (*_compete(pipe, pipe.solver, usual, corners, found, board_size, square, image_size, correction, tried),
                None)
    if models is None:
        with torch.inference_mode():
            results, chosen, table = pipe.selection(corners.to(torch.float64), valid, obj, image_size, weights=weights,
                                                    map_models=_map_in_workers(workers_on(corners.device, pipe.workers)),
                                                    solutions=pipe.subset_solutions)
        fallback = next(iter(results))  # cameras no model calibrated keep that model's (failed) result
        names = [n or fallback for n in chosen]
    else:
        names, table = [n or next(iter(pipe.solvers)) for n in models], None
        # each chosen model solves every camera of the group, as in the selection: the solver's RANSAC draws depend on
        # the batch, and a camera must get the calibration its choice was made on (one rendered fisheye camera of
        # bench section 7 went 0.078 -> 0.754 px E_IP when its model's cameras were solved alone)
        with torch.inference_mode():
            results = {name: pipe.solvers[name](corners.to(torch.float64), valid, obj, image_size, weights=weights)
                       for name in dict.fromkeys(names)}
    parts, order = [], []
    applied = None if correction is None else torch.zeros(corners.shape[0], dtype=torch.bool, device=corners.device)
    for name in dict.fromkeys(names):
        sel = torch.tensor([n == name for n in names], device=corners.device).nonzero().flatten()
        calib, refined, kept = _compete(
            pipe, pipe.solvers[name], select_result(results[name], sel), corners[sel], found[sel], board_size, square,
            image_size, None if correction is None else correction[sel], None if tried is None else tried[sel],
        )
        if correction is not None:
            correction = correction.clone()
            correction[sel] = refined
            applied[sel] = kept
        parts.append(calib)
        order.append(sel)
    return _merge(parts, order, corners.shape[0]), correction, applied, table


def _compete(pipe: Any, solver: Any, usual: CalibrationResult, corners, found, board_size, square, image_size,
             correction, tried):
    """Where the evidence asked for it, the corrected-frame calibration against the usual one (kept where it fits
    the observed corners clearly better); returns ``(calibration, correction, applied)``."""
    # (the corrected frame's radial model is a pinhole lens's: not for fisheye cameras)
    if correction is None or tried is None or not bool(tried.any()) or solver.model == "fisheye":
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
        joint_iters=pipe.joint_iters, free_distortion_centre=pipe.free_distortion_centre,
        max_rms_ratio=pipe.max_rms_ratio,
    )
    keep = torch.zeros_like(usual.success)
    keep[sel] = kept.to(keep.device)
    merged = corrected_frame.select_cameras(keep, scatter_cameras(calib, sel, usual), usual)
    correction = correction.clone()
    correction[sel] = refined.to(correction)
    applied[sel] = kept.to(applied.device)
    return merged, correction, applied


def look_on_corrected(pipe: Any, source: Any, out: PipelineResult, correction: torch.Tensor, large: torch.Tensor,
                      same: torch.Tensor, board: tuple[int, int]) -> None:
    """Views missed on the originals of cameras whose pooled correction is ``large`` :math:`(C,)`, looked for on
    copies corrected by ``correction`` :math:`(C, 5)`
    (:func:`~ccs_kornia.modules.correction.corrected_detection.detect_on_corrected`); fills ``out.detections`` in
    place. A second look: finer fallback levels only, no last resorts (:data:`SECOND_LOOK_OPTIONS`), in the pipeline's
    batches (one view at a time changed rendered fisheye cameras' E_IP in the 4th digit, bench section 7), by its worker
    processes on CPU."""
    from ccs_kornia.modules.correction.corrected_detection import detect_on_corrected

    det = out.detections
    device, v = det.corners.device, det.found.shape[1]
    missed = [(ci, vi) for ci in large.nonzero().flatten().tolist()
              for vi in (same[ci] & ~det.found[ci]).nonzero().flatten().tolist()]

    def look(images: torch.Tensor, keys: list) -> tuple[DetectionResult, torch.Tensor | None]:
        images = images.to(device)
        got = detect_on_corrected(pipe.detect_images, pipe.refine_on_patches, images,
                                  correction[torch.tensor([k[0] for k in keys], device=device)], board)
        ok = got.found
        if det.sigma is None or not bool(ok.any()):
            return got, None
        return got, pipe.corner_sigma(images[ok], got.corners[ok], board)  # the precision on the original image

    if not missed:
        return
    with detector_options(pipe.detector, **SECOND_LOOK_OPTIONS):
        for batch in map_batches(look, source, missed, pipe.detection_batch_size, pipe.max_batch_pixels,
                                 workers_on(device, pipe.workers)):
            if batch.size is None or not bool(batch.value[0].found.any()):
                continue
            (got, sigma), ok = batch.value, batch.value[0].found
            cam = torch.tensor([k[0] for k in batch.keys], device=device)[ok]
            view = torch.tensor([k[1] for k in batch.keys], device=device)[ok]
            det.corners[cam, view], det.found[cam, view] = got.corners[ok].to(det.corners), True
            if sigma is not None:
                det.sigma[cam, view] = sigma.to(det.sigma)
            for k in ok.nonzero().flatten().tolist():
                det.reasons[batch.keys[k][0] * v + batch.keys[k][1]] = got.reasons[k]


def _map_in_workers(workers: int):
    """``map_models`` of :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection`: the models solved
    by forked worker processes, one thread each (the solver of a few cameras runs on one thread anyway)."""
    def map_models(fn, items: list) -> list:
        with worker_pool(fn, min(workers, len(items))) as run:
            return list(run(items))

    return map_models


def look_again_with_camera(pipe: Any, source: Any, out: PipelineResult, board: tuple[int, int]) -> bool:
    """Views missed on the originals (or rejected as outliers) of cameras calibrated with the fisheye model, looked
    for on virtual pinhole views of the calibrated lens (:func:`~ccs_kornia.modules.correction.calibrated_detection.detect_with_calibrated_lens`);
    fills ``out.detections`` in place and returns whether a board was found (the cameras are then solved again).

    Only fisheye cameras: there the boards near the rim are too curved for the detector, and the calibrated model is
    what straightens them (measured: 3 of 3 missed ROS views, 6 of 6 missed BoofCV views found); a pinhole lens's
    missed views are missed for other reasons (blur, cut boards) that a reprojection does not cure.
    """
    cal, det = out.calibration, out.detections
    models = cal.model if isinstance(cal.model, tuple) else (cal.model,) * det.found.shape[0]
    same = same_size_views(out)
    ok = cal.success.to(same.device)
    cams = [ci for ci in ok.nonzero().flatten().tolist() if models[ci] == "fisheye"]
    # views without a board, and views whose corners the solver rejected as an outlier (wrong corners on the
    # original image: a board near the rim found, but mislabelled)
    outlier = cal.view_reason.to(same.device) == 4
    retry = same & (~det.found | outlier)
    missed = [(ci, vi) for ci in cams for vi in retry[ci].nonzero().flatten().tolist()]
    if not missed:
        return False
    lens = {ci: select_result(cal, ci) for ci in cams}
    v = det.found.shape[1]
    with detector_options(pipe.detector, **SECOND_LOOK_OPTIONS):
        return _look(pipe, source, missed, lens, det, board, v)


def _look(pipe: Any, source: Any, missed: list, lens: dict, det: Any, board: tuple[int, int], v: int) -> bool:
    """The batches of :func:`look_again_with_camera`."""
    from ccs_kornia.sources import load_batches

    recovered = False
    for batch in load_batches(source, missed, pipe.detection_batch_size, pipe.max_batch_pixels):
        if batch.images is None:
            continue
        device = det.corners.device
        K = torch.stack([lens[ci].K for ci, _ in batch.keys]).to(device)
        dist = torch.stack([lens[ci].dist for ci, _ in batch.keys]).to(device)
        # the images of a batch here, their virtual views by the worker processes (a whole image per process measured
        # no faster: udacity_gopro_wide misses one view, GOPR0055)
        got = _calibrated_passes(pipe, batch.images.to(device), K, dist, board)
        for k, (ci, vi) in enumerate(batch.keys):
            if bool(got.found[k]):
                det.corners[ci, vi] = got.corners[k].to(det.corners)
                det.found[ci, vi] = True
                if det.sigma is not None:  # found on a virtual view: precision unknown (the median weight)
                    det.sigma[ci, vi] = float("nan")
                if det.reasons is not None:
                    det.reasons[ci * v + vi] = got.reasons[k]
                recovered = True
    return recovered


def _calibrated_passes(pipe: Any, images: torch.Tensor, K: torch.Tensor, dist: torch.Tensor,
                       board: tuple[int, int]) -> Any:
    """:func:`~ccs_kornia.modules.correction.calibrated_detection.detect_with_calibrated_lens` in two passes over the
    virtual views: each on the level its square-size estimate picks, then, for the images still without a board, on
    the detector's fallback levels only.

    A board near a fisheye's rim is found on the first level of some view (the real fisheye sets: 9 of 9 boards, and
    8 of 8 at half size, on the same views as with the fallbacks); the fallbacks, finer levels of up to 16x the
    pixels, find the others (bench section 7's renders: 733 boards of 750, 723 with the second pass left out where
    the lens's focal length exceeds the axis view's; ros_fisheye_mono at half size: 2 of its 5 missed views). One
    pass with the fallbacks paid them on every view before the one that had the board: boofcv_fisheye_chessboard's
    look 6.2 -> 2.2-2.5 s, ros_fisheye_mono's 0.79 -> 0.42 s; a view with no board in reach pays both passes, the
    first one on top of the old cost (udacity_gopro_wide's GOPR0055, a board larger than the frame: 2.2-2.5 ->
    2.8-3.2 s). The same boards on bench section 7 (733 and 732 of 750)."""
    from ccs_kornia.modules.correction.calibrated_detection import VIEWS_PER_ROUND, detect_with_calibrated_lens

    workers = workers_on(images.device, pipe.workers)
    pool = functools.partial(worker_pool, workers=min(workers, VIEWS_PER_ROUND)) if workers > 1 else None

    def look(x: torch.Tensor, k: torch.Tensor, d: torch.Tensor) -> Any:
        return detect_with_calibrated_lens(pipe.detect_images, pipe.refine_on_patches, x, k, d, True, board,
                                           view_pool=pool)

    fallback = getattr(pipe.detector, "scale_fallback", ())
    with detector_options(pipe.detector, scale_fallback=()):
        got = look(images, K, dist)
    missed = (~got.found).nonzero().flatten()
    if fallback and missed.numel():
        with detector_options(pipe.detector, scale_primary=False):
            again = look(images[missed], K[missed], dist[missed])
        for j, i in enumerate(missed.tolist()):
            if bool(again.found[j]):
                got.corners[i], got.found[i], got.reasons[i] = again.corners[j], True, again.reasons[j]
    return got


def look_foreshortened(pipe: Any, source: Any, out: PipelineResult, board: tuple[int, int]) -> bool:
    """Views still without a board after the other looks, looked for with the detector's last resort for boards at a
    grazing angle (``detector.foreshortened``: the image compressed along a few directions); fills
    ``out.detections`` in place and returns whether a board was found.

    The pipeline defers this resort to the end (``detect_views`` runs the detector without it): it costs four
    detections at the finest level on every view without a board, and most such views of a fisheye lens are found by
    the calibrated look anyway (boofcv_fisheye_chessboard: 10 of its 26 views, +4.5 s when each paid it first).
    """
    resort = getattr(pipe.detector, "foreshortened", None)
    det = out.detections
    if resort is None or not getattr(pipe.detector, "foreshortened_retry", False):
        return False
    from ccs_kornia.sources import load_batches

    retry = out.present & ~det.found
    if out.correction_tried is not None:
        # a strongly distorted lens (its pooled correction large) bends a board's squares beyond an affine
        # compression: the corrected look is its resort (bench section 4's wide lens: looking here found one rim
        # board of 300 views, and the mean E_IP rose 0.041 -> 0.045 px)
        retry &= ~out.correction_tried.to(retry.device)[:, None]
    missed = [tuple(k) for k in retry.nonzero().tolist()]
    if not missed:
        return False
    v = det.found.shape[1]
    recovered = False
    for batch in load_batches(source, missed, pipe.detection_batch_size, pipe.max_batch_pixels):
        if batch.images is None:
            continue
        images = batch.images.to(det.corners.device)
        with torch.inference_mode():
            got = resort(images.float(), board)
        for k, (ci, vi) in enumerate(batch.keys):
            if bool(got.found[k]):
                det.corners[ci, vi] = got.corners[k].to(det.corners)
                det.found[ci, vi] = True
                if det.reasons is not None:
                    det.reasons[ci * v + vi] = got.reasons[k]
                recovered = True
        hit = got.found.nonzero().flatten()
        if det.sigma is not None and hit.numel():
            cam = torch.tensor([batch.keys[k][0] for k in hit.tolist()], device=det.sigma.device)
            view = torch.tensor([batch.keys[k][1] for k in hit.tolist()], device=det.sigma.device)
            det.sigma[cam, view] = pipe.corner_sigma(images[hit], got.corners[hit], board).to(det.sigma)
    return recovered
