"""Detection stage (paper Sec. III-B): images to corners in grid order.

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> from ccs_kornia.modules.detection import make_detector
    >>> type(make_detector("opencv")).__name__
    'OpenCVChessboardDetector'
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "DetectionResult": "ccs_kornia.modules.detection.base",
    "ChessboardDetector": "ccs_kornia.modules.detection.base",
    "DETECTORS": "ccs_kornia.modules.detection.factory",
    "make_detector": "ccs_kornia.modules.detection.factory",
    "OpenCVChessboardDetector": "ccs_kornia.modules.detection.opencv_detector",
    "check_grid": "ccs_kornia.modules.detection.checks.board_checks",
    "check_saddles": "ccs_kornia.modules.detection.checks.board_checks",
    "board_extends": "ccs_kornia.modules.detection.checks.board_checks",
    "skipped_line": "ccs_kornia.modules.detection.checks.board_checks",
    "whole_board_check": "ccs_kornia.modules.detection.checks.board_checks",
    "CornerEvidence": "ccs_kornia.modules.detection.checks.corner_evidence",
    "measure_corner_evidence": "ccs_kornia.modules.detection.checks.corner_evidence",
    "decide_corners": "ccs_kornia.modules.detection.checks.corner_evidence",
    "board_grid_in": "ccs_kornia.modules.detection.checks.board_size",
    "board_size_in": "ccs_kornia.modules.detection.checks.board_size",
    "other_board_size": "ccs_kornia.modules.detection.checks.board_size",
    "opencv_candidates": "ccs_kornia.modules.detection.learned.opencv_candidates",
    "corner_uncertainty": "ccs_kornia.modules.detection.refine.corner_uncertainty",
    "corner_weights": "ccs_kornia.modules.detection.refine.corner_uncertainty",
    "CornerUncertainty": "ccs_kornia.modules.detection.refine.corner_uncertainty",
    "canonical_corner_order": "ccs_kornia.modules.detection.checks.board_checks",
    "CornerUNet": "ccs_kornia.modules.detection.learned.heatmap_unet",
    "DoubleConv": "ccs_kornia.modules.detection.learned.heatmap_unet",
    "heatmap_peaks": "ccs_kornia.modules.detection.learned.peaks",
    "HeatmapPeaks": "ccs_kornia.modules.detection.learned.peaks",
    "gaussian_fit": "ccs_kornia.modules.detection.learned.gaussian_fit",
    "GaussianFit": "ccs_kornia.modules.detection.learned.gaussian_fit",
    "sigma_outlier_rejection": "ccs_kornia.modules.detection.learned.sigma_rejection",
    "SigmaOutlierRejection": "ccs_kornia.modules.detection.learned.sigma_rejection",
    "organize_grid": "ccs_kornia.modules.detection.grid.grid_organizer",
    "GridOrganizer": "ccs_kornia.modules.detection.grid.grid_organizer",
    "is_symmetric_board": "ccs_kornia.modules.detection.grid.grid_organizer",
    "collinearity_refine": "ccs_kornia.modules.detection.grid.collinearity",
    "CollinearityRefiner": "ccs_kornia.modules.detection.grid.collinearity",
    "predict_missing_corners": "ccs_kornia.modules.detection.grid.missing_corners",
    "grid_spacing": "ccs_kornia.modules.detection.grid.grid_geometry",
    "line_sagitta": "ccs_kornia.modules.detection.grid.grid_geometry",
    "refine_corners": "ccs_kornia.modules.detection.refine.saddle_refine",
    "CornerRefiner": "ccs_kornia.modules.detection.refine.saddle_refine",
    "x_junction_mask": "ccs_kornia.modules.detection.learned.x_junction",
    "symmetry_polish": "ccs_kornia.modules.detection.refine.symmetry_refine",
    "DEFAULT_DETECTOR_WEIGHTS": "ccs_kornia.modules.detection.learned.learned_detector",
    "load_corner_unet": "ccs_kornia.modules.detection.learned.learned_detector",
    "LearnedChessboardDetector": "ccs_kornia.modules.detection.learned.learned_detector",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
