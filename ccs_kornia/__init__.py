"""ccs_kornia: camera calibration from chessboard images as a batched PyTorch/Kornia pipeline."""

from __future__ import annotations

__version__ = "0.1.0"

from ccs_kornia.pipeline import CalibrationPipeline, PipelineResult

__all__ = ["__version__", "CalibrationPipeline", "PipelineResult"]
