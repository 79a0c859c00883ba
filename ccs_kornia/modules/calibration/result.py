"""What the calibration solver returns: :class:`CalibrationResult` and the codes of why a view was not used."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch

__all__ = ["VIEW_REASONS", "CalibrationResult"]

#: codes of ``CalibrationResult.view_reason``
VIEW_REASONS: dict[int, str] = {
    0: "used",
    1: "too few corners",
    2: "homography failed (degenerate corners)",
    3: "rejected by image RANSAC",
    4: "reprojection error outlier after refinement",
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
    view_reason: torch.Tensor  #: (C, V) int64, keys of VIEW_REASONS
    converged: torch.Tensor  #: (C,) bool, LM met its tolerance
    candidate_rms: torch.Tensor  #: (C, V) px: every view with a homography under the final model (used or not)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), torch.Tensor)}
