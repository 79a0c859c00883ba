"""The differentiable path of :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` (``differentiable=True``).

The usual pipeline runs first, without autograd, in this process (no worker processes): it takes every discrete
decision (which views show a board, the grid order, which corners are valid, the detection level, the model,
which views the solver uses, whether the corrected-frame calibration is kept) and gives the values. Then:

* the corners of found boards are made differentiable functions of the images and of the heatmap network
  (:mod:`~ccs_kornia.modules.detection.refine.differentiable_refine`: the network's Gaussian-fit seed on the detection
  level, the point-symmetry refinement on the image; the values stay the usual ones);
* each image size's cameras are solved again with those corners by the same solver call (same model, batch, weights
  and start), whose implicit gradient (:mod:`~ccs_kornia.modules.calibration.implicit`) carries the corners' gradient
  to ``K``, ``dist``, ``rvec`` and ``tvec``: the values are bit-identical to the usual solve's.

Not differentiated: the distortion network. Its prediction only takes decisions (which cameras try the corrected
frame, which missed views are looked for on corrected copies) and starts the corrected-frame refinement, whose
optimum does not depend on its start; a camera whose corrected-frame calibration was kept returns it without
gradient (``docs/gradients.md``). Corner weights (``weigh_corners``) are measured without gradient.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    measured_corners,
)
from ccs_kornia.modules.detection.refine.differentiable_refine import (
    SYMMETRY_STEPS,
    DifferentiableCorners,
)
from ccs_kornia.pipeline.result import (
    PipelineResult,
    concat_results,
    positive_size,
    select_result,
)
from ccs_kornia.pipeline.solve import Solving
from ccs_kornia.runtime.checks import check_board_size

__all__ = ["differentiable_detect", "differentiable_run", "corner_module"]


def corner_module(det: ChessboardDetector, net: torch.nn.Module | None = None) -> DifferentiableCorners:
    """The :class:`DifferentiableCorners` of the detector ``det``: its heatmap network (or ``net``, e.g. one in
    training) seeds the refinement; no image refinement steps where the detector has none (its corners are the
    network's own)."""
    net = det.heatmap_net if net is None else net
    steps = SYMMETRY_STEPS if det.refines_on_image else 0
    return DifferentiableCorners(net, steps, det.fit_window)


def _detection_factor(det: ChessboardDetector, images: torch.Tensor) -> torch.Tensor | float:
    """Full-resolution px per detection-level px of each image (the learned detector's primary level)."""
    with torch.no_grad():
        return det.detection_factor(images.detach().float())


def _corners(det_module: ChessboardDetector, images: torch.Tensor, det: DetectionResult, board: tuple[int, int],
             net: torch.nn.Module | None) -> tuple[torch.Tensor, torch.Tensor]:
    """Differentiable corners ``(C, V, N, 2)`` float64 of the found boards of ``images`` (C, V, 1, H, W), and the gap
    of the differentiated estimator to the usual values (NaN where not found)."""
    c, v = det.found.shape
    corners = det.corners.to(torch.float64)
    gap = torch.full_like(corners, float("nan"))
    idx = det.found.flatten().nonzero().flatten()
    if idx.numel() == 0:
        return corners, gap
    flat = images.flatten(0, 1)[idx.to(images.device)]
    pts = corners.flatten(0, 1)[idx]
    valid = measured_corners(pts, torch.ones(idx.numel(), dtype=torch.bool, device=pts.device))
    module = corner_module(det_module, net)
    out, g = module(flat, pts, valid, board, _detection_factor(det_module, flat))
    corners = corners.flatten(0, 1).index_put((idx,), out.to(torch.float64)).view(c, v, -1, 2)
    gap = gap.flatten(0, 1).index_put((idx,), g.to(torch.float64)).view(c, v, -1, 2)
    return corners, gap


def differentiable_detect(out: PipelineResult, images: torch.Tensor, board_size: tuple[int, int],
                          detector: ChessboardDetector, net: torch.nn.Module | None = None) -> DetectionResult:
    """:meth:`CalibrationPipeline.detect <ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.detect>` with the corners of found
    boards differentiable with respect to ``images`` and the heatmap network (``net``: default, ``detector``'s).

    Args:
        out: the usual pipeline's result on ``images`` (``run(..., calibrate=False)`` without autograd, batched with
            a camera dimension): every decision and value.
        images: :math:`(V, 1, H, W)` or :math:`(C, V, 1, H, W)`, the images ``out`` was computed from.
        board_size: ``(cols, rows)`` inner corners.
        detector: the detector that found the boards.
        net: the heatmap network to differentiate (default: ``detector``'s).

    The result also carries ``gap`` (float64, the shape of ``corners``): how far the differentiated estimator's value
    is from the returned corner (NaN where not found)."""
    board = check_board_size(board_size)
    batched = images if images.dim() == 5 else images[None]
    corners, gap = _corners(detector, batched, out.detections, board, net)
    det = replace(out.detections, corners=corners, correction=out.correction, correction_tried=out.correction_tried,
                  gap=gap)
    return select_result(det, 0) if images.dim() == 4 else det


def differentiable_run(out: PipelineResult, images: torch.Tensor, board_size: tuple[int, int], square: float,
                       detector: ChessboardDetector, solving: Solving,
                       net: torch.nn.Module | None = None) -> PipelineResult:
    """:meth:`CalibrationPipeline.forward <ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.forward>` with ``K``, ``dist``,
    ``rvec`` and ``tvec`` differentiable with respect to ``images`` and the heatmap network (``net``: default, the
    detector's), through the differentiable corners and the solver's implicit gradient. Values: the usual ones;
    no camera dimension for 4-D ``images``.

    Args:
        out: the usual pipeline's result on ``images`` (``run`` without autograd, batched with a camera
            dimension): every decision and value.
        images: :math:`(V, 1, H, W)` or :math:`(C, V, 1, H, W)`, the images ``out`` was computed from.
        board_size: ``(cols, rows)`` inner corners; square: the square side.
        detector: the detector that found the boards.
        solving: the pipeline's solver settings (:class:`~ccs_kornia.pipeline.solve.Solving`).
        net: the heatmap network to differentiate (default: ``detector``'s).

    ``detections.gap`` says how far the differentiated corner estimator's value is from each corner."""
    board = check_board_size(board_size)
    batched = images if images.dim() == 5 else images[None]
    det = out.detections
    corners, gap = _corners(detector, batched, det, board, net)
    # the usual solve's input (its views, valid corners and weights) with the differentiable corners
    inputs = replace(solving.inputs(out, board, square), corners=corners)
    parts, order = [], []
    for size in dict.fromkeys(out.image_size):
        sel = torch.tensor([s == size for s in out.image_size], device=corners.device).nonzero().flatten()
        part = inputs.cameras(sel)
        if isinstance(solving.model, ModelChoice):
            tables = out.model_selection or [None] * len(out.image_size)
            # the model chosen for each camera (the first candidate where none was)
            names = [out.calibration.camera.models[ci] if (tables[ci] or {}).get("chosen")
                     else next(iter(solving.solvers)) for ci in sel.tolist()]
        else:
            names = [solving.solver.model] * sel.numel()
        # the usual solve's call: each model over every camera of the group (the RANSAC draws depend on the batch)
        results = {n: part.solve(solving.solvers[n], positive_size(size)) for n in dict.fromkeys(names)}
        for k, (ci, n) in enumerate(zip(sel.tolist(), names)):
            # a camera whose corrected-frame calibration was kept: that one, without gradient
            kept = out.corrected is not None and bool(out.corrected[ci])
            source, row = (out.calibration, ci) if kept else (results[n], k)
            parts.append(select_result(source, torch.tensor([row])))
            order.append(ci)
    out = replace(out, detections=replace(det, corners=corners, gap=gap),
                  calibration=_in_order(parts, order, len(out.image_size)))
    return out.select(0) if images.dim() == 4 else out


def _in_order(parts: list, order: list[int], count: int):
    """One-camera results back in camera order (models with different distortion sizes are padded as the usual
    pipeline pads them)."""
    inverse = torch.empty(count, dtype=torch.long)
    inverse[torch.tensor(order)] = torch.arange(count)
    merged = concat_results(parts)
    return select_result(merged, inverse.to(merged.K.device))
