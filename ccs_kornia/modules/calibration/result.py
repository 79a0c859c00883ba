"""What the calibration solver returns: :class:`CalibrationResult` and why a view was not used (:class:`ViewReason`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import Any, Callable

import torch

from ccs_kornia.geometry.camera import Camera

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
    """Calibration of C cameras from V views each (the C dim is absent from the per-view and per-camera tensors for
    unbatched input; :attr:`camera` always holds the cameras, one for unbatched input)."""

    camera: Camera  #: the C cameras (their models, parameters and image size)
    rvec: torch.Tensor  #: (C, V, 3) world-to-camera axis-angle per view
    tvec: torch.Tensor  #: (C, V, 3)
    view_rms: torch.Tensor  #: (C, V) px, NaN for views not used
    used: torch.Tensor  #: (C, V) bool
    rms: torch.Tensor  #: (C,) OpenCV's definition: sqrt(sum squared error / number of points) over used views
    std_intrinsics: torch.Tensor  #: (C, 4) std of fx, fy, cx, cy
    std_dist: torch.Tensor  #: (C, D)
    success: torch.Tensor  #: (C,) bool
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
    #: (C, 2) the board's sag (mrcal's ``calobject_warp``: :math:`c_x, c_y` in the board's units,
    #: :mod:`~ccs_kornia.geometry.board_warp`) where the solve estimated it, else None (a flat board)
    board_warp: torch.Tensor | None = None
    std_board_warp: torch.Tensor | None = None  #: (C, 2) its 1-sigma
    # whether the model fits: the residuals' structure over the image (quality/residual_structure.py)
    #: (C,) int64 :class:`~ccs_kornia.modules.calibration.quality.residual_structure.ModelFit`: 0 the model fits, 1 its
    #: residuals are structured, 2 it does not fit (residuals mostly its error: ``success`` alone does not say it)
    model_fit: torch.Tensor | None = None
    structure_cells: torch.Tensor | None = None  #: (C,) int64 image cells judged (6 x 4 grid)
    structure_rms: torch.Tensor | None = None  #: (C,) px, RMS of the cells' mean residuals
    structure_significant: torch.Tensor | None = None  #: (C,) int64 cells whose mean is beyond its standard error
    structure_worst: torch.Tensor | None = None  #: (C,) px, the longest cell mean
    structure_median: torch.Tensor | None = None  #: (C,) px, the median residual length
    structure_noise: torch.Tensor | None = None  #: (C,) px, the corners' noise measured on the board (same scale)

    def residual_structure(self, camera: int = 0) -> dict | None:
        """One camera's residual structure and model-fit flag as JSON (``None`` where not computed)."""
        if self.model_fit is None:
            return None
        from ccs_kornia.modules.calibration.quality.residual_structure import ModelFit

        def pick(t):
            return t if t.dim() == 0 else t[camera]

        def num(t):
            x = float(pick(t))
            return x if math.isfinite(x) else None

        fit = ModelFit(int(pick(self.model_fit)))
        median, noise = num(self.structure_median), num(self.structure_noise)
        return {"model_fit": fit.label, "message": fit.message, "grid": [6, 4],
                "cells": int(pick(self.structure_cells)), "rms_cell_means_px": num(self.structure_rms),
                "cells_significant": int(pick(self.structure_significant)),
                "worst_cell_px": num(self.structure_worst), "median_residual_px": median, "corner_noise_px": noise,
                "noise_ratio": None if median is None or not noise else median / noise}

    @property
    def batched(self) -> bool:
        """Whether the per-view tensors have the camera dimension first."""
        return self.used.dim() == 2

    @property
    def K(self) -> torch.Tensor:
        """:math:`(C, 3, 3)` camera matrices (:math:`(3, 3)` unbatched)."""
        return self.camera.K if self.batched else self.camera.K[0]

    @property
    def dist(self) -> torch.Tensor:
        """:math:`(C, D)` coefficients in OpenCV's layout (:math:`(D,)` unbatched; cameras of several models:
        NaN-padded to the widest)."""
        return self.camera.dist if self.batched else self.camera.dist[0]

    def issues(self) -> list[list[dict]]:
        """Per camera, the warnings and errors of the degeneracy checks as JSON-able dicts
        ``{"check", "severity", "message", "advice", "views"}`` (one list per camera, also for an unbatched result)."""
        if self.check_severity is None:
            return [[] for _ in range(len(self.camera) if self.batched else 1)]
        from ccs_kornia.modules.calibration.quality.degeneracy import (
            issues_from_tensors,
        )

        return issues_from_tensors(self.check_severity, self.check_value, self.check_views)

    def tensors(self) -> dict[str, torch.Tensor]:
        """The tensor fields by name (the camera's parameters as ``camera_params``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), torch.Tensor)}
        return {"camera_params": self.camera.params, **out}

    def map_tensors(self, fn: Callable[[torch.Tensor], Any], camera: Callable[[Camera], Camera] | None = None
                    ) -> CalibrationResult:
        """A result with ``fn`` applied to every tensor field and ``camera`` (default: unchanged) to the cameras,
        e.g. ``result.map_tensors(lambda t: t[None])`` to add the camera dimension."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values = {k: (fn(v) if isinstance(v, torch.Tensor) else v) for k, v in values.items()}
        values["camera"] = camera(self.camera) if camera is not None else self.camera
        return type(self)(**values)
