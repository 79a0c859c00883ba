"""The composition: images to calibrated cameras through the stages, as one loop over *looks*.

:class:`CalibrationPipeline` (:mod:`.calibration_pipeline`) runs the loop, its options one value (:mod:`.settings`);
its looks are values of :mod:`.looks`; :mod:`.solve` is the solver stage (on :mod:`.solver_input`, the detections as
the solver takes them, built once), :mod:`.result` the typed result, :mod:`.sources` the views (tensors, files, video
frames), :mod:`.workers` the worker processes, :mod:`.rig_pipeline` a rig's cameras and :mod:`.frame_matching` which
views of a rig's cameras were taken together; recordings go through :mod:`.screening` (the quick pass over every
frame), :mod:`.frame_candidates` (the frames the detector sees) and :mod:`.video_input`; a live source's frames
through :mod:`.guided_capture` (which to keep, the predicted figure, the next pose). No command line and no Lightning
here.

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> from ccs_kornia.pipeline import CalibrationPipeline
    >>> CalibrationPipeline.__module__
    'ccs_kornia.pipeline.calibration_pipeline'
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "CalibrationPipeline": "ccs_kornia.pipeline.calibration_pipeline",
    "PipelineResult": "ccs_kornia.pipeline.result",
    "PipelineSettings": "ccs_kornia.pipeline.settings",
    "SolverInput": "ccs_kornia.pipeline.solver_input",
    "FileSource": "ccs_kornia.pipeline.sources",
    "TensorSource": "ccs_kornia.pipeline.sources",
    "VideoSource": "ccs_kornia.pipeline.sources",
    "RigPipeline": "ccs_kornia.pipeline.rig_pipeline",
    "GuidedCapture": "ccs_kornia.pipeline.guided_capture",
    "RigCapture": "ccs_kornia.pipeline.rig_capture",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
