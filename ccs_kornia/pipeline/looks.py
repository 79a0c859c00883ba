"""The looks of :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` at its views, each a value the pipeline's loop runs.

The first look (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.detect_views`) detects every view as it is; the
pipeline's looks (by default those of :data:`LOOKS`) come after it, in order, each on the views the looks before it
missed:

========================  ====================================  ==================================  ===========
look                      views (``select``)                    warp (``detect``)                   needs
========================  ====================================  ==================================  ===========
:data:`CORRECTED`         missed, of cameras whose pooled       the network's pooled correction     correction
                          correction is large                   (:class:`CorrectedCopy`)
:data:`CALIBRATED`        missed or outliers, of cameras        virtual pinhole views of the        camera
                          calibrated with the fisheye model     calibrated lens (:class:`VirtualView`)
:data:`FORESHORTENED`     still missed (no large correction)    the detector's compressed levels    --
========================  ====================================  ==================================  ===========

A look says which of the detector's fallbacks it pays for (``passes``: functions of the detector's own
:class:`~ccs_kornia.modules.detection.base.Fallbacks`, one detection per pass, each pass on the views the passes
before it missed) and whether it needs the camera (the loop solves first). The pipeline's detection tools reach a
look as one value (:class:`Tools`); a look's boards are written back with
:meth:`~ccs_kornia.modules.detection.base.DetectionResult.fill`. Why each look asks what it does, with the figures:
``docs/measurements.md`` (the looks at missed views).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Callable

import torch

from ccs_kornia.modules.calibration.result import ViewReason
from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    Fallbacks,
)
from ccs_kornia.modules.detection.warps.corrected_copy import (
    detect_on_corrected,
    straightening_evidence,
)
from ccs_kornia.modules.detection.warps.virtual_view import (
    VIEWS_PER_ROUND,
    detect_with_calibrated_lens,
)
from ccs_kornia.pipeline.result import PipelineResult, positive_size
from ccs_kornia.pipeline.workers import worker_pool

__all__ = ["Pass", "Tools", "Look", "own_fallbacks", "first_look_fallbacks", "second_look_fallbacks",
           "FIRST_PASSES", "FIRST", "CORRECTED", "CALIBRATED", "FORESHORTENED", "LOOKS", "measure_straightening"]

#: what one pass of a look asks of the detector: its own fallbacks in, the ones to pay for out
Pass = Callable[[Fallbacks], Fallbacks]


def own_fallbacks(own: Fallbacks) -> Fallbacks:
    """The detector's own fallbacks, unchanged."""
    return own


def first_look_fallbacks(own: Fallbacks) -> Fallbacks:
    """The first look's: every fallback but the costly last resort for boards at a grazing angle, which waits for the
    views the other looks miss (:data:`FORESHORTENED`)."""
    return own.but(foreshortened=False)


def second_look_fallbacks(own: Fallbacks) -> Fallbacks:
    """A second look at missed views (corrected copies, virtual views of the calibrated lens): the finer fallback
    levels only, which find boards there; the coarser level, the octaves below, the finest level and OpenCV's
    candidates found none and cost time on every view without a board (``docs/measurements.md``); the enhanced copies
    were looked at by the first look already."""
    return own.but(levels=(0.5, 0.25), finest=False, opencv=False, foreshortened=False, copies=False)


def _virtual_view_first_level(own: Fallbacks) -> Fallbacks:
    """The calibrated look's first pass: the level the square-size estimate picks, no fallback level."""
    return second_look_fallbacks(own).but(levels=())


def _virtual_view_fallback_levels(own: Fallbacks) -> Fallbacks:
    """The calibrated look's second pass: the second look's fallback levels only."""
    return second_look_fallbacks(own).but(primary=False)


#: the first look's passes
FIRST_PASSES: tuple[Pass, ...] = (first_look_fallbacks,)


@dataclass(frozen=True)
class Tools:
    """What a look detects with: the pipeline's detection tools.

    Attributes:
        detect: ``(images (B,1,H,W), board_size, fallbacks) -> DetectionResult``, the detector (through a downscaled
            copy of large images) with ``fallbacks`` (``None``: its own), corners' precision measured where weighed.
        refine: ``(images, corners (B,N,2), board_size) -> corners``: the saddle refinement at full resolution.
        measure: ``(images, corners (B,N,2), board_size) -> sigma (B,N)``: the corners' precision (``None``: corners
            are not weighed).
        detector: the detector itself (its own fallbacks, its last resort).
        workers: processes that may work at once on CPU.
    """

    detect: Callable[[torch.Tensor, tuple[int, int], Fallbacks | None], DetectionResult]
    refine: Callable[[torch.Tensor, torch.Tensor, tuple[int, int]], torch.Tensor]
    measure: Callable[[torch.Tensor, torch.Tensor, tuple[int, int]], torch.Tensor] | None
    detector: ChessboardDetector
    workers: int


@dataclass(frozen=True)
class Look:
    """One look at views a look before it missed.

    Attributes:
        name: what the look is.
        select: ``select(out, detector) -> [(camera, view), ...]``: the views it looks at (``None``: every view of the
            source).
        detect: ``detect(tools, out, images, keys, board_size, fallbacks) -> DetectionResult``: one batch of those
            views (``keys``), the warp -> detect -> map back -> refine -> precision of the look, corners in the images;
            ``fallbacks``: the pass's (``None`` for a detector without fallbacks).
        passes: what each pass asks of the detector's own fallbacks (:data:`Pass`), one detection per pass, each on
            the views the passes before missed (a pass that would try no level, or a detector without fallbacks after
            the first pass, is skipped).
        needs_camera: the cameras are solved (again, where a look found boards since) before this look.
        needs_correction: the network's pooled correction per camera (the look is skipped without one).
        in_workers: its batches are shared out to the pipeline's worker processes (``False``: here, one after the
            other: the calibrated look shares out its own rounds of virtual views, and the foreshortened look's
            answers are those of this process's threads).
        after: ``after(out, board_size) -> out``: the result with what the look measures once it has run (with or
            without views to look at).
    """

    name: str
    select: Callable[[PipelineResult | None, ChessboardDetector], list[tuple[int, int]] | None]
    detect: Callable[..., DetectionResult]
    passes: tuple[Pass, ...] = (own_fallbacks,)
    needs_camera: bool = False
    needs_correction: bool = False
    in_workers: bool = True
    after: Callable[[PipelineResult, tuple[int, int]], PipelineResult] | None = None

    def run(self, tools: Tools, out: PipelineResult, images: torch.Tensor, keys: list,
            board_size: tuple[int, int]) -> DetectionResult:
        """The look on one batch ``images`` :math:`(B, 1, H, W)` of views ``keys``: its :attr:`passes` in turn."""
        own = tools.detector.fallbacks
        got = None
        for k, ask in enumerate(self.passes):
            fallbacks = None if own is None else ask(own)
            if k and (fallbacks is None or fallbacks.empty):
                break
            every = torch.arange(images.shape[0], device=images.device)
            todo = every if got is None else (~got.found).nonzero().flatten()
            if not todo.numel():
                break
            part = [keys[i] for i in todo.tolist()]
            again = self.detect(tools, out, images if got is None else images[todo], part, board_size, fallbacks)
            if got is None:
                got = again
            else:
                got.fill(todo, again)
        return got


def _every_view(out: PipelineResult | None, detector: ChessboardDetector) -> None:
    """Every view of the source."""
    return None


def _as_is(tools: Tools, out: PipelineResult | None, images: torch.Tensor, keys: list, board_size: tuple[int, int],
           fallbacks: Fallbacks | None) -> DetectionResult:
    """The views as they are (through a downscaled copy where the pipeline detects large images so)."""
    return tools.detect(images, board_size, fallbacks)


def _missed_with_large_correction(out: PipelineResult, detector: ChessboardDetector) -> list:
    """Views missed on the originals of cameras whose pooled correction is large."""
    same, det = out.same_size_views, out.detections
    return [(ci, vi) for ci in out.correction_tried.nonzero().flatten().tolist()
            for vi in (same[ci] & ~det.found[ci]).nonzero().flatten().tolist()]


def _on_corrected_copies(tools: Tools, out: PipelineResult, images: torch.Tensor, keys: list,
                         board_size: tuple[int, int], fallbacks: Fallbacks | None) -> DetectionResult:
    """The views on copies corrected by their camera's pooled correction, corners refined and measured on the
    originals (:func:`~ccs_kornia.modules.detection.warps.corrected_copy.detect_on_corrected`)."""
    device = out.detections.corners.device
    images = images.to(device)
    correction = out.correction[torch.tensor([k[0] for k in keys], device=device)]
    detect = functools.partial(_with_fallbacks, tools.detect, fallbacks)
    return detect_on_corrected(detect, tools.refine, images, correction, board_size, tools.measure)


def _missed_on_fisheye_cameras(out: PipelineResult, detector: ChessboardDetector) -> list:
    """Views missed on the originals, or rejected as outliers, of cameras calibrated with a fisheye model.

    Only fisheye cameras: there the boards near the rim are too curved for the detector, and the calibrated model is
    what straightens them (it found every missed view of the real fisheye sets, ``docs/measurements.md``); a pinhole
    lens's missed views are missed for other reasons (blur, cut boards) that a reprojection does not cure."""
    cal, det = out.calibration, out.detections
    models = cal.camera.models
    same = out.same_size_views
    ok = cal.success.to(same.device)
    cams = [ci for ci in ok.nonzero().flatten().tolist() if models[ci].is_fisheye]
    # views without a board, and views whose corners the solver rejected as an outlier (wrong corners on the
    # original image: a board near the rim found, but mislabelled)
    outlier = cal.view_reason.to(same.device) == ViewReason.OUTLIER
    retry = same & (~det.found | outlier)
    return [(ci, vi) for ci in cams for vi in retry[ci].nonzero().flatten().tolist()]


def _on_virtual_views(tools: Tools, out: PipelineResult, images: torch.Tensor, keys: list,
                      board_size: tuple[int, int], fallbacks: Fallbacks | None) -> DetectionResult:
    """The views on virtual pinhole views of their camera's calibrated lens
    (:func:`~ccs_kornia.modules.detection.warps.virtual_view.detect_with_calibrated_lens`), the rounds of virtual
    views by the worker processes (a whole image per process measured no faster). Found on a virtual view, a
    corner's precision is unknown (the median weight)."""
    device = out.detections.corners.device
    camera = out.calibration.camera[torch.tensor([ci for ci, _ in keys])].to(device)
    workers = tools.workers if device.type == "cpu" else 1
    pool = functools.partial(worker_pool, workers=min(workers, VIEWS_PER_ROUND)) if workers > 1 else None
    detect = functools.partial(_with_fallbacks, tools.detect, fallbacks)
    return detect_with_calibrated_lens(detect, tools.refine, images.to(device), camera, board_size, view_pool=pool)


def _still_missed(out: PipelineResult, detector: ChessboardDetector) -> list:
    """Views still without a board, where the detector has the last resort for boards at a grazing angle among its
    own fallbacks (:meth:`~ccs_kornia.modules.detection.base.ChessboardDetector.foreshortened`); not those of a
    strongly distorted lens (its pooled correction large), which bends a board's squares beyond an affine compression:
    the corrected look is its resort (looking there too cost accuracy on bench section 4's wide lens,
    ``docs/measurements.md``)."""
    own = detector.fallbacks
    if own is None or not own.foreshortened:
        return []
    retry = out.present & ~out.detections.found
    if out.correction_tried is not None:
        retry &= ~out.correction_tried.to(retry.device)[:, None]
    return [tuple(k) for k in retry.nonzero().tolist()]


def _foreshortened(tools: Tools, out: PipelineResult, images: torch.Tensor, keys: list,
                   board_size: tuple[int, int], fallbacks: Fallbacks | None) -> DetectionResult:
    """The detector's last resort for boards at a grazing angle (``detector.foreshortened``: the image compressed
    along a few directions, corners mapped back and refined by the detector), precision measured on the images."""
    images = images.to(out.detections.corners.device)
    with torch.inference_mode():
        got = tools.detector.foreshortened(images.float(), board_size)
    hit = got.found.nonzero().flatten()
    got.sigma = None
    if tools.measure is not None and hit.numel():
        got.sigma = torch.full(got.corners.shape[:2], float("nan"), dtype=torch.float32, device=images.device)
        got.sigma[hit] = tools.measure(images[hit], got.corners[hit], board_size).to(got.sigma)
    return got


def _with_fallbacks(detect: Callable, fallbacks: Fallbacks | None, images: torch.Tensor, board_size: tuple[int, int]):
    return detect(images, board_size, fallbacks)


def measure_straightening(out: PipelineResult, board_size: tuple[int, int]) -> PipelineResult:
    """``out`` with ``straightness``: how straight the found boards' rows and columns are before and after each
    camera's pooled correction (:func:`~ccs_kornia.modules.detection.warps.corrected_copy.straightening_evidence`)."""
    det, usable = out.detections, out.usable_views
    device = det.corners.device
    straightness = torch.full((det.found.shape[0], 2), float("nan"), dtype=torch.float64, device=device)
    for size in set(out.image_size):
        sel = torch.tensor([s == size for s in out.image_size], device=device).nonzero().flatten()
        before, after = straightening_evidence(det.corners[sel], usable[sel], out.correction[sel], board_size,
                                               positive_size(size))
        straightness[sel] = torch.stack([before, after], -1)
    return replace(out, straightness=straightness)


#: every view as it is: the look that makes the result (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.detect_views`,
#: with the network's correction of each view)
FIRST = Look("first look", _every_view, _as_is, FIRST_PASSES)

#: views missed on the originals of a strongly distorted camera, on copies corrected by the network's pooled
#: correction: finer fallback levels only, in the pipeline's batches (one view at a time changed results in the
#: fourth digit, ``docs/measurements.md``), by its worker processes on CPU
CORRECTED = Look("corrected look", _missed_with_large_correction, _on_corrected_copies, (second_look_fallbacks,),
                 needs_correction=True, after=measure_straightening)

#: a fisheye lens, once calibrated, straightens the boards its rim hid from the detector: two passes over the
#: virtual views, each on the level its square-size estimate picks, then, for the images still without a board, on
#: the fallback levels only; most rim boards are found on the first level, and one pass with the fallbacks paid them
#: on every view before the one that had the board (``docs/measurements.md``)
CALIBRATED = Look("calibrated look", _missed_on_fisheye_cameras, _on_virtual_views,
                  (_virtual_view_first_level, _virtual_view_fallback_levels), needs_camera=True, in_workers=False)

#: the last resort on the views every other look missed: it costs four detections at the finest level on every view
#: without a board, and most such views of a fisheye lens are found by the calibrated look anyway
#: (``docs/measurements.md``)
FORESHORTENED = Look("foreshortened look", _still_missed, _foreshortened, in_workers=False)

#: the looks after the first (:data:`FIRST`), in order: the default of the pipeline's ``looks``
LOOKS: tuple[Look, ...] = (CORRECTED, CALIBRATED, FORESHORTENED)
