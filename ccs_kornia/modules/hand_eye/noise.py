r"""How noisy the corners and the robot's poses are, estimated from the data: variance components.

A hand-eye data set has two kinds of error: the detector's, independent from corner to corner, and the robot's, a
small error of each reported pose that moves all of its view's corners together (joint encoders, elasticity,
kinematic calibration; millimetres on many arms). Weighing them right is what makes the fit accurate and its
covariance honest, and neither is known beforehand. :func:`fit_with_noise_estimate` fits with the robot-pose noise
term of :class:`~ccs_kornia.modules.hand_eye.problem.HandEyeProblem` and re-estimates the three variances -- the
corners', the poses' rotation and translation -- from the fit's residuals by Helmert's variance-component estimation:
each group's weighted sum of squares divided by its share of the redundancy,

.. math::
    \hat\sigma_k^2 = \sigma_k^2 \, \frac{v_k^T P_k v_k}{r_k}, \qquad r_k = n_k - \operatorname{tr}(N^{-1} N_k),

(``N`` the full normal matrix, every view's correction included; ``N_k`` group ``k``'s part of it), refitting until
the variances settle. On a robot whose poses are exact the poses' sigmas shrink to their floor and the fit is the
plain one.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.geometry.spd_inverse import pseudo_inverse, spd_inverse
from ccs_kornia.modules.hand_eye.fit import FitResult, fit_problem
from ccs_kornia.modules.hand_eye.problem import HandEyeProblem, HandEyeState

__all__ = ["NOISE_FLOOR", "NoiseEstimate", "fit_with_noise_estimate", "variance_factors"]

#: the smallest robot-pose sigmas the estimate may reach: (radians, the poses' unit)
NOISE_FLOOR = (1e-6, 1e-7)


@dataclass
class NoiseEstimate:
    """The fit with the estimated variances (``B`` problems)."""

    fit: FitResult
    problem: HandEyeProblem  #: the problem reweighted with them
    pixel_sigma: torch.Tensor  #: (B,) the corners' sigma, px (for unit weights; else the weights' scale)
    robot_noise: torch.Tensor  #: (B, 2) the poses' sigma: rotation (radians), translation (the poses' unit)
    rounds: int


def variance_factors(problem: HandEyeProblem, state: HandEyeState) -> torch.Tensor:
    """Helmert's factors :math:`(B, 3)` of the corners', the poses' rotation and translation variances at ``state``
    (module doc): 1 where the current variances fit the residuals."""
    eq = problem.normal_equations(state)
    B, V, _ = problem.shape
    G = eq.U.shape[-1]
    # the item blocks of N^-1 from the arrow structure: V_v^-1 + V_v^-1 W_v^T S^-1 W_v V_v^-1, S = U - sum W V^-1 W^T
    Vinv = spd_inverse(eq.Vb)
    Vinv = torch.where(Vinv.isfinite(), Vinv, torch.zeros_like(Vinv))
    Y = eq.W @ Vinv  # (B, V, G, 6)
    S = eq.U - (Y @ eq.W.transpose(-1, -2)).sum(1)
    Sinv = spd_inverse(S)
    bad = ~Sinv.flatten(1).isfinite().all(-1)
    if bool(bad.any()):
        Sinv[bad] = pseudo_inverse(S[bad])
    blocks = Vinv + Y.transpose(-1, -2) @ Sinv[:, None] @ Y  # (B, V, 6, 6)
    d = blocks.diagonal(dim1=-2, dim2=-1)
    inv2 = problem.prior_scale ** 2  # (B, 6)
    tr = (d * inv2[:, None]).sum(1)  # (B, 6)
    tr_r, tr_t = tr[:, :3].sum(-1), tr[:, 3:].sum(-1)
    r = torch.where(problem.w[..., None] > 0, problem.residuals(state), 0.0)
    omega_px = (problem.w[..., None] * r * r).sum((1, 2, 3))
    prior = torch.cat([log_so3(state.RE), state.tE], -1) * problem.prior_scale[:, None]
    omega_r, omega_t = (prior[..., :3] ** 2).sum((1, 2)), (prior[..., 3:] ** 2).sum((1, 2))
    n_px = 2 * (problem.w > 0).sum((1, 2)).to(S.dtype)
    red_px = n_px - (G + 6 * V - tr_r - tr_t)
    red_r, red_t = 3 * V - tr_r, 3 * V - tr_t
    floor = 1e-3 * 3 * V
    return torch.stack([omega_px / red_px.clamp_min(floor), omega_r / red_r.clamp_min(floor),
                        omega_t / red_t.clamp_min(floor)], -1)


def fit_with_noise_estimate(problem: HandEyeProblem, state: HandEyeState, start_noise: torch.Tensor,
                            rounds: int = 12, tol: float = 0.05, max_iters: int = 100,
                            round_iters: int = 10) -> NoiseEstimate:
    """Fit with the noise term, re-estimating the corners' and the poses' variances between fits (module doc).

    Args:
        problem: the problems (their weights give the corners' relative variances; the noise term is replaced).
        state: the start.
        start_noise: :math:`(B, 2)` the poses' sigmas to start from (radians, the poses' unit).
        rounds: fits at most.
        tol: stop when every variance changed by less than this (relative).
        max_iters: iterations of the first and the last fit.
        round_iters: iterations of the fits between (each starts where the last one ended).

    Returns:
        :class:`NoiseEstimate`.
    """
    B = problem.shape[0]
    dtype, device = problem.w.dtype, problem.w.device
    pix = torch.ones(B, dtype=dtype, device=device)
    noise = start_noise.to(dtype).reshape(B, 2).clone()
    floor = torch.tensor(NOISE_FLOOR, dtype=dtype, device=device)
    base = problem
    current = base.reweighted(pix, noise)
    fit = fit_problem(current, state, max_iters=max_iters)
    k = 0
    for k in range(1, rounds):
        f = variance_factors(current, fit.state)
        f = torch.where(f.isfinite() & (f > 0), f, torch.ones_like(f))
        pix = pix * f[:, 0]
        new = torch.maximum(noise * f[:, 1:].sqrt(), floor)
        # settled: every factor near 1, or a sigma held at its floor
        settled = ((f - 1).abs() < tol) | torch.cat([torch.zeros_like(f[:, :1], dtype=torch.bool),
                                                     (new <= floor) & (f[:, 1:] < 1)], -1)
        noise = new
        current = base.reweighted(pix, noise)
        last = bool(settled.all()) or k == rounds - 1
        fit = fit_problem(current, fit.state, max_iters=max_iters if last else round_iters)
        if last:
            break
    return NoiseEstimate(fit, current, pix.sqrt(), noise, k + 1)
