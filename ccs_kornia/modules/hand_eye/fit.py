r"""Levenberg–Marquardt on a hand-eye *problem* (:class:`~ccs_kornia.modules.hand_eye.problem.HandEyeProblem`),
batched over problems, with the covariance of the global block at the optimum: the package's one LM core
(:func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm`) drives it, the robot-pose corrections of the noise term
eliminated as its items.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.modules.calibration.schur_lm import NormalEquations, schur_lm
from ccs_kornia.modules.hand_eye.problem import HandEyeProblem, HandEyeState

__all__ = ["FitResult", "fit_problem"]


@dataclass
class FitResult:
    """Output of :func:`fit_problem` (``B`` problems, ``G`` global coordinates)."""

    state: HandEyeState  #: the optimum
    cost: torch.Tensor  #: (B,) weighted sum of squared residuals there
    covariance: torch.Tensor  #: (B, G, G) sigma^2 S^-1, S the global block's Schur complement (items marginalised)
    sigma2: torch.Tensor  #: (B,) cost / degrees of freedom
    iterations: torch.Tensor  #: (B,) int64
    status: torch.Tensor  #: (B,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus`


class _SchurProblem:
    """A :class:`~ccs_kornia.modules.hand_eye.problem.HandEyeProblem` in the form the LM core takes
    (:class:`~ccs_kornia.modules.calibration.schur_lm.SchurProblem`): the unknowns as a dict of its state's fields, the robot-pose
    corrections as the items (none without the noise term)."""

    def __init__(self, problem: HandEyeProblem) -> None:
        self.problem = problem
        B, V, _ = problem.shape
        data = problem.w.gt(0).any(-1)  # (B, V) views with a weighted corner
        self.used = data if problem.num_items else data[:, :0]
        self.num_residuals = 2 * problem.w.gt(0).sum((1, 2)) + 6 * self.used.sum(-1)
        self.floor = (problem.w.sum((1, 2)) * 1e-20).clamp_min(1e-300)  # an RMS of 1e-10 px: a perfect fit

    def linearize(self, state: dict[str, torch.Tensor]) -> NormalEquations:
        eq = self.problem.normal_equations(HandEyeState(**state))
        return NormalEquations(cost=eq.cost, U=eq.U, eg=eq.g, W=eq.W, V=eq.Vb, ep=eq.gv)

    def retract(self, state: dict[str, torch.Tensor], dg: torch.Tensor, dp: torch.Tensor) -> dict[str, torch.Tensor]:
        return self.problem.retract(HandEyeState(**state), dg, dp)._asdict()

    def scale(self, state: dict[str, torch.Tensor]) -> torch.Tensor:
        sizes = torch.cat([state["tX"], state["tZ"], state["params"], state["tE"].flatten(1)], -1)
        return 1.0 + sizes.abs().amax(-1)

    def take(self, keep: torch.Tensor) -> "_SchurProblem":
        return _SchurProblem(self.problem.subset(keep))


def fit_problem(problem: HandEyeProblem, state: HandEyeState, max_iters: int = 100, ftol: float = 1e-12,
                xtol: float = 1e-12) -> FitResult:
    """Minimise the problem's cost from ``state``; the covariance of the global block at the optimum is
    ``sigma^2 S^{-1}`` (``sigma^2 = cost / dof``, ``S`` the Schur complement of the item blocks; a pseudo-inverse
    where ``S`` is numerically singular: huge, not NaN, variances along the undetermined directions).

    Args:
        problem: :class:`~ccs_kornia.modules.hand_eye.problem.HandEyeProblem`.
        state: the start.
        max_iters, ftol, xtol: as :func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt`.

    Returns:
        :class:`FitResult`.
    """
    res = schur_lm(_SchurProblem(problem), state._asdict(), max_iters=max_iters, ftol=ftol, xtol=xtol)
    return FitResult(HandEyeState(**res.unknowns), res.cost, res.covariance, res.sigma2, res.iterations, res.status)
