"""ccs_kornia: camera calibration from chessboard images as a batched PyTorch/Kornia pipeline.

The top-level names are imported lazily (PEP 562), so ``import ccs_kornia.geometry.camera`` loads neither the stages nor
OpenCV.

Example:
    >>> import ccs_kornia
    >>> ccs_kornia.CalibrationPipeline.__module__
    'ccs_kornia.pipeline.calibration_pipeline'
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

__version__ = "0.1.0"

_EXPORTS = {"CalibrationPipeline": "ccs_kornia.pipeline.calibration_pipeline", "PipelineResult": "ccs_kornia.pipeline.calibration_pipeline"}

__all__ = ["__version__", "CalibrationPipeline", "PipelineResult"]
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
