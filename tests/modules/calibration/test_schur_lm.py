"""The LM core alone: toy problems with a known optimum (global unknowns only, and with 6-dof item blocks), batches
of problems that converge at different iterations, the covariance against a dense solve, the step against a dense
solve, the working set, the checks of the normal equations, how each problem ended (its status)."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.schur_lm import (
    LM_STATUS_MESSAGES,
    LMStatus,
    NormalEquations,
    SchurLMResult,
    schur_lm,
    schur_step,
)

F64 = torch.float64


class Exponential:
    """``y = a exp(b x)`` (+ ``c``, a coordinate no residual depends on, with ``idle``): global unknowns only."""

    def __init__(self, x, y, idle=False):
        self.x, self.y, self.idle = x, y, idle
        B = x.shape[0]
        self.used = torch.zeros(B, 0, dtype=torch.bool, device=x.device)
        self.num_residuals = torch.full((B,), x.shape[1], device=x.device)
        self.floor = torch.full((B,), 1e-28, dtype=x.dtype, device=x.device)

    def linearize(self, s):
        a, b = s["p"][:, :1], s["p"][:, 1:2]
        e = torch.exp(b * self.x)
        cols = [e, a * self.x * e] + ([torch.zeros_like(e)] if self.idle else [])
        J = torch.stack(cols, -1)  # (B, N, G)
        r = a * e - self.y
        return NormalEquations(cost=(r * r).sum(-1), U=J.mT @ J, eg=(J.mT @ r[..., None])[..., 0])

    def retract(self, s, dg, dp):
        return {"p": s["p"] + dg}

    def scale(self, s):
        return s["p"].abs().amax(-1).clamp_min(1.0)

    def take(self, keep):
        return Exponential(self.x[keep], self.y[keep], self.idle)


def _skew(p):
    z = torch.zeros_like(p[..., 0])
    return torch.stack([z, -p[..., 2], p[..., 1], p[..., 2], z, -p[..., 0], -p[..., 1], p[..., 0], z], -1).unflatten(
        -1, (3, 3))


class ScaledCloud:
    """Points ``y_vn = R_v (s X_n) + t_v``: the scale ``s`` global, one pose per item (view); items without data are
    not used."""

    def __init__(self, X, Y, used):
        self.X, self.Y, self.used = X, Y, used  # (N, 3), (B, V, N, 3), (B, V)
        self.num_residuals = 3 * X.shape[0] * used.sum(-1)
        self.floor = torch.full((Y.shape[0],), 1e-28, dtype=Y.dtype, device=Y.device)

    def jacobian(self, s):
        """Residuals (B, V, N, 3) and their derivatives (B, V, N, 3, 7) by (s, w, t), zero for unused items."""
        RX = torch.einsum("bvij,nj->bvni", s["R"], self.X)
        p = s["s"][:, None, None, :] * RX
        m = self.used[..., None, None].to(p.dtype)
        r = (p + s["t"][:, :, None] - self.Y) * m
        eye = torch.eye(3, dtype=p.dtype, device=p.device).expand(*p.shape[:-1], 3, 3)
        J = torch.cat([RX[..., None], -_skew(p), eye], -1) * m[..., None]
        return r, J

    def linearize(self, s):
        r, J = self.jacobian(s)
        A = torch.einsum("bvnki,bvnkj->bvij", J, J)
        g = torch.einsum("bvnki,bvnk->bvi", J, r)
        eye6 = torch.eye(6, dtype=A.dtype, device=A.device)
        V = torch.where(self.used[..., None, None], A[..., 1:, 1:], eye6)
        return NormalEquations(cost=(r * r).sum((1, 2, 3)), U=A[..., :1, :1].sum(1), eg=g[..., :1].sum(1),
                               W=A[..., :1, 1:], V=V, ep=g[..., 1:])

    def retract(self, s, dg, dp):
        return {"s": s["s"] + dg, "R": exp_so3(dp[..., :3]) @ s["R"], "t": s["t"] + dp[..., 3:]}

    def scale(self, s):
        return torch.cat([s["s"].abs(), s["t"].abs().flatten(1), torch.ones_like(s["s"])], -1).amax(-1)

    def take(self, keep):
        return ScaledCloud(self.X, self.Y[keep], self.used[keep])


def _exponential(device, B=4, noise=0.0, idle=False):
    g = torch.Generator().manual_seed(3)
    x = torch.linspace(0.0, 1.0, 12, dtype=F64).expand(B, 12)
    truth = torch.stack([1.0 + torch.rand(B, generator=g, dtype=F64), torch.linspace(-1.0, 2.0, B, dtype=F64)], -1)
    y = truth[:, :1] * torch.exp(truth[:, 1:] * x) + noise * torch.randn(B, 12, generator=g, dtype=F64)
    start = truth * torch.linspace(0.5, 1.5, B, dtype=F64)[:, None]  # starts ever farther off
    if idle:
        start = torch.cat([start, torch.zeros(B, 1, dtype=F64)], -1)
    return Exponential(x.to(device), y.to(device), idle), {"p": start.to(device)}, truth.to(device)


def _cloud(device, B=3, V=5, N=8, noise=0.0, seed=0):
    g = torch.Generator().manual_seed(seed)
    X = torch.randn(N, 3, generator=g, dtype=F64)
    s = 1.0 + torch.rand(B, 1, generator=g, dtype=F64)
    w = 0.5 * torch.randn(B, V, 3, generator=g, dtype=F64)
    t = torch.randn(B, V, 3, generator=g, dtype=F64)
    Y = torch.einsum("bvij,bnj->bvni", exp_so3(w), s[:, :, None] * X) + t[:, :, None]
    Y = Y + noise * torch.randn(Y.shape, generator=g, dtype=F64)
    used = torch.ones(B, V, dtype=torch.bool)
    used[0, -1] = False  # an item without data
    start = {"s": s * 1.2, "R": exp_so3(w + 0.05), "t": t + 0.1}
    prob = ScaledCloud(X.to(device), Y.to(device), used.to(device))
    return prob, {k: v.to(device) for k, v in start.items()}, (s.to(device), exp_so3(w).to(device), t.to(device))


def test_global_only_reaches_the_optimum(device):
    prob, start, truth = _exponential(device)
    res = schur_lm(prob, start)
    assert isinstance(res, SchurLMResult)
    assert torch.allclose(res.unknowns["p"], truth, rtol=1e-9, atol=1e-9)
    assert (res.status == LMStatus.CONVERGED).all() and res.status.dtype == torch.long
    assert res.covariance.shape == (4, 2, 2) and res.iterations.shape == (4,)
    assert res.equations.U.shape == (4, 2, 2) and res.equations.W.shape == (4, 0, 2, 6)
    assert start["p"].shape == (4, 2)  # the initial state is not modified
    assert len(set(res.iterations.tolist())) > 1  # the problems converged at different iterations


def test_items_reach_the_optimum_and_unused_items_stay(device):
    prob, start, (s, R, t) = _cloud(device)
    res = schur_lm(prob, start)
    used = prob.used
    assert torch.allclose(res.unknowns["s"], s, rtol=1e-9)
    assert torch.allclose(res.unknowns["R"][used], R[used], atol=1e-9)
    assert torch.allclose(res.unknowns["t"][used], t[used], atol=1e-9)
    assert torch.equal(res.unknowns["t"][~used], start["t"][~used])  # no data: never moved
    assert (res.status == LMStatus.CONVERGED).all() and res.covariance.shape == (3, 1, 1)


def test_batch_with_different_convergence_equals_one_by_one(device):
    prob, start, _ = _exponential(device, B=5, noise=0.01)
    batch = schur_lm(prob, start)
    assert len(set(batch.iterations.tolist())) > 1
    for b in range(5):
        keep = torch.arange(5, device=device) == b
        one = schur_lm(prob.take(keep), {"p": start["p"][keep]})
        assert torch.allclose(one.unknowns["p"], batch.unknowns["p"][keep], rtol=1e-12, atol=0)
        assert torch.equal(one.iterations, batch.iterations[keep]) and torch.equal(one.status, batch.status[keep])
        assert torch.allclose(one.covariance, batch.covariance[keep], rtol=1e-9, atol=0)


def test_working_set_and_host_checks_do_not_change_the_answer(device):
    prob, start, _ = _cloud(device, B=4, noise=0.01, seed=2)
    ref = schur_lm(prob, start, shrink=False, check_every=1)
    for kwargs in ({"shrink": True, "check_every": 1}, {"shrink": True, "check_every": 10}, {"check_every": 7}):
        got = schur_lm(prob, start, **kwargs)
        for k in ("s", "R", "t"):
            assert torch.allclose(got.unknowns[k], ref.unknowns[k], rtol=1e-12, atol=1e-15), (kwargs, k)
        assert torch.equal(got.iterations, ref.iterations) and torch.equal(got.status, ref.status)
        assert torch.allclose(got.covariance, ref.covariance, rtol=1e-9, atol=0)


def test_covariance_matches_a_dense_solve(device):
    prob, start, _ = _cloud(device, B=2, noise=0.02, seed=5)
    res = schur_lm(prob, start)
    r, J = prob.jacobian(res.unknowns)
    for b in range(2):
        used = prob.used[b]
        Vb, N = int(used.sum()), prob.X.shape[0]
        Jb = J[b][used]  # (V', N, 3, 7)
        dense = torch.zeros(Vb, N, 3, 1 + 6 * Vb, dtype=F64, device=device)
        dense[..., 0] = Jb[..., 0]
        for v in range(Vb):
            dense[v, ..., 1 + 6 * v : 7 + 6 * v] = Jb[v, ..., 1:]
        dense = dense.reshape(-1, 1 + 6 * Vb)
        cost = float((r[b] ** 2).sum())
        sigma2 = cost / (dense.shape[0] - 1 - 6 * Vb)
        cov = sigma2 * torch.linalg.inv(dense.T @ dense)[:1, :1]
        assert torch.allclose(res.sigma2[b], torch.tensor(sigma2, dtype=F64, device=device), rtol=1e-9)
        assert torch.allclose(res.covariance[b], cov, rtol=1e-7)
        assert torch.allclose(res.information[b], 1.0 / (cov / sigma2), rtol=1e-7)


def test_undetermined_coordinate_gets_a_huge_finite_variance(device):
    prob, start, truth = _exponential(device, B=2, noise=0.01, idle=True)
    res = schur_lm(prob, start)
    cov = res.covariance
    assert cov.isfinite().all()
    assert (cov[:, 2, 2] > 1e6 * cov[:, 0, 0]).all()  # the pseudo-inverse, not NaN
    assert torch.allclose(res.unknowns["p"][:, :2], truth, rtol=1e-1)


def test_absolute_weights_and_stopping_options(device):
    prob, start, _ = _exponential(device, B=3, noise=0.05)
    rel = schur_lm(prob, start)
    absw = schur_lm(prob, start, absolute_weights=True)
    assert torch.equal(absw.sigma2, torch.ones_like(absw.sigma2))
    assert torch.allclose(absw.covariance * rel.sigma2[:, None, None], rel.covariance, rtol=1e-12)
    capped = schur_lm(prob, start, max_iters=1)
    assert (capped.iterations == 1).all() and (capped.status == LMStatus.MAX_ITERATIONS).all()
    slow = schur_lm(prob, start, lambda_init=1e6)  # heavy damping: many short steps
    stalled = schur_lm(prob, start, lambda_init=1e6, stall_tol=1e300)  # every window of 10 iterations "stalls"
    assert (slow.iterations > 10).all() and (slow.status == LMStatus.CONVERGED).all()
    assert (stalled.iterations == 10).all() and (stalled.status == LMStatus.STALLED).all()


def test_dominated_start_stops_early(device):
    prob, start, _ = _exponential(device, B=1, noise=0.01)
    both = Exponential(prob.x.expand(2, -1), prob.y.expand(2, -1))  # the same problem twice
    far = torch.cat([start["p"], start["p"] * torch.tensor([[0.01, 5.0]], dtype=F64, device=device)])  # a slow start
    free = schur_lm(both, {"p": far})
    grouped = schur_lm(both, {"p": far}, groups=torch.tensor([0, 0], device=device))
    assert grouped.status.tolist() == [LMStatus.CONVERGED, LMStatus.DOMINATED]
    assert grouped.iterations[1] < free.iterations[1] and free.status[1] == LMStatus.CONVERGED
    assert torch.equal(grouped.unknowns["p"][0], free.unknowns["p"][0])


def test_no_data_is_not_solved(device):
    prob, start, _ = _cloud(device, B=2)
    prob.used = torch.zeros_like(prob.used)
    prob.num_residuals = torch.zeros_like(prob.num_residuals)
    res = schur_lm(prob, start)
    assert (res.status == LMStatus.NO_DATA).all() and (res.iterations == 0).all()
    assert torch.equal(res.unknowns["s"], start["s"])


def test_schur_step_matches_a_dense_solve(device, dtype):
    g = torch.Generator().manual_seed(1)
    B, V, G = 2, 3, 4
    J = torch.randn(B, 40, G + 6 * V, generator=g, dtype=F64)
    H = J.mT @ J
    e = torch.randn(B, G + 6 * V, generator=g, dtype=F64)
    W = torch.stack([H[:, G + 6 * v : G + 6 * v + 6, :G].mT for v in range(V)], 1)
    Vb = torch.stack([H[:, G + 6 * v : G + 6 * v + 6, G + 6 * v : G + 6 * v + 6] for v in range(V)], 1)
    # the step neglects the coupling between items (the arrow structure): drop it from the dense system too
    arrow = H.clone()
    for v in range(V):
        for u in range(V):
            if u != v:
                arrow[:, G + 6 * v : G + 6 * v + 6, G + 6 * u : G + 6 * u + 6] = 0
    ref = torch.linalg.solve(arrow, -e)
    args = [t.to(device, dtype) for t in (H[:, :G, :G], W, Vb, e[:, :G], e[:, G:].reshape(B, V, 6))]
    dg, dp = schur_step(*args, torch.ones(B, V, dtype=torch.bool, device=device))
    tol = 1e-8 if dtype == F64 else 1e-2
    assert torch.allclose(dg.double().cpu(), ref[:, :G], rtol=tol, atol=tol)
    assert torch.allclose(dp.double().cpu().flatten(1), ref[:, G:], rtol=tol, atol=tol)
    damped, _ = schur_step(*args, torch.ones(B, V, dtype=torch.bool, device=device), damping=torch.full((B,), 1e3))
    assert (damped.norm(dim=-1) < dg.norm(dim=-1)).all()
    _, parked = schur_step(*args, torch.zeros(B, V, dtype=torch.bool, device=device))
    assert (parked == 0).all()


def test_bad_normal_equations_are_named(device):
    prob, start, _ = _cloud(device, B=2)
    bad = ScaledCloud(prob.X, prob.Y, prob.used)
    bad.linearize = lambda s: replace(prob.linearize(s), W=torch.zeros(2, 5, 2, 6, dtype=F64, device=device))
    with pytest.raises(ValueError, match="W must be"):
        schur_lm(bad, start)
    bad.linearize = lambda s: replace(prob.linearize(s), V=None)
    with pytest.raises(ValueError, match="V must be .* got None"):
        schur_lm(bad, start)
    bad.linearize = lambda s: vars(prob.linearize(s))  # the normal equations as a plain dict
    with pytest.raises(TypeError, match="NormalEquations"):
        schur_lm(bad, start)
    bad.linearize, bad.used = prob.linearize, prob.used[:, :, None]
    with pytest.raises(ValueError, match="used must be"):
        schur_lm(bad, start)


def test_status_values_and_words():
    status = torch.tensor([LMStatus.CONVERGED, LMStatus.MAX_ITERATIONS, LMStatus.NO_DATA])
    assert (status == LMStatus.MAX_ITERATIONS).tolist() == [False, True, False]  # a member compares with entries
    assert [LMStatus(int(v)) for v in status] == [LMStatus.CONVERGED, LMStatus.MAX_ITERATIONS, LMStatus.NO_DATA]
    assert set(LM_STATUS_MESSAGES) == set(LMStatus) and LMStatus.NO_DATA.message == "no data to fit"
    assert [m for m in LMStatus if m.converged] == [LMStatus.CONVERGED, LMStatus.STALLED]


def test_each_problem_of_a_batch_gets_its_own_status(device):
    """One batch whose problems end differently: one without data (every item masked), one converged at the
    iteration limit, one before it, one still running at it; each status, iteration count and solution as the
    problem alone gets them."""
    prob, start, _ = _cloud(device, B=4, noise=0.01, seed=2)
    prob.used[1] = False  # no item with data: nothing to fit
    prob = ScaledCloud(prob.X, prob.Y, prob.used)
    start["s"][3] *= 3.0  # a farther start: slower
    start["R"][2:] = start["R"][2:] @ start["R"][2:]
    free = schur_lm(prob, start)
    assert free.status.tolist() == [LMStatus.CONVERGED, LMStatus.NO_DATA, LMStatus.CONVERGED, LMStatus.CONVERGED]
    n = free.iterations.tolist()
    assert n[1] == 0 and n[0] < n[2] < n[3]
    capped = schur_lm(prob, start, max_iters=n[2])
    want = [LMStatus.CONVERGED, LMStatus.NO_DATA, LMStatus.CONVERGED, LMStatus.MAX_ITERATIONS]
    assert capped.status.tolist() == want and torch.equal(capped.iterations, free.iterations.clamp_max(n[2]))
    for b in range(4):
        keep = torch.arange(4, device=device) == b
        one = schur_lm(prob.take(keep), {k: v[keep] for k, v in start.items()}, max_iters=n[2])
        assert torch.equal(one.status, capped.status[keep]) and torch.equal(one.iterations, capped.iterations[keep])
        assert torch.allclose(one.unknowns["s"], capped.unknowns["s"][keep], rtol=1e-12, atol=0)
    assert torch.equal(capped.unknowns["s"][1], start["s"][1])  # no data: the start, untouched


def test_zero_iterations_leave_every_problem_at_the_limit(device):
    prob, start, _ = _exponential(device, B=2)
    res = schur_lm(prob, start, max_iters=0)
    assert (res.status == LMStatus.MAX_ITERATIONS).all() and (res.iterations == 0).all()
    assert torch.equal(res.unknowns["p"], start["p"])
