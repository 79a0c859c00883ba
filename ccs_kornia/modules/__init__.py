"""The stages, each an ``nn.Module`` on batched tensors, one sub-package per stage of the paper (see docs/architecture.md).

``correction/`` (distortion correction), ``detection/`` (corners in grid order), ``calibration/`` (the solver),
``rig/`` (stereo heads and multi-camera rigs), ``hand_eye/`` (a camera on a robot), ``undistort/`` (undistorted images for output). The helpers the
stages share (shape checks, kernels, resizes, folded batch norms) are the private modules beside them.

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> import ccs_kornia.modules as m
    >>> m.CalibrationSolver.__module__
    'ccs_kornia.modules.calibration.solver'
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "BatchedHomography": "ccs_kornia.modules.calibration.homography",
    "CalibrationResult": "ccs_kornia.modules.calibration.result",
    "CalibrationSolver": "ccs_kornia.modules.calibration.solver",
    "ChessboardDetector": "ccs_kornia.modules.detection.base",
    "CollinearityRefiner": "ccs_kornia.modules.detection.grid.collinearity",
    "CornerRefiner": "ccs_kornia.modules.detection.refine.saddle_refine",
    "CornerUNet": "ccs_kornia.modules.detection.learned.heatmap_unet",
    "DetectionResult": "ccs_kornia.modules.detection.base",
    "DistortionNet": "ccs_kornia.modules.correction.distortion_net",
    "GaussianFit": "ccs_kornia.modules.detection.learned.gaussian_fit",
    "GridOrganizer": "ccs_kornia.modules.detection.grid.grid_organizer",
    "HandEyeSolver": "ccs_kornia.modules.hand_eye.solver",
    "HeatmapPeaks": "ccs_kornia.modules.detection.learned.peaks",
    "ImageRansac": "ccs_kornia.modules.calibration.ransac",
    "JointRefinement": "ccs_kornia.modules.calibration.refinement",
    "LearnedChessboardDetector": "ccs_kornia.modules.detection.learned.learned_detector",
    "OpenCVChessboardDetector": "ccs_kornia.modules.detection.opencv_detector",
    "RadialUndistort": "ccs_kornia.modules.correction.radial_warp",
    "SigmaOutlierRejection": "ccs_kornia.modules.detection.learned.sigma_rejection",
    "ZhangInit": "ccs_kornia.modules.calibration.zhang",
    "make_detector": "ccs_kornia.modules.detection.factory",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
