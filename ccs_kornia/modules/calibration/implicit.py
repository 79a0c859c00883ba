r"""Gradients of a Levenberg–Marquardt optimum by implicit differentiation (no unrolled iterations).

At the optimum :math:`x^*` of :math:`F(x, c) = \frac12 \sum_n w_n |r_n(x, c)|^2` with :math:`r_n = \pi_n(x) - c_n`
(:math:`x`: the free camera coordinates and every used view's pose, :math:`c`: the observed corners), the
stationarity :math:`g(x^*, c) = J^T W r = 0` holds for every :math:`c`, so

.. math::
    \frac{d x^*}{d c} = -H^{-1} \frac{\partial g}{\partial c} = H^{-1} J^T W, \qquad
    H = \frac{\partial g}{\partial x} = J^T W J + \sum_n w_n r_n \cdot \nabla^2 \pi_n .

A backward pass solves one linear system :math:`H u = \bar x` with the arrow structure of the LM core (a camera
block, one 6x6 block per view, eliminated by the Schur complement and batched over cameras:
:func:`~ccs_kornia.modules.calibration.schur_lm.schur_step` at zero damping), then gives every input
:math:`-u^T \partial g / \partial (c, w, X)` in one vector-Jacobian product: corners :math:`w_n J_n u`, weights
:math:`-(J_n u) \cdot r_n`, board points through the projection and its Jacobian.

``H`` is the exact Hessian: ``g`` is built from the camera model's analytic Jacobian columns and differentiated once
more by autograd (one vector-Jacobian product on ``F + 6`` copies of the problem gives every block). The Gauss-Newton
:math:`J^T W J` alone is exact only where the residuals vanish: with noisy corners its gradients are off where the
exact Hessian's agree with central differences (``docs/gradients.md``).

Only the free coordinates carry gradient: a fixed parameter has zero gradient, tied ones (``basis``, e.g. a fixed
aspect ratio) move together. Rotations are perturbed on the left, ``R <- exp(w) R`` as in the LM core; the
gradient of the returned axis-angle ``rvec`` goes through the inverse left Jacobian of SO(3).

Everything decided before the optimum (initialisation, RANSAC, which views and corners are used, the outlier
check, the basis of tied parameters) is a constant of the backward pass.
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.schur_lm import schur_step

__all__ = ["HESSIAN_CHUNK", "implicit_solution", "ImplicitSolution", "so3_left_jacobian_inverse"]


def so3_left_jacobian_inverse(w: torch.Tensor) -> torch.Tensor:
    r"""Inverse left Jacobian :math:`(..., 3, 3)` of SO(3) at rotation vectors ``w`` :math:`(..., 3)`: the derivative
    of :math:`\log(\exp(\delta) \exp(w))` by :math:`\delta` at 0.

    Example:
        >>> so3_left_jacobian_inverse(torch.zeros(1, 3)).squeeze(0).equal(torch.eye(3))
        True
    """
    t2 = (w * w).sum(-1)[..., None, None]
    t = t2.sqrt()
    small = t < 1e-4
    ts = torch.where(small, torch.ones_like(t), t)
    coef = torch.where(small, 1.0 / 12.0 + t2 / 720.0, 1.0 / ts.square() - (1 + ts.cos()) / (2 * ts * ts.sin()))
    z = torch.zeros_like(w[..., 0])
    K = torch.stack([z, -w[..., 2], w[..., 1], w[..., 2], z, -w[..., 0], -w[..., 1], w[..., 0], z], -1)
    K = K.view(*w.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=w.dtype, device=w.device)
    return eye - 0.5 * K + coef * (K @ K)


def _gradient(model, basis, params, R, tvec, obj, corners, weights, z_cam, z_pose):
    """Gradient of the cost (halved) in the solver's coordinates at ``z``: free camera coordinates ``z_cam`` (C, F)
    and left pose increments ``z_pose`` (C, V, 6), from the model's analytic columns (differentiable by autograd)."""
    C, V, N = corners.shape[:3]
    p = params + (basis @ z_cam.unsqueeze(-1)).squeeze(-1)
    # exp(w) R to first order (all the derivative at z = 0 needs; exp's own derivative is undefined at 0 by autograd)
    w = z_pose[..., :3]
    zero = torch.zeros_like(w[..., 0])
    Kw = torch.stack([zero, -w[..., 2], w[..., 1], w[..., 2], zero, -w[..., 0], -w[..., 1], w[..., 0], zero], -1)
    Rz = R + Kw.view(*w.shape[:-1], 3, 3) @ R
    q = torch.matmul(obj[:, None].expand(C, V, N, 3), Rz.transpose(-1, -2))  # R X
    uv, dp, (dx, dy, dz) = model.columns(q + (tvec + z_pose[..., 3:])[:, :, None, :], p)
    wr = weights[..., None] * (uv - corners)  # (C, V, N, 2)
    g_par = torch.stack([(wr * col).sum((-1, -2)) for col in dp], -1)  # (C, V, P) per view
    qx, qy, qz = q[..., 0:1], q[..., 1:2], q[..., 2:3]
    cols = [qy * dz - qz * dy, qz * dx - qx * dz, qx * dy - qy * dx, dx, dy, dz]
    g_pose = torch.stack([(wr * col).sum((-1, -2)) for col in cols], -1)  # (C, V, 6)
    g_cam = (basis.transpose(-1, -2) @ g_par.sum(1).unsqueeze(-1)).squeeze(-1)  # (C, F)
    return g_cam, g_pose


#: points (cameras x views x corners x seeds) per autograd pass of :func:`_hessian`
HESSIAN_CHUNK = 1 << 21


def _hessian(model, basis, params, R, tvec, obj, corners, weights):
    """The exact Hessian of the cost in the arrow blocks ``U (C, F, F), W (C, V, F, 6), V (C, V, 6, 6)``: the gradient
    of :func:`_gradient` on copies of the problem, one copy per seed (a camera coordinate, or a pose coordinate of
    every view at once: the views' pose rows do not mix), differentiated in one vector-Jacobian product."""
    C, V, N = corners.shape[:3]
    F = basis.shape[-1]
    S = F + 6
    dtype, device = params.dtype, params.device
    seeds = torch.eye(S, dtype=dtype, device=device)
    rows_c, rows_p = [], []
    step = max(1, HESSIAN_CHUNK // max(C * V * N, 1))
    for a in range(0, S, step):
        E = seeds[a : a + step]  # (s, S)
        s = E.shape[0]

        def rep(t):
            return t.repeat(s, *([1] * (t.dim() - 1)))

        z_cam = torch.zeros(s * C, F, dtype=dtype, device=device, requires_grad=True)
        z_pose = torch.zeros(s * C, V, 6, dtype=dtype, device=device, requires_grad=True)
        with torch.enable_grad():
            g_cam, g_pose = _gradient(model, rep(basis), rep(params), rep(R), rep(tvec), rep(obj), rep(corners),
                                      rep(weights), z_cam, z_pose)
            e_cam = E[:, None, :F].expand(s, C, F).reshape(s * C, F)
            e_pose = E[:, None, None, F:].expand(s, C, V, 6).reshape(s * C, V, 6)
            gc, gp = torch.autograd.grad((g_cam, g_pose), (z_cam, z_pose), (e_cam, e_pose))
        rows_c.append(gc.view(s, C, F))
        rows_p.append(gp.view(s, C, V, 6))
    rows_c, rows_p = torch.cat(rows_c), torch.cat(rows_p)
    return rows_c[:F].permute(1, 0, 2), rows_p[:F].permute(1, 2, 0, 3), rows_p[F:].permute(1, 2, 0, 3)


def _backward(model, basis, params, rvec, tvec, corners, weights, obj, g_params, g_rvec, g_tvec, need):
    """Vector-Jacobian products of the optimum (see the module doc); ``need`` flags (corners, weights, obj)."""
    C, V, N = corners.shape[:3]
    dtype, device = params.dtype, params.device
    on = weights > 0
    used = on.any(-1)
    ok = used.any(-1) & params.isfinite().all(-1)  # (C,) cameras with a solution
    p = torch.where(ok[:, None], params, 1.0)
    rv = torch.where(used[..., None] & rvec.isfinite(), rvec, 0.0)
    park = torch.tensor([0.0, 0.0, 1.0 + 10.0 * float(obj.abs().amax())], dtype=dtype, device=device)
    tv = torch.where(used[..., None] & tvec.isfinite(), tvec, park)
    R = exp_so3(rv)
    F = basis.shape[-1]
    c_in = torch.where(on[..., None], corners, 0.0)
    w_in = torch.where(on, weights, 0.0)
    U, Wb, Hpp = _hessian(model, basis, p, R, tv, obj, c_in, w_in)
    c_in, w_in = c_in.requires_grad_(need[0]), w_in.requires_grad_(need[1])
    o_in = obj.detach().clone().requires_grad_(need[2])
    z_cam = torch.zeros(C, F, dtype=dtype, device=device)
    z_pose = torch.zeros(C, V, 6, dtype=dtype, device=device)
    with torch.enable_grad():
        g_cam, g_pose = _gradient(model, basis, p, R, tv, o_in, c_in, w_in, z_cam, z_pose)
        eye6 = torch.eye(6, dtype=dtype, device=device)
        Vb = torch.where(used[..., None, None], Hpp, eye6)

        # right-hand side: the output gradients in the solver's coordinates (free camera coordinates, left pose
        # increments)
        zeros3 = torch.zeros(C, V, 3, dtype=dtype, device=device)
        g_params = torch.zeros_like(params) if g_params is None else g_params.nan_to_num(0.0)
        g_rvec = zeros3 if g_rvec is None else g_rvec.nan_to_num(0.0)
        g_tvec = zeros3 if g_tvec is None else g_tvec.nan_to_num(0.0)
        v_cam = (basis.transpose(-1, -2) @ g_params.unsqueeze(-1)).squeeze(-1)
        g_w = (so3_left_jacobian_inverse(rv).transpose(-1, -2) @ g_rvec.unsqueeze(-1)).squeeze(-1)
        used_f = used.to(dtype)
        v_pose = torch.cat([g_w, g_tvec], -1) * used_f[..., None]
        # the undamped step of the LM core solves H u = -(eg, ep): with (eg, ep) = -(v_cam, v_pose) it gives H^-1 v
        u_cam, u_pose = schur_step(U.detach(), Wb.detach(), Vb.detach(), -v_cam, -v_pose, used)
        u_cam = torch.where(ok[:, None], u_cam, 0.0)
        u_pose = torch.where(ok[:, None, None], u_pose, 0.0)
        inputs = [t for t, n in zip((c_in, w_in, o_in), need) if n]
        grads = iter(torch.autograd.grad((g_cam, g_pose), inputs, (-u_cam, -u_pose), allow_unused=True))
    out = [next(grads) if n else None for n in need]
    keep = on & ok[:, None, None]
    if out[0] is not None:
        out[0] = torch.where(keep[..., None], out[0], 0.0)
    if out[1] is not None:
        out[1] = torch.where(keep, out[1], 0.0)
    if out[2] is not None:
        out[2] = torch.where(ok[:, None, None], out[2], 0.0)
    return tuple(out)


class ImplicitSolution(torch.autograd.Function):
    """Identity on a solved optimum ``(params, rvec, tvec)`` whose backward differentiates it with respect to the
    problem's ``(corners, weights, object_points)`` implicitly (see the module doc). Use :func:`implicit_solution`."""

    @staticmethod
    def forward(ctx, corners, weights, obj, params, rvec, tvec, model, basis):
        ctx.model = model
        ctx.save_for_backward(corners, weights, obj, params, rvec, tvec, basis)
        return params.clone(), rvec.clone(), tvec.clone()

    @staticmethod
    def backward(ctx, g_params, g_rvec, g_tvec):
        corners, weights, obj, params, rvec, tvec, basis = ctx.saved_tensors
        need = ctx.needs_input_grad[:3]
        with torch.no_grad():
            gc, gw, go = _backward(ctx.model, basis, params, rvec, tvec, corners, weights, obj, g_params, g_rvec,
                                   g_tvec, need)
        return gc, gw, go, None, None, None, None, None


def implicit_solution(
    model: CameraModel,
    basis: torch.Tensor,
    params: torch.Tensor,
    rvec: torch.Tensor,
    tvec: torch.Tensor,
    corners: torch.Tensor,
    weights: torch.Tensor,
    object_points: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Attach implicit gradients to an optimum of :func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt`.

    The returned tensors equal ``params, rvec, tvec`` bit for bit; their gradients flow to ``corners``, ``weights``
    and ``object_points`` (whichever require grad) through the optimality condition, not through the iterations.
    The optimum must be one of this problem (same model, weights, basis); a loose tolerance gives a gradient that
    is as accurate as the optimum.

    Args:
        model: the camera model of the solve.
        basis: :math:`(C, P, F)` free-coordinate basis of the solve (:attr:`LMResult.basis`).
        params: :math:`(C, P)` optimal parameters.
        rvec, tvec: :math:`(C, V, 3)` optimal poses (views without a weighted corner get no gradient).
        corners: :math:`(C, V, N, 2)` observed pixels (entries of weight 0 may be NaN).
        weights: :math:`(C, V, N)` the weights of the solve (0: corner unused).
        object_points: :math:`(C, N, 3)` board points.

    Returns:
        ``(params, rvec, tvec)`` carrying gradients.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> from ccs_kornia.modules.calibration.lm import levenberg_marquardt
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> obj = board_object_points(4, 3, 0.1, dtype=torch.float64)[None]
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rv = torch.tensor([[[0.2, 0.1, 0.0], [-0.2, 0.3, 0.1], [0.1, -0.3, 0.2]]], dtype=torch.float64)
        >>> tv = torch.tensor([-0.1, -0.1, 1.0], dtype=torch.float64).expand(1, 3, 3)
        >>> uv = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rv[0], tv[0])[None]
        >>> w = torch.ones(1, 3, 12, dtype=torch.float64)
        >>> m = PINHOLE
        >>> res = levenberg_marquardt(m, torch.tensor([[505., 495., 322., 238.]], dtype=torch.float64), rv, tv, obj, uv)
        >>> _ = uv.requires_grad_()
        >>> p, r, t = implicit_solution(m, res.basis, res.params, res.rvec, res.tvec, uv, w, obj)
        >>> p[0, 0].backward()
        >>> uv.grad.shape
        torch.Size([1, 3, 12, 2])
    """
    return ImplicitSolution.apply(corners, weights, object_points, params.detach(), rvec.detach(), tvec.detach(),
                                  model, basis.detach())
