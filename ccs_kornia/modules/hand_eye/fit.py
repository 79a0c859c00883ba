r"""Levenberg–Marquardt on a hand-eye *problem* (:class:`~ccs_kornia.modules.hand_eye.problem.HandEyeProblem`),
batched over problems, with the covariance of the global block at the optimum.

:func:`fit_problem` is what the hand-eye solver calls. Its driver, :func:`_damped_gauss_newton`, is a stand-in for
the package's one Levenberg–Marquardt core (:mod:`~ccs_kornia.modules.calibration.lm`): it exists only until that
core drives problem objects (arrow-structured normal equations and a retraction, as the problem supplies them) and is
to be replaced by it, leaving :func:`fit_problem`'s signature and result as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.geometry.spd_inverse import pseudo_inverse, spd_inverse
from ccs_kornia.modules.hand_eye.problem import HandEyeProblem, HandEyeState, NormalEquations

__all__ = ["FitResult", "fit_problem"]


@dataclass
class FitResult:
    """Output of :func:`fit_problem` (``B`` problems, ``G`` global coordinates)."""

    state: HandEyeState  #: the optimum
    cost: torch.Tensor  #: (B,) weighted sum of squared residuals there
    covariance: torch.Tensor  #: (B, G, G) sigma^2 S^-1, S the global block's Schur complement (items marginalised)
    sigma2: torch.Tensor  #: (B,) cost / degrees of freedom
    iterations: torch.Tensor  #: (B,) int64
    converged: torch.Tensor  #: (B,) bool


def _solve_spd(A: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``A x = b`` for SPD ``A`` :math:`(B, K, K)` with Jacobi scaling; a failed factor gives ``x = 0``."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    L, info = torch.linalg.cholesky_ex(A * (d[..., :, None] * d[..., None, :]))
    bad = info != 0
    L = torch.where(bad[..., None, None], torch.eye(A.shape[-1], dtype=A.dtype, device=A.device), L)
    x = torch.cholesky_solve((b * d)[..., None], L)[..., 0] * d
    return x.masked_fill(bad[..., None] | ~x.isfinite(), 0.0)


def _damped_step(eq: NormalEquations, lam: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The damped Gauss-Newton step ``(dg, dv)``: item blocks eliminated (Schur complement), global block solved."""
    dU = eq.U.diagonal(dim1=-2, dim2=-1)
    dU = torch.maximum(dU, 1e-12 * dU.amax(-1, keepdim=True).clamp_min(1e-300))
    Ud = eq.U + torch.diag_embed(dU * lam[:, None])
    if eq.Vb.shape[1] == 0:
        return _solve_spd(Ud, -eq.g), eq.gv
    Vd = eq.Vb + torch.diag_embed(eq.Vb.diagonal(dim1=-2, dim2=-1) * lam[:, None, None])
    Vinv = torch.linalg.inv_ex(Vd)[0].nan_to_num_(0.0, 0.0, 0.0)
    Y = eq.W @ Vinv  # (B, V, G, 6)
    S = Ud - (Y @ eq.W.transpose(-1, -2)).sum(1)
    dg = _solve_spd(S, -eq.g + (Y @ eq.gv[..., None]).sum(1)[..., 0])
    dv = -(Vinv @ (eq.gv[..., None] + eq.W.transpose(-1, -2) @ dg[:, None, :, None]))[..., 0]
    return dg, dv


def _damped_gauss_newton(problem: HandEyeProblem, state: HandEyeState, max_iters: int = 100, ftol: float = 1e-12,
                         xtol: float = 1e-12, lambda_init: float = 1e-3
                         ) -> tuple[HandEyeState, NormalEquations, torch.Tensor, torch.Tensor]:
    """Levenberg–Marquardt iterations of every problem of the batch (a problem that stopped keeps its values).

    A stand-in for the package's Levenberg–Marquardt core, to be replaced by it (module doc): the damping, the
    acceptance and the stopping rules are the core's (``lambda`` times 10 on a rejected step, divided by 10 on an
    accepted one; stop on a relative decrease below ``ftol``, a step below ``xtol`` relative, or a perfect fit).

    Returns:
        ``(state, normal equations at it, iterations (B,), converged (B,))``.
    """
    eq = problem.normal_equations(state)
    B = eq.cost.shape[0]
    dtype, device = eq.cost.dtype, eq.cost.device
    lam = torch.full((B,), lambda_init, dtype=dtype, device=device)
    done = ~eq.cost.isfinite()
    converged = torch.zeros(B, dtype=torch.bool, device=device)
    iters = torch.zeros(B, dtype=torch.long, device=device)
    floor = (problem.w.sum((1, 2)) * 1e-20).clamp_min(1e-300)
    for _ in range(max_iters):
        if bool(done.all()):
            break
        active = ~done
        dg, dv = _damped_step(eq, lam)
        cand = problem.retract(state, dg, dv)
        new = problem.normal_equations(cand)
        accept = (new.cost < eq.cost) & active
        scale = 1.0 + torch.cat([state.tX, state.tZ, state.params, state.tE.flatten(1)], -1).abs().amax(-1)
        step = torch.cat([dg, dv.flatten(1)], -1).abs().amax(-1)
        finished = (accept & ((eq.cost - new.cost) <= ftol * eq.cost)) | (step <= xtol * scale) | (lam > 1e16)
        finished = active & (finished | (torch.where(accept, new.cost, eq.cost) <= floor))
        state = cand.select(accept, state)
        eq = new.select(accept, eq)
        lam = torch.where(active, torch.where(accept, (lam / 10).clamp_min(1e-15), lam * 10), lam)
        iters = iters + active.long()
        done = done | finished
        converged = converged | finished
    return state, eq, iters, converged


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
    state, eq, iters, converged = _damped_gauss_newton(problem, state, max_iters, ftol, xtol)
    S = eq.U
    if eq.Vb.shape[1]:
        Vinv = spd_inverse(eq.Vb)
        Vinv = torch.where(Vinv.isfinite(), Vinv, torch.zeros_like(Vinv))
        S = S - ((eq.W @ Vinv) @ eq.W.transpose(-1, -2)).sum(1)
    G = S.shape[-1]
    dof = (problem.num_residuals - G - 6 * problem.num_items).clamp_min(1).to(S.dtype)
    sigma2 = eq.cost / dof
    cov = spd_inverse(S)
    singular = ~cov.flatten(1).isfinite().all(-1) & S.flatten(1).isfinite().all(-1)
    if bool(singular.any()):
        cov[singular] = pseudo_inverse(S[singular])
    return FitResult(state, eq.cost, cov * sigma2[:, None, None], sigma2, iters, converged)
