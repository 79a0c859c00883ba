"""The hand-eye problem: its normal equations are the cost's exact gradient and Gauss-Newton matrix (both set-ups, free
intrinsics, the robot-pose noise term, the board's sag), shapes, batch independence, and the fit on exact data."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.lm import parameter_basis
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.hand_eye.fit import fit_problem
from ccs_kornia.modules.hand_eye.problem import HandEyeProblem, HandEyeState


def _problem(setup, model=K1K2, noise=(0.01, 0.002), B=2, V=4, seed=0, free=True, bent=False):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g, dtype=torch.float64)
    m = model
    T = torch.eye(4, dtype=torch.float64).repeat(B, V, 1, 1)
    T[..., :3, :3], T[..., :3, 3] = exp_so3(0.3 * r(B, V, 3)), 0.2 * r(B, V, 3)
    params = torch.tensor([[500.0, 510.0, 320.0, 240.0] + [0.01] * (m.num_params - 4)] * B, dtype=torch.float64)
    obj = board_object_points(4, 3, 0.05, dtype=torch.float64)
    basis = parameter_basis(m, params) if free else None
    prob = HandEyeProblem(setup, m, T, obj, 400 * torch.rand(B, V, 12, 2, generator=g, dtype=torch.float64),
                          0.5 + torch.rand(B, V, 12, generator=g, dtype=torch.float64), basis, noise, bent)
    s = HandEyeState(exp_so3(0.2 * r(B, 3)), 0.1 * r(B, 3), exp_so3(0.2 * r(B, 3)),
                     torch.tensor([[0.0, 0.0, 1.0]] * B, dtype=torch.float64), params, exp_so3(0.01 * r(B, V, 3)),
                     0.003 * r(B, V, 3), 0.002 * r(B, 2))
    return prob, s


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("model", [OPENCV5, FISHEYE], ids=str)
@pytest.mark.parametrize("bent", [False, True], ids=["flat", "bent"])
def test_gradient_is_the_cost_derivative(setup, model, bent):
    prob, s = _problem(setup, model, bent=bent)
    assert prob.num_global == 12 + model.num_params + 2 * bent
    eq = prob.normal_equations(s)
    G, eps = prob.num_global, 1e-6
    fd = torch.zeros_like(eq.g)
    for k in range(G):
        d = torch.zeros_like(eq.g)
        d[:, k] = eps
        fd[:, k] = (prob.cost(prob.retract(s, d)) - prob.cost(prob.retract(s, -d))) / (4 * eps)
    torch.testing.assert_close(fd, eq.g, rtol=1e-6, atol=1e-6 * float(eq.g.abs().max()))
    fdv = torch.zeros_like(eq.gv)
    for v in range(prob.shape[1]):
        for k in range(6):
            d = torch.zeros_like(eq.gv)
            d[:, v, k] = eps
            z = torch.zeros_like(eq.g)
            fdv[:, v, k] = (prob.cost(prob.retract(s, z, d)) - prob.cost(prob.retract(s, z, -d))) / (4 * eps)
    torch.testing.assert_close(fdv, eq.gv, rtol=1e-5, atol=1e-6 * float(eq.gv.abs().max()))
    torch.testing.assert_close(eq.cost, prob.cost(s))


def test_shapes_without_the_noise_term():
    prob, s = _problem("eye_to_hand", noise=None, free=False)
    eq = prob.normal_equations(s)
    assert prob.num_global == 12 and prob.num_items == 0
    assert eq.U.shape == (2, 12, 12) and eq.W.shape == (2, 0, 12, 6) and eq.Vb.shape == (2, 0, 6, 6)
    assert prob.num_residuals.tolist() == [96, 96]


def test_batch_members_are_independent():
    prob, s = _problem("eye_in_hand")
    eq = prob.normal_equations(s)
    one = prob.subset(torch.tensor([1]))
    eq1 = one.normal_equations(HandEyeState(*(x[1:] for x in s)))
    torch.testing.assert_close(eq1.U[0], eq.U[1])
    torch.testing.assert_close(eq1.W[0], eq.W[1])


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_fit_recovers_an_exact_optimum(setup, device):
    prob, truth = _problem(setup, noise=None, free=False, V=6)
    # observations made by the truth itself
    obs = prob.residuals(truth) + prob.obs
    prob = HandEyeProblem(setup, prob.model, prob.robot_poses, prob.obj, obs, torch.ones_like(prob.w))
    start = truth._replace(RX=exp_so3(torch.tensor([0.01, -0.02, 0.01], dtype=torch.float64)) @ truth.RX,
                           tZ=truth.tZ + 0.01)
    fit = fit_problem(prob, start)
    torch.testing.assert_close(fit.state.RX, truth.RX, atol=1e-8, rtol=0)
    torch.testing.assert_close(fit.state.tZ, truth.tZ, atol=1e-8, rtol=0)
    assert bool((fit.status == LMStatus.CONVERGED).all()) and fit.covariance.shape == (2, 12, 12)
