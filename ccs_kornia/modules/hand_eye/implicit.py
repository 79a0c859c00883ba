r"""Gradients of a hand-eye optimum by implicit differentiation (as :mod:`~ccs_kornia.modules.calibration.implicit`
gives the single-camera solver's): no unrolled iterations.

At the optimum :math:`z^* = 0` of the fit's cost :math:`F(z; c, T)` in the solver's coordinates (left increments of
``X`` and ``Z``, the free intrinsics, the robot-pose corrections of the noise term) the gradient
:math:`g = \partial F / \partial z` vanishes for every input, so

.. math::
    \frac{d z^*}{d c} = -H^{-1} \frac{\partial g}{\partial c}, \qquad H = \frac{\partial g}{\partial z},

with ``c`` the corners and ``T`` the robot poses. A backward pass solves one system :math:`H u = \bar z` (the output
gradients in those coordinates) and returns :math:`-u^T \partial g / \partial (c, T)` by one vector-Jacobian product.
``H`` is the exact Hessian (the gradient differentiated by autograd, one row per coordinate). Everything decided
before the optimum (the start, the views used, the estimated noise sigmas and weights) is a constant of the backward
pass.
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.so3 import skew
from ccs_kornia.modules.hand_eye.problem import (
    GLOBAL_POSE_PARAMS,
    HandEyeProblem,
    HandEyeState,
)

__all__ = ["attach_gradients", "hand_eye_cost"]


def _perturbed(problem: HandEyeProblem, s: HandEyeState, z: torch.Tensor) -> HandEyeState:
    """The state moved by ``z`` :math:`(B, D)` to first order (all the derivatives at ``z = 0`` need)."""
    eye = torch.eye(3, dtype=z.dtype, device=z.device)
    RX = (eye + skew(z[:, 0:3])) @ s.RX
    RZ = (eye + skew(z[:, 6:9])) @ s.RZ
    params = s.params
    G = problem.num_global
    if problem.basis is not None:
        params = params + (problem.basis @ z[:, GLOBAL_POSE_PARAMS:G, None])[..., 0]
    RE, tE = s.RE, s.tE
    if problem.num_items:
        dv = z[:, G:].reshape(z.shape[0], -1, 6)
        RE = (eye + skew(dv[..., :3])) @ RE
        tE = tE + dv[..., 3:]
    return HandEyeState(RX, s.tX + z[:, 3:6], RZ, s.tZ + z[:, 9:12], params, RE, tE, s.warp)


def hand_eye_cost(problem: HandEyeProblem, s: HandEyeState, z: torch.Tensor) -> torch.Tensor:
    """:math:`(B,)` half the fit's cost at the state moved by ``z`` (differentiable in ``z`` and in the problem's
    corners and robot poses)."""
    s = _perturbed(problem, s, z)
    r = torch.where(problem.w[..., None] > 0, problem.residuals(s), 0.0)
    c = (problem.w[..., None] * r * r).sum((1, 2, 3))
    if problem.noise is not None:
        # log(R_E) as the skew part of R_E: exact to first order about the identity, where the corrections (a robot's
        # pose error) are
        RE = s.RE
        w = 0.5 * torch.stack([RE[..., 2, 1] - RE[..., 1, 2], RE[..., 0, 2] - RE[..., 2, 0],
                               RE[..., 1, 0] - RE[..., 0, 1]], -1)
        c = c + ((torch.cat([w, s.tE], -1) * problem.prior_scale[:, None]) ** 2).sum((1, 2))
    return 0.5 * c


class _Implicit(torch.autograd.Function):
    @staticmethod
    def forward(ctx, corners, robot_poses, X, Z, params, problem, state):
        ctx.problem, ctx.state = problem, state
        ctx.save_for_backward(corners, robot_poses)
        return X.clone(), Z.clone(), params.clone()

    @staticmethod
    def backward(ctx, gX, gZ, gP):
        corners, robot_poses = ctx.saved_tensors
        problem, s = ctx.problem, ctx.state
        B = corners.shape[0]
        G = problem.num_global
        D = G + 6 * problem.num_items
        dtype = s.RX.dtype
        gX = torch.zeros(B, 4, 4, dtype=dtype, device=s.RX.device) if gX is None else gX.to(dtype)
        gZ = torch.zeros(B, 4, 4, dtype=dtype, device=s.RX.device) if gZ is None else gZ.to(dtype)
        # the output gradients in the solver's coordinates: d X / d w_k = [e_k]_x R, d X / d t = I
        eye = torch.eye(3, dtype=dtype, device=s.RX.device)
        rx = torch.stack([(gX[:, :3, :3] * (skew(eye[k]).expand(B, 3, 3) @ s.RX)).sum((-1, -2)) for k in range(3)], -1)
        rz = torch.stack([(gZ[:, :3, :3] * (skew(eye[k]).expand(B, 3, 3) @ s.RZ)).sum((-1, -2)) for k in range(3)], -1)
        v = torch.zeros(B, D, dtype=dtype, device=s.RX.device)
        v[:, 0:3], v[:, 3:6], v[:, 6:9], v[:, 9:12] = rx, gX[:, :3, 3], rz, gZ[:, :3, 3]
        if problem.basis is not None and gP is not None:
            v[:, GLOBAL_POSE_PARAMS:G] = (problem.basis.transpose(-1, -2) @ gP.to(dtype)[..., None])[..., 0]
        with torch.enable_grad():
            c_in = corners.detach().to(dtype).requires_grad_(ctx.needs_input_grad[0])
            t_in = robot_poses.detach().to(dtype).requires_grad_(ctx.needs_input_grad[1])
            prob = HandEyeProblem(problem.setup, problem.model, t_in, problem.obj, c_in, problem.w, problem.basis,
                                  problem.noise)
            z = torch.zeros(B, D, dtype=dtype, device=s.RX.device, requires_grad=True)
            g = torch.autograd.grad(hand_eye_cost(prob, s, z).sum(), z, create_graph=True)[0]
            rows = [torch.autograd.grad(g[:, k].sum(), z, retain_graph=True)[0] for k in range(D)]
            H = torch.stack(rows, 1)  # (B, D, D)
            u = torch.linalg.lstsq(H, v[..., None]).solution[..., 0]
            inputs = [t for t, need in zip((c_in, t_in), ctx.needs_input_grad[:2]) if need]
            grads = iter(torch.autograd.grad((g * u.detach()).sum(), inputs, allow_unused=True))
        out = [(-next(grads)) if need else None for need in ctx.needs_input_grad[:2]]
        out = [None if o is None else o.to(t.dtype) for o, t in zip(out, (corners, robot_poses))]
        return out[0], out[1], None, None, None, None, None


def attach_gradients(result, corners, valid, object_points, robot_poses, weights, free_intrinsics, robot_noise):
    """The result with ``X``, ``Z`` and the camera's parameters carrying implicit gradients to ``corners`` and ``robot_poses``
    (whichever require grad): its fit is rebuilt as a problem (same weights, start, noise sigmas) at its optimum."""
    from ccs_kornia.modules.calibration.lm import parameter_basis

    B, V, N = corners.shape[:3]
    dtype = torch.float64
    model = result.camera.model
    if result.board_order is not None and bool(result.board_order.any()):  # the fit's numbering of the corners
        from ccs_kornia.modules.calibration.board_symmetry import board_symmetries
        from ccs_kornia.modules.hand_eye.board_order import renumber_corners

        corners, valid = renumber_corners(corners, valid, result.board_order, board_symmetries(object_points.detach()))
    w = (valid.bool() & corners.detach().isfinite().all(-1) & result.used[..., None]).to(dtype)
    if weights is not None:
        w = w * weights.detach().to(dtype).clamp_min(0)
    if result.pixel_sigma is not None:
        w = w / (result.pixel_sigma.to(dtype) ** 2)[:, None, None]
    basis = None
    if free_intrinsics:
        basis = parameter_basis(model, result.camera.params.detach(), None if free_intrinsics is True else list(free_intrinsics))
    noise = result.robot_noise
    safe = torch.where(robot_poses.detach().flatten(-2).isfinite().all(-1)[..., None, None], robot_poses.detach().to(dtype),
                       torch.eye(4, dtype=dtype, device=corners.device))
    board = object_points.detach().to(dtype)
    if result.board_warp is not None:  # the board as the fit bent it, held (a constant of the backward pass)
        board = warped_board(board, result.board_warp.detach().to(board).nan_to_num(0.0))
    problem = HandEyeProblem(result.setup, model, safe, board, corners.detach().to(dtype), w, basis, noise)
    state = HandEyeProblem.initial_state(result.X.detach(), result.Z.detach(), result.camera.params.detach(), V)
    if noise is not None and result.corrections is not None:
        state = state._replace(RE=result.corrections[0], tE=result.corrections[1])
    X, Z, params = _Implicit.apply(corners, robot_poses, result.X, result.Z, result.camera.params, problem, state)
    result.X, result.Z, result.camera = X, Z, result.camera.with_params(params)
    return result
