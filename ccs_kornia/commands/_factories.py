"""The detector and the pipeline a command's arguments describe (``--detector``, ``--network-precision``, the board,
``--jobs``, ``--batch-size``, ``--allow-weak``, ...)."""

from __future__ import annotations

import argparse

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.modules.calibration.quality.degeneracy import (
    DegeneracyThresholds,
)
from ccs_kornia.modules.detection.circles.circle_grid import CircleGridDetector
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.markers.aprilgrid import AprilGridDetector
from ccs_kornia.modules.detection.markers.charuco import CharucoDetector
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.runtime.errors import UserError

__all__ = ["make_detector_from", "make_pipeline", "missing_weights", "pipeline_options"]


def make_detector_from(args: argparse.Namespace):
    """The detector the command's ``--detector`` (and ``--network-precision``) name, or the ChArUco board's
    (:func:`~ccs_kornia.commands._boards.resolve_board`)."""
    if getattr(args, "charuco_board", None) is not None:
        return CharucoDetector(args.charuco_board)
    if getattr(args, "aprilgrid_board", None) is not None:
        return AprilGridDetector(args.aprilgrid_board)
    if getattr(args, "circle_board", None) is not None:
        return CircleGridDetector(args.circle_board)
    options = {}
    if args.detector == "learned" and getattr(args, "network_precision", None):
        options["precision"] = args.network_precision
    try:
        return make_detector(args.detector, **options)
    except ValueError as err:
        raise UserError(str(err)) from None


def pipeline_options(args: argparse.Namespace, use_ransac: bool = True, seed: int = 0) -> dict:
    """The :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` options the command's arguments set
    (``--allow-weak``: the solvers keep cameras the views determine only weakly)."""
    options = dict(
        use_ransac=use_ransac, seed=seed, detection_batch_size=args.batch_size,
        workers=getattr(args, "jobs", 1),
        max_detection_side=getattr(args, "max_detection_side", 2048) or None,
        distortion_correction=bool(getattr(args, "distortion_correction", False)),
        diagnostics=bool(getattr(args, "diagnostics", False)),
        weigh_corners=bool(getattr(args, "weigh_corners", True)),
        board_flatness=bool(getattr(args, "board_flatness", False)),
    )
    if getattr(args, "allow_weak", False):
        options["thresholds"] = DegeneracyThresholds(refuse_weak=False)
    return options


def missing_weights(err: FileNotFoundError) -> UserError:
    """The distortion network's missing weights, as the command line says it."""
    return UserError(str(err).replace("pass distortion_correction=False", "use --no-distortion-correction"))


def make_pipeline(args: argparse.Namespace, model: CameraModel | ModelChoice = OPENCV5, use_ransac: bool = True,
                  seed: int = 0, frame_selection=None, detector=None, **options):
    """The :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` of the command's arguments, with the
    detector of :func:`make_detector_from` (or ``detector``); ``options`` replace those of the arguments
    (:func:`pipeline_options`). ``model``: a camera model or a model choice (``--model``, as the command line read it)."""
    detector = make_detector_from(args) if detector is None else detector
    try:
        return CalibrationPipeline(detector, model=model, frame_selection=frame_selection,
                                   **(pipeline_options(args, use_ransac, seed) | options))
    except FileNotFoundError as err:
        raise missing_weights(err) from None
