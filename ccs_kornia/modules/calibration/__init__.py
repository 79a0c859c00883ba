"""Calibration stage: homographies, Zhang, RANSAC, the one Levenberg-Marquardt core (:mod:`.schur_lm`) and the camera
on it (:mod:`.lm`), the outlier rule, the solver composing them, fisheye initialisation and calibration, the
calibration in the radially corrected frame (:mod:`.corrected_frame`, on :mod:`ccs_kornia.modules.correction`'s
warp); the quality of
a calibration in :mod:`.quality` (the camera models are in :mod:`ccs_kornia.geometry.models`, rigs in
:mod:`ccs_kornia.modules.rig`).

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> from ccs_kornia.modules.calibration import VIEW_REASONS
    >>> VIEW_REASONS[0]
    'used'
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "VIEW_REASONS": "ccs_kornia.modules.calibration.result",
    "ViewReason": "ccs_kornia.modules.calibration.result",
    "CalibrationResult": "ccs_kornia.modules.calibration.result",
    "CalibrationSolver": "ccs_kornia.modules.calibration.solver",
    "calibrate": "ccs_kornia.modules.calibration.solver",
    "MIN_HOMOGRAPHY_POINTS": "ccs_kornia.modules.calibration.homography",
    "find_homographies": "ccs_kornia.modules.calibration.homography",
    "BatchedHomography": "ccs_kornia.modules.calibration.homography",
    "zhang_intrinsics": "ccs_kornia.modules.calibration.zhang",
    "extrinsics_from_homography": "ccs_kornia.modules.calibration.zhang",
    "rotation_translation_from_homography": "ccs_kornia.modules.calibration.zhang",
    "ZhangInit": "ccs_kornia.modules.calibration.zhang",
    "hypothesis_view_rms": "ccs_kornia.modules.calibration.ransac",
    "image_ransac": "ccs_kornia.modules.calibration.ransac",
    "ImageRansac": "ccs_kornia.modules.calibration.ransac",
    "RefinementResult": "ccs_kornia.modules.calibration.refinement",
    "joint_refinement": "ccs_kornia.modules.calibration.refinement",
    "JointRefinement": "ccs_kornia.modules.calibration.refinement",
    "DIVISION_RANGE": "ccs_kornia.modules.calibration.radial_guess",
    "radial_from_views": "ccs_kornia.modules.calibration.radial_guess",
    "radial_polynomial_from_division": "ccs_kornia.modules.calibration.radial_guess",
    "centred_radial_distort": "ccs_kornia.modules.calibration.centred_radial",
    "radial_from_correction": "ccs_kornia.modules.calibration.centred_radial",
    "radial_from_points": "ccs_kornia.modules.calibration.centred_radial",
    "refine_centred_radial": "ccs_kornia.modules.calibration.centred_radial",
    "LM_STATUS_MESSAGES": "ccs_kornia.modules.calibration.schur_lm",
    "LMState": "ccs_kornia.modules.calibration.schur_lm",
    "LMStatus": "ccs_kornia.modules.calibration.schur_lm",
    "NormalEquations": "ccs_kornia.modules.calibration.schur_lm",
    "solve_with_correction": "ccs_kornia.modules.calibration.corrected_frame",
    "calibrate_corrected": "ccs_kornia.modules.calibration.corrected_frame",
    "select_cameras": "ccs_kornia.modules.calibration.corrected_frame",
    "SchurProblem": "ccs_kornia.modules.calibration.schur_lm",
    "SchurLMResult": "ccs_kornia.modules.calibration.schur_lm",
    "schur_lm": "ccs_kornia.modules.calibration.schur_lm",
    "schur_step": "ccs_kornia.modules.calibration.schur_lm",
    "drop_outliers": "ccs_kornia.modules.calibration.outliers",
    "LMResult": "ccs_kornia.modules.calibration.lm",
    "levenberg_marquardt": "ccs_kornia.modules.calibration.lm",
    "LevenbergMarquardt": "ccs_kornia.modules.calibration.lm",
    "parameter_basis": "ccs_kornia.modules.calibration.lm",
    "implicit_solution": "ccs_kornia.modules.calibration.implicit",
    "ImplicitSolution": "ccs_kornia.modules.calibration.implicit",
    "board_to_ray_poses": "ccs_kornia.modules.calibration.fisheye_init",
    "focal_hypotheses": "ccs_kornia.modules.calibration.fisheye_init",
    "init_fisheye": "ccs_kornia.modules.calibration.fisheye_init",
    "FisheyeCalibrationResult": "ccs_kornia.modules.calibration.fisheye_calibration",
    "calibrate_fisheye": "ccs_kornia.modules.calibration.fisheye_calibration",
    "FisheyeCalibrator": "ccs_kornia.modules.calibration.fisheye_calibration",
    "DegeneracyThresholds": "ccs_kornia.modules.calibration.quality.degeneracy",
    "check_degeneracy": "ccs_kornia.modules.calibration.quality.degeneracy",
    "duplicate_views": "ccs_kornia.modules.calibration.duplicates",
    "view_differences": "ccs_kornia.modules.calibration.duplicates",
    "projection_uncertainty": "ccs_kornia.modules.calibration.quality.uncertainty",
    "cross_validation": "ccs_kornia.modules.calibration.quality.diagnostics",
    "verdict": "ccs_kornia.modules.calibration.quality.diagnostics",
    "diagnose": "ccs_kornia.modules.calibration.quality.diagnostics",
    "CalibrationDiagnostics": "ccs_kornia.modules.calibration.quality.diagnostics",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
