"""Gradients of the calibration solver by implicit differentiation at the LM optimum: finite differences, gradcheck,
unchanged answers without grad, batches, fixed and tied parameters."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera, project_points
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, RATIONAL
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.calibration.implicit import (
    implicit_solution,
    so3_left_jacobian_inverse,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver

F64 = torch.float64
SIZE = (640, 480)
DIST = {
    K1K2: [-0.25, 0.08, 0.0, 0.0, 0.0],
    OPENCV5: [-0.25, 0.08, 0.001, -0.002, 0.01],
    RATIONAL: [-0.25, 0.08, 0.001, -0.002, 0.01, 0.01, 0.0, 0.0],
}


def _corners(model: str, obj: torch.Tensor, V: int = 6, seed: int = 0, noise: float = 0.3) -> torch.Tensor:
    """Noisy corners of V random board views (V, N, 2)."""
    g = torch.Generator().manual_seed(seed)
    rv = 0.8 * (torch.rand(V, 3, generator=g, dtype=F64) - 0.5)
    tv = torch.stack([-0.08 + 0.05 * torch.randn(V, generator=g, dtype=F64),
                      -0.06 + 0.05 * torch.randn(V, generator=g, dtype=F64),
                      0.3 + 0.1 * torch.rand(V, generator=g, dtype=F64)], -1)
    pts = obj.expand(V, -1, -1)
    if model == FISHEYE:
        K = torch.tensor([[250.0, 0, 321], [0, 251, 239], [0, 0, 1]], dtype=F64)
        D = torch.tensor([0.03, -0.01, 0.004, -0.001], dtype=F64)
        uv = Camera.from_opencv(FISHEYE, K, D).project(pts[None], rv[None], tv[None])[0]
    else:
        K = torch.tensor([[520.0, 0, 322], [0, 522, 241], [0, 0, 1]], dtype=F64)
        uv = project_points(pts, K.expand(V, 3, 3), torch.tensor(DIST.get(model, [0.0] * 5), dtype=F64), rv, tv)
    return uv + noise * torch.randn(uv.shape, generator=g, dtype=F64)


def _solver(model: str, **kwargs) -> CalibrationSolver:
    """A solver converged far below the finite-difference steps (no stall stop, tight ftol)."""
    return CalibrationSolver(model=model, ftol=1e-15, stall_tol=0.0, max_iters=300, use_ransac=False, **kwargs)


def _outputs(res) -> torch.Tensor:
    """fx, cx, k1 (fy without distortion), one rotation and one translation entry."""
    k1 = res.dist[..., 0] if res.dist.shape[-1] else res.K[..., 1, 1]
    return torch.stack([res.K[..., 0, 0], res.K[..., 0, 2], k1, res.rvec[..., 1, 0], res.tvec[..., 2, 2]], -1)


def _fd_check(solver, uv, obj, picks, eps=1e-3, weights=None, wrt="corners"):
    """(analytic, central-difference) derivatives of :func:`_outputs` by the flat entries ``picks`` of ``wrt``."""
    x = {"corners": uv, "weights": weights, "obj": obj}[wrt].clone()

    def solve(v):
        args = {"corners": uv, "weights": weights, "obj": obj}
        args[wrt] = v
        return solver(args["corners"], None, args["obj"], SIZE, weights=args["weights"])

    xg = x.clone().requires_grad_()
    out = _outputs(solve(xg))
    an = torch.stack([torch.autograd.grad(out[i], xg, retain_graph=True)[0].flatten()[picks] for i in range(5)])
    fd = torch.zeros_like(an)
    with torch.no_grad():
        for j, i in enumerate(picks.tolist()):
            up, dn = x.clone().view(-1), x.clone().view(-1)
            up[i] += eps
            dn[i] -= eps
            fd[:, j] = (_outputs(solve(up.view_as(x))) - _outputs(solve(dn.view_as(x)))) / (2 * eps)
    return an, fd


def _rel(an, fd):
    return (an - fd).norm(dim=-1) / fd.norm(dim=-1)


@pytest.mark.parametrize("model", [OPENCV5, K1K2, RATIONAL, FISHEYE])
def test_corner_gradients_match_finite_differences(model):
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(model, obj)
    picks = torch.randperm(uv.numel(), generator=torch.Generator().manual_seed(1))[:24]
    an, fd = _fd_check(_solver(model), uv, obj, picks)
    assert fd.norm(dim=-1).min() > 0
    assert _rel(an, fd).max() < 0.05, _rel(an, fd)


def test_weight_and_board_gradients_match_finite_differences():
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(K1K2, obj)
    w = 0.5 + torch.rand(uv.shape[:-1], generator=torch.Generator().manual_seed(2), dtype=F64)
    picks = torch.randperm(w.numel(), generator=torch.Generator().manual_seed(3))[:12]
    an, fd = _fd_check(_solver(K1K2), uv, obj, picks, weights=w, wrt="weights")
    assert _rel(an, fd).max() < 0.05, _rel(an, fd)
    picks = torch.arange(0, obj.numel(), 7)  # x, y and z entries of the board points
    an, fd = _fd_check(_solver(K1K2), uv, obj, picks, eps=1e-6, wrt="obj")
    assert _rel(an, fd).max() < 0.05, _rel(an, fd)


@pytest.mark.parametrize("model", [K1K2, FISHEYE])
def test_gradcheck(model):
    obj = board_object_points(4, 3, 0.06, dtype=F64)
    uv = _corners(model, obj, V=4, noise=0.05)
    solver = _solver(model, reject_outliers=False, checks=False, min_corners=6)

    def fn(c):
        r = solver(c, None, obj, SIZE)
        return torch.stack([r.K[0, 0], r.K[1, 1], r.K[0, 2], r.K[1, 2]])

    assert torch.autograd.gradcheck(fn, (uv.clone().requires_grad_(),), eps=1e-3, atol=2e-3, rtol=1e-3)


@pytest.mark.parametrize("model", [OPENCV5, FISHEYE])
def test_values_unchanged_by_grad(model):
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(model, obj, V=8)
    solver = CalibrationSolver(model=model)
    plain = solver(uv, None, obj, SIZE)
    with torch.inference_mode():
        inference = solver(uv, None, obj, SIZE)
    graded = solver(uv.clone().requires_grad_(), None, obj, SIZE)
    assert graded.K.requires_grad and graded.rvec.requires_grad and not plain.K.requires_grad
    for k, v in plain.tensors().items():
        assert torch.equal(v.nan_to_num(7.0), graded.tensors()[k].detach().nan_to_num(7.0)), k
        assert torch.equal(v.nan_to_num(7.0), inference.tensors()[k].nan_to_num(7.0)), k


def test_batched_cameras_are_independent():
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = torch.stack([_corners(OPENCV5, obj, seed=0), _corners(OPENCV5, obj, seed=5)])
    solver = _solver(OPENCV5)
    c = uv.clone().requires_grad_()
    res = solver(c, None, obj, SIZE)
    assert res.K.shape == (2, 3, 3) and bool(res.success.all())
    g, = torch.autograd.grad(res.K[1, 0, 0], c)
    assert g[0].abs().max() == 0 and g[1].abs().max() > 0
    c1 = uv[1].clone().requires_grad_()
    g1, = torch.autograd.grad(solver(c1, None, obj, SIZE).K[0, 0], c1)
    # the batched and the single solve each stop within the LM's tolerance of the one optimum (ftol 1e-15 on the cost:
    # the parameters to about 1e-9 relative), which the implicit gradient's entries follow
    torch.testing.assert_close(g[1], g1, rtol=1e-5, atol=1e-6)


def test_fixed_and_tied_parameters():
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(K1K2, obj)
    c = uv.clone().requires_grad_()
    res = _solver(K1K2, fix_principal_point=True, fix_aspect_ratio=True)(c, None, obj, SIZE)
    g_cx, = torch.autograd.grad(res.K[0, 2], c, retain_graph=True)
    assert g_cx.abs().max() == 0  # fixed: no gradient
    g_fx, = torch.autograd.grad(res.K[0, 0], c, retain_graph=True)
    g_fy, = torch.autograd.grad(res.K[1, 1], c)
    torch.testing.assert_close(g_fx, g_fy * (res.K[0, 0] / res.K[1, 1]).detach())  # tied: fx / fy held
    picks = torch.randperm(uv.numel(), generator=torch.Generator().manual_seed(4))[:12]
    an, fd = _fd_check(_solver(K1K2, fix_principal_point=True, fix_aspect_ratio=True), uv, obj, picks)
    keep = [0, 2, 3, 4]  # cx is fixed (both sides zero)
    assert fd[1].abs().max() == 0 and an[1].abs().max() == 0
    assert _rel(an[keep], fd[keep]).max() < 0.05


def test_unused_views_and_invalid_corners_get_no_gradient():
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(K1K2, obj, V=7)
    uv[6] = uv[6] + 40.0 * torch.randn(uv[6].shape, generator=torch.Generator().manual_seed(6), dtype=F64)
    uv[0, :3] = float("nan")
    c = uv.clone().requires_grad_()
    res = CalibrationSolver(model=K1K2)(c, None, obj, SIZE)
    assert not bool(res.used[6])
    g, = torch.autograd.grad(res.K[0, 0] + res.tvec[6].sum(), c)
    assert g.isfinite().all() and g[6].abs().max() == 0 and g[0, :3].abs().max() == 0


def test_left_jacobian_inverse_matches_log_exp():
    w = torch.tensor([[0.3, -0.2, 0.5], [1e-6, 0.0, 0.0], [0.0, 2.5, 1.0]], dtype=F64)
    num = torch.autograd.functional.jacobian(lambda d: log_so3(exp_so3(d) @ exp_so3(w)), torch.full_like(w, 1e-30))
    num = torch.stack([num[i, :, i] for i in range(3)])
    torch.testing.assert_close(so3_left_jacobian_inverse(w), num)


def test_implicit_solution_exceptions_and_passthrough():
    obj = board_object_points(4, 3, 0.06, dtype=F64)
    uv = _corners(K1K2, obj, V=4)[None]
    res = _solver(K1K2)(uv[0], None, obj, SIZE)
    with pytest.raises(ValueError, match="weights"):
        _solver(K1K2)(uv[0], None, obj, SIZE, weights=torch.ones(3))

    m = K1K2
    params = m.params_from(res.K[None], res.dist[None])
    out = implicit_solution(m, torch.eye(6, dtype=F64)[None], params, res.rvec[None], res.tvec[None], uv,
                            torch.ones(uv.shape[:-1], dtype=F64), obj[None])
    assert torch.equal(out[0], params) and torch.equal(out[1], res.rvec[None]) and not out[0].requires_grad


def test_fisheye_fixed_principal_point():
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(FISHEYE, obj)
    picks = torch.randperm(uv.numel(), generator=torch.Generator().manual_seed(7))[:10]
    an, fd = _fd_check(_solver(FISHEYE, fix_principal_point=True), uv, obj, picks)
    assert an[1].abs().max() == 0 and fd[1].abs().max() == 0
    keep = [0, 2, 3, 4]
    assert _rel(an[keep], fd[keep]).max() < 0.05


def test_fixed_intrinsics_warm_start():
    obj = board_object_points(6, 5, 0.03, dtype=F64)
    uv = _corners(K1K2, obj)
    solver = CalibrationSolver(model=K1K2)
    first = solver(uv, None, obj, SIZE)
    c = uv.clone().requires_grad_()
    res = solver(c, None, obj, SIZE, initial=first, fix_intrinsics=True)
    g_k, = torch.autograd.grad(res.K.sum(), c, retain_graph=True)
    g_d, = torch.autograd.grad(res.dist[0] + res.tvec[0, 2], c)
    assert g_k.abs().max() == 0 and g_d.abs().max() > 0 and g_d.isfinite().all()
