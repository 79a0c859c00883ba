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

_EXPORTS = {
    "CalibrationPipeline": "ccs_kornia.pipeline.calibration_pipeline",
    "PipelineResult": "ccs_kornia.pipeline.calibration_pipeline",
    # the camera value and the models it holds (``model=OPENCV5``; ``ModelChoice()`` chooses among models)
    "Camera": "ccs_kornia.geometry.camera",
    "PINHOLE": "ccs_kornia.geometry.models.factory",
    "K1K2": "ccs_kornia.geometry.models.factory",
    "OPENCV5": "ccs_kornia.geometry.models.factory",
    "RATIONAL": "ccs_kornia.geometry.models.factory",
    "FISHEYE": "ccs_kornia.geometry.models.factory",
    "ModelChoice": "ccs_kornia.modules.calibration.model_selection",
}

__all__ = ["__version__", *_EXPORTS]
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
