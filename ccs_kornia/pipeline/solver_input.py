"""What the solver takes of a run's detections, built once: :class:`SolverInput`.

Every solve of a run (the calibration per image size, the model selection, the diagnostics, the differentiable
solve, :meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.calibrate`) takes the same input: the
corners of the views a solve uses (a board found on an image of its camera's size:
:attr:`~ccs_kornia.pipeline.result.PipelineResult.usable_views`), which of their corners were measured
(:func:`~ccs_kornia.modules.detection.base.measured_corners`: a partial board's hidden corners left out), the
weights the corners' measured precision gives them
(:func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_weights`, relative to each camera's median) and
the board's points. It is made once from the detections and passed; a group of cameras takes its rows
(:meth:`SolverInput.cameras`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from ccs_kornia.modules.detection.base import measured_corners
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_weights
from ccs_kornia.pipeline.result import PipelineResult

__all__ = ["SolverInput"]


@dataclass(frozen=True)
class SolverInput:
    r"""The solver's input for ``C`` cameras of ``V`` views of a board of ``N`` corners.

    Attributes:
        corners: :math:`(C, V, N, 2)` float64 pixels in grid order.
        usable: :math:`(C, V)` bool, the views the solve takes.
        valid: :math:`(C, V, N)` bool, the measured corners of those views.
        weights: :math:`(C, V, N)` float64 per-corner weights from the corners' precision (0 where not valid;
            ``None``: every corner counts alike).
        object_points: :math:`(N, 3)` float64 board points.

    Example:
        >>> from ccs_kornia.modules.detection.boards import grid_object_points
        >>> corners = torch.rand(2, 3, 12, 2, dtype=torch.float64)
        >>> corners[0, 1, 5] = float("nan")  # a hidden corner of a partial board
        >>> sigma = torch.full((2, 3, 12), 0.05)
        >>> obj = grid_object_points(None, (4, 3), 0.1)
        >>> inputs = SolverInput.from_views(corners, torch.ones(2, 3, dtype=torch.bool), obj, sigma)
        >>> int(inputs.valid.sum()), float(inputs.weights[0, 1, 5]), inputs.cameras(torch.tensor([1])).corners.shape
        (71, 0.0, torch.Size([1, 3, 12, 2]))
    """

    corners: torch.Tensor
    usable: torch.Tensor
    valid: torch.Tensor
    weights: torch.Tensor | None
    object_points: torch.Tensor

    @classmethod
    def from_corners(cls, corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
                     sigma: torch.Tensor | None = None, usable: torch.Tensor | None = None) -> SolverInput:
        """The input of corners whose ``valid`` :math:`(C, V, N)` mask is given; ``sigma`` :math:`(C, V, N)`: the
        corners' measured precision (``None``: no weights); ``usable`` :math:`(C, V)`: the views (``None``: those
        with a valid corner)."""
        valid = valid.bool()
        usable = valid.any(-1) if usable is None else usable.bool()
        weights = None if sigma is None else corner_weights(sigma.to(valid.device), valid)
        return cls(corners.to(torch.float64), usable, valid, weights, object_points.to(torch.float64))

    @classmethod
    def from_views(cls, corners: torch.Tensor, usable: torch.Tensor, object_points: torch.Tensor,
                   sigma: torch.Tensor | None = None) -> SolverInput:
        """The input of the views ``usable`` :math:`(C, V)`: their measured (finite) corners."""
        return cls.from_corners(corners, measured_corners(corners, usable.bool()), object_points, sigma, usable)

    @classmethod
    def from_result(cls, out: PipelineResult, object_points: torch.Tensor, weigh: bool = True) -> SolverInput:
        """The input of a batched run's detections: its usable views
        (:attr:`~ccs_kornia.pipeline.result.PipelineResult.usable_views`), weighted by the corners' precision where
        ``weigh`` and the detections carry one."""
        det = out.detections
        return cls.from_views(det.corners, out.usable_views, object_points, det.sigma if weigh else None)

    def cameras(self, idx: torch.Tensor) -> SolverInput:
        """Cameras ``idx`` :math:`(K,)` (long) of this input."""
        idx = idx.to(self.corners.device)
        return SolverInput(self.corners[idx], self.usable[idx], self.valid[idx],
                           None if self.weights is None else self.weights[idx], self.object_points)

    def solve(self, solver: Any, image_size: tuple[int, int], **kwargs: Any) -> Any:
        """``solver(corners, valid, object_points, image_size, weights=weights, **kwargs)``: a
        :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` or a
        :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection` on this input."""
        return solver(self.corners, self.valid, self.object_points, image_size, weights=self.weights, **kwargs)
