"""Calibration stage: homographies, Zhang, RANSAC, the one Levenberg-Marquardt core and its camera models, the solver
composing them, fisheye initialisation and calibration, and the rig solver (stereo and multi-camera rigs).

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> from ccs_kornia.modules.calibration import VIEW_REASONS
    >>> VIEW_REASONS[0]
    'used'
"""

from __future__ import annotations

from ccs_kornia._lazy import lazy_exports

_EXPORTS = {
    "VIEW_REASONS": "ccs_kornia.modules.calibration.result",
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
    "FREE_DISTORTION": "ccs_kornia.modules.calibration.refinement",
    "centred_radial_distort": "ccs_kornia.modules.calibration.centred_radial",
    "radial_from_correction": "ccs_kornia.modules.calibration.centred_radial",
    "radial_from_points": "ccs_kornia.modules.calibration.centred_radial",
    "refine_centred_radial": "ccs_kornia.modules.calibration.centred_radial",
    "LMResult": "ccs_kornia.modules.calibration.lm",
    "levenberg_marquardt": "ccs_kornia.modules.calibration.lm",
    "LevenbergMarquardt": "ccs_kornia.modules.calibration.lm",
    "parameter_basis": "ccs_kornia.modules.calibration.lm",
    "implicit_solution": "ccs_kornia.modules.calibration.implicit",
    "ImplicitSolution": "ccs_kornia.modules.calibration.implicit",
    "CameraModel": "ccs_kornia.modules.calibration.models.base",
    "OpenCVModel": "ccs_kornia.modules.calibration.models.opencv",
    "OPENCV_VARIANTS": "ccs_kornia.modules.calibration.models.opencv",
    "CentredRadialModel": "ccs_kornia.modules.calibration.models.centred_radial",
    "KannalaBrandtModel": "ccs_kornia.modules.calibration.models.fisheye",
    "camera_model": "ccs_kornia.modules.calibration.models.factory",
    "board_to_ray_poses": "ccs_kornia.modules.calibration.fisheye_init",
    "focal_hypotheses": "ccs_kornia.modules.calibration.fisheye_init",
    "init_fisheye": "ccs_kornia.modules.calibration.fisheye_init",
    "FisheyeCalibrationResult": "ccs_kornia.modules.calibration.fisheye_calibration",
    "calibrate_fisheye": "ccs_kornia.modules.calibration.fisheye_calibration",
    "FisheyeCalibrator": "ccs_kornia.modules.calibration.fisheye_calibration",
    "DegeneracyThresholds": "ccs_kornia.modules.calibration.degeneracy",
    "check_degeneracy": "ccs_kornia.modules.calibration.degeneracy",
    "duplicate_views": "ccs_kornia.modules.calibration.duplicates",
    "view_differences": "ccs_kornia.modules.calibration.duplicates",
    "exp_so3": "ccs_kornia.modules.calibration.so3",
    "log_so3": "ccs_kornia.modules.calibration.so3",
    "projection_uncertainty": "ccs_kornia.modules.calibration.uncertainty",
    "cross_validation": "ccs_kornia.modules.calibration.diagnostics",
    "verdict": "ccs_kornia.modules.calibration.diagnostics",
    "diagnose": "ccs_kornia.modules.calibration.diagnostics",
    "CalibrationDiagnostics": "ccs_kornia.modules.calibration.diagnostics",
    "RigCamera": "ccs_kornia.modules.calibration.rig_camera",
    "RigResult": "ccs_kornia.modules.calibration.rig",
    "RigSolver": "ccs_kornia.modules.calibration.rig",
    "calibrate_rig": "ccs_kornia.modules.calibration.rig",
    "RigVerdictThresholds": "ccs_kornia.modules.calibration.rig_diagnostics",
    "rig_verdict": "ccs_kornia.modules.calibration.rig_diagnostics",
    "RigLMResult": "ccs_kornia.modules.calibration.rig_lm",
    "rig_levenberg_marquardt": "ccs_kornia.modules.calibration.rig_lm",
    "StereoPair": "ccs_kornia.modules.calibration.stereo",
    "stereo_pair": "ccs_kornia.modules.calibration.stereo",
    "stereo_rectify": "ccs_kornia.modules.calibration.stereo",
    "epipolar_distances": "ccs_kornia.modules.calibration.stereo",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
