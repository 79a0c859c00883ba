"""The stages, each an ``nn.Module`` on batched tensors (see docs/architecture.md)."""

from __future__ import annotations

from ccs_kornia.modules.calibrator import CalibrationResult, CalibrationSolver
from ccs_kornia.modules.corner_refine import CornerRefiner
from ccs_kornia.modules.detector import ChessboardDetector, DetectionResult, OpenCVChessboardDetector, make_detector
from ccs_kornia.modules.distortion_net import DistortionNet
from ccs_kornia.modules.grid import CollinearityRefiner, GridOrganizer
from ccs_kornia.modules.heatmap_unet import CornerUNet
from ccs_kornia.modules.homography import BatchedHomography
from ccs_kornia.modules.learned_detector import LearnedChessboardDetector
from ccs_kornia.modules.ransac import ImageRansac
from ccs_kornia.modules.refine import JointRefinement
from ccs_kornia.modules.subpixel import GaussianFit, HeatmapPeaks, SigmaOutlierRejection
from ccs_kornia.modules.undistort import RadialUndistort
from ccs_kornia.modules.zhang import ZhangInit

__all__ = [
    "BatchedHomography",
    "CalibrationResult",
    "CalibrationSolver",
    "ChessboardDetector",
    "CollinearityRefiner",
    "CornerRefiner",
    "CornerUNet",
    "DetectionResult",
    "DistortionNet",
    "GaussianFit",
    "GridOrganizer",
    "HeatmapPeaks",
    "ImageRansac",
    "JointRefinement",
    "LearnedChessboardDetector",
    "OpenCVChessboardDetector",
    "RadialUndistort",
    "SigmaOutlierRejection",
    "ZhangInit",
    "make_detector",
]
