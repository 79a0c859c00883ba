"""What the calibration solver returns: :class:`CalibrationResult` and why a view was not used (:class:`ViewReason`)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum

import torch

__all__ = ["VIEW_REASONS", "ViewReason", "CalibrationResult"]


class ViewReason(IntEnum):
    """Why the solver did not use a view: the values of ``CalibrationResult.view_reason`` (an int64 tensor, so a
    member compares with its entries: ``result.view_reason == ViewReason.OUTLIER``).

    Example:
        >>> ViewReason(4), ViewReason.OUTLIER.message
        (<ViewReason.OUTLIER: 4>, 'reprojection error outlier after refinement')
    """

    USED = 0
    TOO_FEW_CORNERS = 1
    NO_HOMOGRAPHY = 2
    RANSAC_REJECTED = 3
    OUTLIER = 4
    DUPLICATE = 5

    @property
    def message(self) -> str:
        """The reason in words (the records' ``reason`` of a view)."""
        return VIEW_REASONS[self]


#: each :class:`ViewReason` in words
VIEW_REASONS: dict[int, str] = {
    ViewReason.USED: "used",
    ViewReason.TOO_FEW_CORNERS: "too few corners",
    ViewReason.NO_HOMOGRAPHY: "homography failed (degenerate corners)",
    ViewReason.RANSAC_REJECTED: "rejected by image RANSAC",
    ViewReason.OUTLIER: "reprojection error outlier after refinement",
    ViewReason.DUPLICATE: "copy of an earlier view (not an independent observation)",
}


@dataclass
class CalibrationResult:
    """Calibration of C cameras from V views each (the C dim is absent for unbatched input)."""

    K: torch.Tensor  #: (C, 3, 3)
    dist: torch.Tensor  #: (C, D) OpenCV order (k1, k2, p1, p2, k3[, k4, k5, k6])
    rvec: torch.Tensor  #: (C, V, 3) world-to-camera axis-angle per view
    tvec: torch.Tensor  #: (C, V, 3)
    view_rms: torch.Tensor  #: (C, V) px, NaN for views not used
    used: torch.Tensor  #: (C, V) bool
    rms: torch.Tensor  #: (C,) OpenCV's definition: sqrt(sum squared error / number of points) over used views
    std_intrinsics: torch.Tensor  #: (C, 4) std of fx, fy, cx, cy
    std_dist: torch.Tensor  #: (C, D)
    success: torch.Tensor  #: (C,) bool
    model: str
    view_reason: torch.Tensor  #: (C, V) int64, :class:`ViewReason` values
    #: (C,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus` values: how the final LM of each camera
    #: ended (``success`` says whether the camera is usable)
    lm_status: torch.Tensor
    candidate_rms: torch.Tensor  #: (C, V) px: every view with a homography under the final model (used or not)
    # covariance and degeneracy checks; see modules/calibration/quality/degeneracy.py
    cov_camera: torch.Tensor | None = None  #: (C, 4 + D, 4 + D) covariance of (fx, fy, cx, cy, dist)
    check_severity: torch.Tensor | None = None  #: (C, K) int64 per degeneracy.CHECKS: 0 ok, 1 warning, 2 error
    check_value: torch.Tensor | None = None  #: (C, K) float64 measured value of each check
    check_views: torch.Tensor | None = None  #: (C, K, V) bool, views each check names

    def issues(self) -> list[list[dict]]:
        """Per camera, the warnings and errors of the degeneracy checks as JSON-able dicts
        ``{"check", "severity", "message", "advice", "views"}`` (one list per camera, also for an unbatched result)."""
        if self.check_severity is None:
            return [[] for _ in range(1 if self.K.dim() == 2 else self.K.shape[0])]
        from ccs_kornia.modules.calibration.quality.degeneracy import (
            issues_from_tensors,
        )

        return issues_from_tensors(self.check_severity, self.check_value, self.check_views)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), torch.Tensor)}
