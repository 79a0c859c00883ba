"""Rig calibration: stereo heads and multi-camera rigs from board corners, batched over rigs (docs/rig.md).

:class:`RigSolver` (:mod:`.rig_solver`) initialises each camera alone and the relative poses over a spanning tree
(:mod:`.rig_init`), then fits intrinsics (each held by a prior from its own views), extrinsics and one board pose per
frame jointly (:mod:`.rig_lm`; the rig's unknowns and the corners it explains are two values, :mod:`.rig_state`),
frames weighted by how well one board pose explains them (:mod:`.frame_consistency`); :mod:`.rig_diagnostics` gives
the epipolar figures and the verdict, :mod:`.session_advice` what to record next, :mod:`.stereo` a pair's geometry.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "RigResult": "ccs_kornia.modules.rig.rig_solver",
    "RigSolver": "ccs_kornia.modules.rig.rig_solver",
    "calibrate_rig": "ccs_kornia.modules.rig.rig_solver",
    "RigVerdictThresholds": "ccs_kornia.modules.rig.rig_diagnostics",
    "rig_verdict": "ccs_kornia.modules.rig.rig_diagnostics",
    "RigLMResult": "ccs_kornia.modules.rig.rig_lm",
    "RigObservations": "ccs_kornia.modules.rig.rig_state",
    "RigState": "ccs_kornia.modules.rig.rig_state",
    "rig_levenberg_marquardt": "ccs_kornia.modules.rig.rig_lm",
    "FrameKernel": "ccs_kornia.modules.rig.frame_consistency",
    "frame_disagreement": "ccs_kornia.modules.rig.frame_consistency",
    "session_advice": "ccs_kornia.modules.rig.session_advice",
    "StereoPair": "ccs_kornia.modules.rig.stereo",
    "stereo_pair": "ccs_kornia.modules.rig.stereo",
    "stereo_rectify": "ccs_kornia.modules.rig.stereo",
    "epipolar_distances": "ccs_kornia.modules.rig.stereo",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
