"""Hand-eye calibration: where the camera sits on a robot (and the board in the robot's other frame), from board
corners and robot poses, with an error a user can trust (docs/hand_eye.md).

:class:`HandEyeSolver` / :func:`calibrate_hand_eye` (:mod:`.solver`): the board's pose per view, the checks that refuse
degenerate or disagreeing data (:mod:`.degeneracy`), the closed forms (:mod:`.closed_forms`) as starts, the joint fit
of every corner (:mod:`.problem` on :mod:`.fit`), the leave-one-pose-out figures (:mod:`.heldout`) and the verdict
(:mod:`.result`, with :mod:`.camera_fit`: whether the camera fits its images; :mod:`.target_scale`: whether the board
is the size it was given); :mod:`.setup` names the two set-ups, :mod:`.implicit` gives the gradients.

Names are imported lazily (PEP 562): importing this package loads none of its modules.
"""

from __future__ import annotations

from ccs_kornia.runtime.lazy import lazy_exports

_EXPORTS = {
    "HandEyeSetup": "ccs_kornia.modules.hand_eye.setup",
    "invert_transforms": "ccs_kornia.modules.hand_eye.setup",
    "HandEyeSolver": "ccs_kornia.modules.hand_eye.solver",
    "calibrate_hand_eye": "ccs_kornia.modules.hand_eye.solver",
    "HandEyeResult": "ccs_kornia.modules.hand_eye.result",
    "HandEyeVerdictThresholds": "ccs_kornia.modules.hand_eye.result",
    "hand_eye_verdict": "ccs_kornia.modules.hand_eye.result",
    "HandEyeProblem": "ccs_kornia.modules.hand_eye.problem",
    "HandEyeState": "ccs_kornia.modules.hand_eye.problem",
    "fit_problem": "ccs_kornia.modules.hand_eye.fit",
    "hand_eye_issues": "ccs_kornia.modules.hand_eye.degeneracy",
    "closed_form_candidates": "ccs_kornia.modules.hand_eye.closed_forms",
    "leave_one_pose_out": "ccs_kornia.modules.hand_eye.heldout",
    "board_scale": "ccs_kornia.modules.hand_eye.target_scale",
    "calibrated_view_rms": "ccs_kornia.modules.hand_eye.camera_fit",
    "camera_misfits": "ccs_kornia.modules.hand_eye.result",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
