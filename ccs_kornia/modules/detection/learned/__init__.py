"""The learned chessboard detector, step by step: the square size and detection level (:mod:`.scale`), the heatmap
UNet, peaks, Gaussian fit, sigma rejection, the X-junction test, and the last resorts (OpenCV's candidates, the
foreshortened levels); :class:`LearnedChessboardDetector` composes them with the grid, refinement and checks.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "LearnedChessboardDetector": "ccs_kornia.modules.detection.learned.learned_detector",
    "CornerUNet": "ccs_kornia.modules.detection.learned.heatmap_unet",
    "HeatmapPeaks": "ccs_kornia.modules.detection.learned.peaks",
    "GaussianFit": "ccs_kornia.modules.detection.learned.gaussian_fit",
    "SigmaOutlierRejection": "ccs_kornia.modules.detection.learned.sigma_rejection",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
