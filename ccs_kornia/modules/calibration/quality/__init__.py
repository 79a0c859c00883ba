"""Is a calibration good? Coverage of the image, projection uncertainty, degenerate inputs, cross-validation,
held-out error and the verdict.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "check_degeneracy": "ccs_kornia.modules.calibration.quality.degeneracy",
    "DegeneracyThresholds": "ccs_kornia.modules.calibration.quality.degeneracy",
    "projection_uncertainty": "ccs_kornia.modules.calibration.quality.uncertainty",
    "NextBestPose": "ccs_kornia.modules.calibration.quality.next_pose",
    "next_poses": "ccs_kornia.modules.calibration.quality.next_pose",
    "cross_validation": "ccs_kornia.modules.calibration.quality.diagnostics",
    "verdict": "ccs_kornia.modules.calibration.quality.diagnostics",
    "Findings": "ccs_kornia.modules.calibration.quality.verdict",
    "diagnose": "ccs_kornia.modules.calibration.quality.diagnostics",
    "CalibrationDiagnostics": "ccs_kornia.modules.calibration.quality.diagnostics",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
