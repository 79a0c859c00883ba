"""Distortion-correction stage (paper Sec. III-A): the network, the radial warp, pooling (the corrected-frame
calibration is the solver's, :mod:`ccs_kornia.modules.calibration.corrected_frame`; undistortion for output is
:mod:`ccs_kornia.modules.undistort`). Nothing here imports the solver.

Names are imported lazily (PEP 562): importing this package loads none of its modules.

Example:
    >>> from ccs_kornia.modules.correction import corrected_radius
    >>> import torch
    >>> corrected_radius(torch.tensor([[0.5]]), torch.tensor([[1.0, 0.0, 0.2, 0.0, 0.0]]))
    tensor([[0.5250]])
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "DistortionNet": "ccs_kornia.modules.correction.distortion_net",
    "letterbox": "ccs_kornia.modules.correction.distortion_net",
    "correction_from_node_values": "ccs_kornia.modules.correction.distortion_net",
    "CORRECTION_NODES": "ccs_kornia.modules.correction.distortion_net",
    "DEFAULT_DISTORTION_WEIGHTS": "ccs_kornia.modules.correction.distortion_net",
    "load_distortion_net": "ccs_kornia.modules.correction.distortion_net",
    "correct_points": "ccs_kornia.modules.correction.radial_warp",
    "corrected_radius": "ccs_kornia.modules.correction.radial_warp",
    "distort_points_from_correction": "ccs_kornia.modules.correction.radial_warp",
    "invert_correction_radius": "ccs_kornia.modules.correction.radial_warp",
    "radial_undistort_image": "ccs_kornia.modules.correction.radial_warp",
    "RadialUndistort": "ccs_kornia.modules.correction.radial_warp",
    "aggregate_corrections": "ccs_kornia.modules.correction.pooling",
    "correction_displacement": "ccs_kornia.modules.correction.pooling",
    "fit_correction_to_points": "ccs_kornia.modules.correction.correction_fit",
    "straightness_rms": "ccs_kornia.modules.correction.straightness",
    "correction_zoom": "ccs_kornia.modules.correction.radial_warp",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
