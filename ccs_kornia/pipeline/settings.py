"""What a :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` does, as one checked value:
:class:`PipelineSettings`.

The pipeline makes it once from its keyword arguments (its public face) and its stages read it; the components the
settings do not hold are the pipeline's modules (the detector, the distortion network, the solvers made from
``model``, ``use_ransac``, ``seed`` and ``solver_options``). Checked and normalised when made: a bad
value is a ``ValueError`` naming it, ``workers="auto"`` becomes a number, a differentiable pipeline works in one
process.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.pipeline.frame_selection import FrameSelection
from ccs_kornia.pipeline.looks import LOOKS, Look
from ccs_kornia.pipeline.sources import DEFAULT_MAX_BATCH_PIXELS
from ccs_kornia.pipeline.workers import default_workers

__all__ = ["PipelineSettings"]


@dataclass(frozen=True)
class PipelineSettings:
    """The options of a calibration pipeline (correct -> detect -> solve).

    Attributes:
        model: a camera model (:mod:`ccs_kornia.geometry.models`: ``OPENCV5`` (k1, k2, p1, p2, k3), ``K1K2``,
            ``RATIONAL``, ``PINHOLE``, ``FISHEYE`` (cv2.fisheye's)) or a
            :class:`~ccs_kornia.modules.calibration.model_selection.ModelChoice` (one of its candidates per camera,
            by cross-validation; ``PipelineResult.model_selection`` says which and why).
        use_ransac: reject inconsistent views with image-level RANSAC before the refinement.
        seed: seed of the RANSAC sampling (results are deterministic for a given seed).
        solver_options: further options of :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`.
        detection_batch_size: most images handed to the detector at once.
        workers: processes that detect a source's views on CPU (:mod:`~ccs_kornia.pipeline.workers`: forked, one
            thread each, the same batches and results with any number; ``"auto"``: one per core, at most 4; 1 where
            ``differentiable``).
        max_batch_pixels: most pixels loaded and detected at once (bounds memory; at least one image).
        max_detection_side: images whose longer side exceeds this are detected on a downscaled copy and refined at
            full resolution (``None`` or 0: always detect at full resolution). A detector that picks its own
            detection level (``selects_scale``: the learned one with ``scale="auto"``) gets the full images, and the
            corrected copies of large images are warped at this size.
        min_correction: a camera's pooled correction counts as large when it moves some pixel by more than this
            fraction of the half image diagonal (0.02: 8 px at 640x480); only then is the correction used at all.
        max_rms_ratio: the corrected-frame calibration is kept only if its radial model's RMS on the observed
            corners is at most this times that of the usual calibration (same parameter count for ``opencv5``).
        joint_iters: accepted LM steps at most of the corrected-frame joint refinement (the core runs up to 10x
            as many iterations): distorted held-out cameras need 6-18 iterations; on undistorted ones, where the free
            distortion centre is unobservable, it crawls for 30-500 (up to 0.5 s per camera) to gain a fraction of a
            percent of RMS, and such a camera keeps the usual calibration anyway.
        free_distortion_centre: the corrected-frame refinement also estimates the distortion centre.
        diagnostics: also compute each camera's quality figures and verdict (``PipelineResult.diagnostics``; see
            :func:`~ccs_kornia.modules.calibration.quality.diagnostics.diagnose`: several more solves per camera).
        looks: the looks after the first, in order (:class:`~ccs_kornia.pipeline.looks.Look` values; default
            :data:`~ccs_kornia.pipeline.looks.LOOKS`).
        weigh_corners: measure each detected corner's precision on its image
            (:func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_sigma`, ``DetectionResult.sigma``)
            and weight the solver's refinements by it, so a view's soft or shaded corners count less
            (:func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_weights`).
        differentiable: corners and cameras with gradients to the images and the heatmap network
            (:mod:`~ccs_kornia.pipeline.differentiable`; ``docs/gradients.md``). Off: no autograd anywhere.
        board_flatness: after the last solve, fit the board's sag beside each camera's flat-board calibration and keep
            it where held-out views say it helps (:func:`~ccs_kornia.modules.calibration.board_flatness.choose_board_warp`;
            ``PipelineResult.board_flatness`` says what it found); the OpenCV and fisheye models, not a splined camera or
            a camera calibrated in the corrected frame.
        frame_selection: keep only the views that make the best camera
            (:class:`~ccs_kornia.pipeline.frame_selection.FrameSelection`: still, sharp, new, informative) and solve
            again on them after the last solve (``PipelineResult.frame_choice`` says which and why); ``None``: every
            view counts.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> s = PipelineSettings(model=K1K2, workers=3, max_detection_side=0, differentiable=True)
        >>> s.workers, s.max_detection_side, s.looks[0].name
        (1, None, 'corrected look')
        >>> PipelineSettings(joint_iters=-1)
        Traceback (most recent call last):
        ...
        ValueError: joint_iters must be >= 0, got -1.
    """

    model: CameraModel | ModelChoice = OPENCV5
    use_ransac: bool = True
    seed: int = 0
    solver_options: Mapping[str, Any] = field(default_factory=dict)
    detection_batch_size: int = 16
    workers: int | str = 1
    max_batch_pixels: int | None = DEFAULT_MAX_BATCH_PIXELS
    max_detection_side: int | None = 2048
    min_correction: float = 0.02
    max_rms_ratio: float = 0.9
    joint_iters: int = 4
    free_distortion_centre: bool = True
    diagnostics: bool = False
    looks: tuple[Look, ...] = LOOKS
    weigh_corners: bool = True
    differentiable: bool = False
    frame_selection: FrameSelection | None = None
    board_flatness: bool = False

    def __post_init__(self) -> None:
        if self.detection_batch_size < 1:
            raise ValueError(f"detection_batch_size must be >= 1, got {self.detection_batch_size}.")
        side = self.max_detection_side
        if side is not None and side != 0 and side < 64:
            raise ValueError(f"max_detection_side must be >= 64 (or None/0 to disable), got {side}.")
        if self.joint_iters < 0:
            raise ValueError(f"joint_iters must be >= 0, got {self.joint_iters}.")
        for name in ("min_correction", "max_rms_ratio"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}.")
        if not isinstance(self.model, (CameraModel, ModelChoice)):
            raise TypeError(f"model must be a camera model (ccs_kornia.geometry.models) or a ModelChoice, got "
                            f"{self.model!r}.")
        workers = self.workers
        if workers != "auto" and not (isinstance(workers, int) and workers >= 1):
            raise ValueError(f"workers must be an int >= 1 or 'auto', got {workers!r}.")
        workers = default_workers("cpu") if workers == "auto" else workers
        normal = {
            "solver_options": dict(self.solver_options),
            "detection_batch_size": int(self.detection_batch_size),
            # autograd's graph lives in this process: no worker processes
            "workers": 1 if self.differentiable else workers,
            "max_detection_side": int(side) if side else None,
            "min_correction": float(self.min_correction),
            "max_rms_ratio": float(self.max_rms_ratio),
            "joint_iters": int(self.joint_iters),
            "free_distortion_centre": bool(self.free_distortion_centre),
            "diagnostics": bool(self.diagnostics),
            "looks": tuple(self.looks),
            "weigh_corners": bool(self.weigh_corners),
            "differentiable": bool(self.differentiable),
            "board_flatness": bool(self.board_flatness),
        }
        for name, value in normal.items():
            object.__setattr__(self, name, value)
