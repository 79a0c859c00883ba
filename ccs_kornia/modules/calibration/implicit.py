r"""Gradients of a Levenberg–Marquardt optimum by implicit differentiation (no unrolled iterations).

At the optimum :math:`x^*` of :math:`F(x, c) = \sum_n w_n |r_n(x, c)|^2` with :math:`r_n = \pi_n(x) - c_n`
(:math:`x`: the free camera coordinates and every used view's pose, :math:`c`: the observed corners), the
stationarity :math:`g(x^*, c) = J^T W r = 0` holds for every :math:`c`, so

.. math::
    \frac{d x^*}{d c} = -H^{-1} \frac{\partial g}{\partial c} = H^{-1} J^T W, \qquad H \approx J^T W J

(Gauss-Newton: the second-order terms :math:`\sum w\, r\, \nabla^2 r` vanish with the residuals). A backward pass
therefore solves one linear system :math:`H u = \bar x` with the normal equations of the LM core (camera block plus
pose blocks eliminated by the Schur complement, batched over cameras: :func:`~.lm._normal_equations` and
:func:`~.lm._schur_step` at zero damping) and maps :math:`u` back to the inputs through per-corner products:

* corners: :math:`\bar c_n = w_n J_n u` (exact for the Gauss-Newton :math:`H`);
* weights: :math:`\bar w_n = -(J_n u) \cdot r_n` (exact: :math:`\partial g / \partial w_n = J_n^T r_n`);
* board points: :math:`\bar X_n = -\sum_v w_{vn} (J_{vn} u)^T (\partial \pi / \partial X_c) R_v` (Gauss-Newton: the
  term of the Jacobian's own dependence on :math:`X`, weighted by the residual, is dropped).

Only the free coordinates carry gradient: a fixed parameter has zero gradient, tied ones (``basis``, e.g. a fixed
aspect ratio) move together. Rotations are perturbed on the left, ``R <- exp(w) R`` as in the LM core; the
gradient of the returned axis-angle ``rvec`` goes through the inverse left Jacobian of SO(3).

Everything decided before the optimum (initialisation, RANSAC, which views and corners are used, the outlier
check, the basis of tied parameters) is a constant of the backward pass.
"""

from __future__ import annotations

import torch

from ccs_kornia.modules.calibration.lm import _normal_equations, _schur_step
from ccs_kornia.modules.calibration.models.base import CameraModel
from ccs_kornia.modules.calibration.so3 import exp_so3

__all__ = ["implicit_solution", "ImplicitSolution", "so3_left_jacobian_inverse"]


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


def _backward(model, basis, params, rvec, tvec, corners, weights, obj, g_params, g_rvec, g_tvec, need):
    """Vector-Jacobian products of the optimum (see the module doc); ``need`` flags (corners, weights, obj)."""
    C, V, N = corners.shape[:3]
    dtype = params.dtype
    on = weights > 0
    used = on.any(-1)
    ok = used.any(-1) & params.isfinite().all(-1)  # (C,) cameras with a solution
    p = torch.where(ok[:, None], params, 1.0)
    rv = torch.where(used[..., None] & rvec.isfinite(), rvec, 0.0)
    park = torch.tensor([0.0, 0.0, 1.0 + 10.0 * float(obj.abs().amax())], dtype=dtype, device=corners.device)
    tv = torch.where(used[..., None] & tvec.isfinite(), tvec, park)
    R = exp_so3(rv)
    obs = torch.where(on[..., None], corners, 0.0)
    sw = weights.sqrt()
    eye6 = torch.eye(6, dtype=dtype, device=corners.device)
    _, U, Wb, Vb, _, _, _ = _normal_equations(model, R, tv, p, obj, obs, sw, basis, used, eye6, {})

    # right-hand side: the output gradients in the solver's coordinates (free camera coordinates, left pose increments)
    zeros3 = torch.zeros(C, V, 3, dtype=dtype, device=corners.device)
    g_params = torch.zeros_like(params) if g_params is None else g_params.nan_to_num(0.0)
    g_rvec = zeros3 if g_rvec is None else g_rvec.nan_to_num(0.0)
    g_tvec = zeros3 if g_tvec is None else g_tvec.nan_to_num(0.0)
    v_cam = (basis.transpose(-1, -2) @ g_params.unsqueeze(-1)).squeeze(-1)
    g_w = (so3_left_jacobian_inverse(rv).transpose(-1, -2) @ g_rvec.unsqueeze(-1)).squeeze(-1)
    used_f = used.to(dtype)
    v_pose = torch.cat([g_w, g_tvec], -1) * used_f[..., None]
    eyeF = torch.eye(basis.shape[-1], dtype=dtype, device=corners.device)
    lam = torch.zeros(C, dtype=dtype, device=corners.device)
    # the undamped step of the LM core solves H u = -(eg, ep): with (eg, ep) = -(v_cam, v_pose) it gives H^-1 v
    u_cam, u_pose = _schur_step(U, Wb, Vb, -v_cam, -v_pose, lam, used_f, eyeF)
    u_par = (basis @ u_cam.unsqueeze(-1)).squeeze(-1)  # (C, P)

    # J u per corner: parameter columns, then rotation q x (d uv / d Xc) and translation columns
    q = torch.matmul(obj[:, None].expand(C, V, N, 3), R.transpose(-1, -2))
    uv, dp, (dx, dy, dz) = model.columns(q + tv[:, :, None, :], p)
    Ju = torch.zeros_like(uv)
    for i, col in enumerate(dp):
        Ju = Ju + col * u_par[:, i].view(C, *([1] * (uv.dim() - 1)))
    uw, ut = u_pose[..., None, None, :3], u_pose[..., None, None, 3:]  # (C, V, 1, 1, 3)
    qx, qy, qz = q[..., 0:1], q[..., 1:2], q[..., 2:3]
    Ju = Ju + (qy * dz - qz * dy) * uw[..., 0] + (qz * dx - qx * dz) * uw[..., 1] + (qx * dy - qy * dx) * uw[..., 2]
    Ju = Ju + dx * ut[..., 0] + dy * ut[..., 1] + dz * ut[..., 2]
    keep = on & ok[:, None, None]
    Ju = torch.where(keep[..., None], Ju, 0.0)
    w0 = torch.where(keep, weights, 0.0)

    g_corners = g_weights = g_obj = None
    if need[0]:
        g_corners = w0[..., None] * Ju
    if need[1]:
        g_weights = -torch.where(keep, (Ju * (uv - obs)).sum(-1), 0.0)
    if need[2]:
        # (w J u)^T (d uv / d Xc) R, summed over the views
        wJu = w0[..., None] * Ju
        dXc = torch.stack([(wJu * d.expand_as(wJu)).sum(-1) for d in (dx, dy, dz)], -1)  # (C, V, N, 3)
        g_obj = -(dXc @ R).sum(1)
    return g_corners, g_weights, g_obj


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
        >>> from ccs_kornia.camera import board_object_points, project_points
        >>> from ccs_kornia.modules.calibration.lm import levenberg_marquardt
        >>> from ccs_kornia.modules.calibration.models import OpenCVModel
        >>> obj = board_object_points(4, 3, 0.1, dtype=torch.float64)[None]
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rv = torch.tensor([[[0.2, 0.1, 0.0], [-0.2, 0.3, 0.1], [0.1, -0.3, 0.2]]], dtype=torch.float64)
        >>> tv = torch.tensor([-0.1, -0.1, 1.0], dtype=torch.float64).expand(1, 3, 3)
        >>> uv = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rv[0], tv[0])[None]
        >>> w = torch.ones(1, 3, 12, dtype=torch.float64)
        >>> m = OpenCVModel("none")
        >>> res = levenberg_marquardt(m, torch.tensor([[505., 495., 322., 238.]], dtype=torch.float64), rv, tv, obj, uv)
        >>> _ = uv.requires_grad_()
        >>> p, r, t = implicit_solution(m, res.basis, res.params, res.rvec, res.tvec, uv, w, obj)
        >>> p[0, 0].backward()
        >>> uv.grad.shape
        torch.Size([1, 3, 12, 2])
    """
    return ImplicitSolution.apply(corners, weights, object_points, params.detach(), rvec.detach(), tvec.detach(),
                                  model, basis.detach())
