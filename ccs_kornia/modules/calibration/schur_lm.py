r"""The one Levenberg–Marquardt loop of the package, on normal equations with the bundle-adjustment arrow structure.

A *problem* (:class:`SchurProblem`) has, per batch entry, a small dense *global* block of ``G`` unknowns (a camera's
intrinsics, a rig's intrinsics and extrinsics, a hand-eye transform) and ``V`` independent 6-unknown *item* blocks
(one board pose per view or frame; ``V`` may be 0). Its normal equations

.. math::
    \begin{pmatrix} U & W^T \\ W & \mathrm{diag}(V_i) \end{pmatrix}
    \begin{pmatrix} \delta g \\ \delta p \end{pmatrix} = -\begin{pmatrix} e_g \\ e_p \end{pmatrix}

are solved by eliminating the item blocks (:func:`schur_step`), so a step costs time linear in ``V``.
:func:`schur_lm` owns everything else, for every solver alike:

* damping: Marquardt's, relative to the diagonal, divided by 10 after an accepted step, multiplied by 10 after a
  rejected one (a step is accepted when it lowers the cost);
* stopping, per problem: an accepted step lowering the cost by at most ``ftol`` relative, a step below ``xtol``
  times the problem's :meth:`~SchurProblem.scale`, a damping beyond ``1e16``, a cost at the problem's ``floor`` (a
  perfect fit), a stall (:data:`STALL_WINDOW` iterations lowering the cost by at most ``stall_tol`` relative), or a
  start dominated by a converged start of the same problem (``groups``, :data:`DOMINATED_RATIO`);
* batching: every iteration runs on the whole working set with per-problem masks (no Python loop over problems);
  "all done?" is read on the host every ``check_every`` iterations only (every iteration on the CPU, where it costs
  nothing; every 10 on other devices), and the finished problems then leave the working set (``shrink``);
* the covariance of the global unknowns at the solution: the inverse of the Schur complement ``S`` (the item blocks
  marginalised), scaled by ``sigma^2 = cost / dof`` (or 1 for absolute weights), with a pseudo-inverse where ``S`` is
  numerically singular (huge, not NaN, variances along the undetermined directions).

The problems written on it: the camera of :mod:`~ccs_kornia.modules.calibration.lm` (global: the free camera
coordinates; items: the views' poses) and the rig of :mod:`~ccs_kornia.modules.rig.rig_lm` (global: every camera's
intrinsics and extrinsics; items: the frames' board poses) and the hand-eye fit of
:mod:`~ccs_kornia.modules.hand_eye.fit` (global: the hand-eye and robot-world transforms, free intrinsics; items: the
robot poses' corrections). The implicit gradients
(:mod:`~ccs_kornia.modules.calibration.implicit`) solve their linear system with :func:`schur_step`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch

from ccs_kornia.geometry.spd_inverse import pseudo_inverse, spd_inverse

__all__ = ["DOMINATED_RATIO", "STALL_WINDOW", "SchurLMResult", "SchurProblem", "schur_lm", "schur_step"]

#: iterations over which ``stall_tol`` compares the cost
STALL_WINDOW = 10
#: with ``groups``, a problem still iterating stops once its cost exceeds this many times a converged problem's of its
#: group (RMS 10x): one start of a problem crawling far above another start's optimum
DOMINATED_RATIO = 100.0
#: the keys of the normal equations every problem returns (``W``, ``V`` and ``ep`` may be left out when ``V = 0``)
EQUATIONS = ("cost", "U", "W", "V", "eg", "ep")


class SchurProblem(Protocol):
    r"""What :func:`schur_lm` needs of a batch of ``B`` problems; everything is batch-first.

    The unknowns live in a *state*: a ``dict`` of tensors of the caller's choice, each with the batch dimension first
    (e.g. ``{"x": (B, P), "R": (B, V, 3, 3), "t": (B, V, 3)}``). The loop never looks inside it: it selects accepted
    states with :func:`torch.where` and the working set by indexing the first dimension.

    Attributes:
        used: :math:`(B, V)` bool, items with data. Their 6x6 blocks are eliminated; the others get a zero step (their
            ``V`` block must be invertible, e.g. the identity). ``V`` may be 0 (global unknowns only).
        num_residuals: :math:`(B,)` number of scalar residuals with a positive weight (2 per image point): the degrees
            of freedom are ``num_residuals - G - 6 * used.sum(-1)``; a problem with 0 is not solved.
        floor: :math:`(B,)` cost at or below which the fit is perfect and stops (e.g. ``1e-20`` times the sum of the
            weights: an RMS of ``1e-10``).
    """

    used: torch.Tensor
    num_residuals: torch.Tensor
    floor: torch.Tensor

    def linearize(self, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        r"""The normal equations at ``state``, with ``r`` the weighted residuals, ``J_g`` / ``J_p`` their derivatives
        by the global / item unknowns: ``cost`` :math:`(B,)` ``= r^T r`` (``inf`` where not finite), ``U``
        :math:`(B, G, G) = J_g^T J_g`, ``W`` :math:`(B, V, G, 6) = J_g^T J_{p_i}`, ``V`` :math:`(B, V, 6, 6) =
        J_{p_i}^T J_{p_i}`, ``eg`` :math:`(B, G) = J_g^T r`, ``ep`` :math:`(B, V, 6) = J_{p_i}^T r`; any further
        batch-first entries (e.g. per-item costs) travel with the accepted state to the result."""

    def retract(self, state: dict[str, torch.Tensor], dg: torch.Tensor, dp: torch.Tensor) -> dict[str, torch.Tensor]:
        r"""A new state moved by the increments ``dg`` :math:`(B, G)` and ``dp`` :math:`(B, V, 6)` (rotations
        multiplicatively, e.g. ``R <- exp(w) R`` with ``w = dp[..., :3]``); never modifies ``state``."""

    def scale(self, state: dict[str, torch.Tensor]) -> torch.Tensor:
        """:math:`(B,)` size of the unknowns (at least 1), against which ``xtol`` measures the largest step entry."""

    def take(self, keep: torch.Tensor) -> SchurProblem:
        """The problems where ``keep`` :math:`(B,)` bool holds (the working set shrinks to them)."""


@dataclass
class SchurLMResult:
    """Output of :func:`schur_lm` (B problems, G global unknowns)."""

    state: dict[str, torch.Tensor]  #: the solution (the initial state where a problem had no data)
    equations: dict[str, torch.Tensor]  #: the undamped normal equations at the solution (and the problem's extras)
    cost: torch.Tensor  #: (B,) weighted sum of squared residuals
    covariance: torch.Tensor  #: (B, G, G) ``sigma2 * S^-1`` of the global unknowns, the items marginalised
    information: torch.Tensor  #: (B, G, G) ``S``, the Schur complement of the item blocks
    sigma2: torch.Tensor  #: (B,) variance factor applied to the covariance
    iterations: torch.Tensor  #: (B,) int64 iterations run while the problem was active
    #: (B,) bool, a tolerance, the floor or the stall rule stopped the problem (not ``max_iters``, not a dominated
    #: start, not a problem without data)
    converged: torch.Tensor


def _solve_spd(A: torch.Tensor, b: torch.Tensor, eye: torch.Tensor) -> torch.Tensor:
    """Solve SPD systems (..., F, F) x = b with Jacobi scaling; systems that fail give 0 (``eye``: I_F)."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    L, info = torch.linalg.cholesky_ex(A * (d[..., :, None] * d[..., None, :]))
    bad = info != 0
    # a failed factor is replaced by the identity (its solution is then zeroed)
    L = torch.where(bad[..., None, None], eye, L)
    # (the inverse, not cholesky_solve: a problem's result does not depend on the other problems of the batch)
    x = (torch.cholesky_inverse(L) @ (b * d).unsqueeze(-1)).squeeze(-1) * d
    return x.masked_fill(bad[..., None] | ~x.isfinite(), 0.0)


def _step(U, W, Vb, eg, ep, lam, used_f, eyeG):
    """:func:`schur_step` with the item mask as a float and the identity given (the loop's form)."""
    dU = U.diagonal(dim1=-2, dim2=-1)
    # a floor keeps the damped system definite where a column vanishes (e.g. a distortion centre at k = 0)
    if dU.shape[-1]:
        dU = torch.maximum(dU, 1e-12 * dU.amax(-1, keepdim=True).clamp_min(1e-300))
    Ud = U.clone()
    Ud.diagonal(dim1=-2, dim2=-1).add_(dU * lam[:, None])
    Vd = Vb.clone()
    Vd.diagonal(dim1=-2, dim2=-1).mul_((1 + lam)[:, None, None])
    # the damped 6x6 item blocks are definite (unused items: the identity); a failed inverse is zeroed
    Vinv = torch.linalg.inv_ex(Vd)[0].nan_to_num_(0.0, 0.0, 0.0)
    Y = W @ Vinv  # (B, V, G, 6)
    S = Ud - (Y @ W.transpose(-1, -2)).sum(1)
    dg = _solve_spd(S, (Y @ ep.unsqueeze(-1)).sum(1).squeeze(-1) - eg, eyeG)
    dp = (Vinv @ (ep.unsqueeze(-1) + W.transpose(-1, -2) @ dg[:, None, :, None])).squeeze(-1)
    return dg, dp * (-used_f)[..., None]


def schur_step(
    U: torch.Tensor,
    W: torch.Tensor,
    V: torch.Tensor,
    eg: torch.Tensor,
    ep: torch.Tensor,
    used: torch.Tensor,
    damping: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Damped Gauss-Newton step of arrow-structured normal equations: eliminate the item blocks, solve the global
    block (Schur complement), back-substitute.

    Solves :math:`(U + \lambda D_U) \delta g + W^T \delta p = -e_g`, :math:`W \delta g + (1 + \lambda) V \delta p =
    -e_p` with :math:`D_U` the diagonal of ``U`` (floored at ``1e-12`` of its largest entry). A system that cannot be
    solved gives a zero step.

    Args:
        U: :math:`(B, G, G)`; W: :math:`(B, V, G, 6)`; V: :math:`(B, V, 6, 6)` (invertible where not ``used``);
        eg: :math:`(B, G)`; ep: :math:`(B, V, 6)`: the normal equations (:meth:`SchurProblem.linearize`).
        used: :math:`(B, V)` items that move (the others get a zero step).
        damping: :math:`(B,)` Marquardt's :math:`\lambda` (default 0: the Gauss-Newton step).

    Returns:
        ``(dg, dp)``: :math:`(B, G)` and :math:`(B, V, 6)`.

    Example:
        >>> U = torch.tensor([[[4.0, 1.0], [1.0, 3.0]]], dtype=torch.float64)
        >>> dg, dp = schur_step(U, U.new_zeros(1, 0, 2, 6), U.new_zeros(1, 0, 6, 6), U.new_tensor([[1.0, 2.0]]),
        ...                     U.new_zeros(1, 0, 6), torch.zeros(1, 0, dtype=torch.bool))
        >>> torch.allclose(U[0] @ dg[0], -U.new_tensor([1.0, 2.0])), dp.shape
        (True, torch.Size([1, 0, 6]))
    """
    lam = U.new_zeros(U.shape[0]) if damping is None else damping.to(U)
    eyeG = torch.eye(U.shape[-1], dtype=U.dtype, device=U.device)
    return _step(U, W, V, eg, ep, lam, used.to(U.dtype), eyeG)


def _complete(eq: dict[str, torch.Tensor], V: int) -> dict[str, torch.Tensor]:
    """The normal equations with empty item blocks filled in for a problem without items."""
    if "W" in eq:
        return eq
    U = eq["U"]
    B, G = U.shape[:2]
    return {**eq, "W": U.new_zeros(B, V, G, 6), "V": U.new_zeros(B, V, 6, 6), "ep": U.new_zeros(B, V, 6)}


def _check(problem, eq: dict[str, torch.Tensor]) -> None:
    """The problem's masks and its first normal equations have the shapes of the protocol."""
    used = problem.used
    if not isinstance(used, torch.Tensor) or used.dim() != 2 or used.dtype != torch.bool:
        raise ValueError(f"problem.used must be (B, V) bool, got {tuple(getattr(used, 'shape', ()))}.")
    B, V = used.shape
    for name in ("num_residuals", "floor"):
        value = getattr(problem, name)
        if not isinstance(value, torch.Tensor) or value.shape != (B,):
            raise ValueError(f"problem.{name} must be ({B},), got {tuple(getattr(value, 'shape', ()))}.")
    missing = [k for k in EQUATIONS if k not in eq]
    if missing:
        raise ValueError(f"problem.linearize must return {list(EQUATIONS)}, missing {missing}.")
    G = eq["U"].shape[-1] if eq["U"].dim() == 3 else -1
    shapes = {"cost": (B,), "U": (B, G, G), "W": (B, V, G, 6), "V": (B, V, 6, 6), "eg": (B, G), "ep": (B, V, 6)}
    for k, shape in shapes.items():
        if tuple(eq[k].shape) != shape:
            raise ValueError(f"{k} must be {shape} (B={B} problems, V={V} items, G={G}), got {tuple(eq[k].shape)}.")


def _iterate(problem, eq, state, ctl, ftol, xtol, eyeG, used_f):
    """One LM iteration of every problem of the working set (``eq``, ``state``, ``ctl`` updated in place); problems
    that are done keep their values."""
    lam, cost = ctl["lam"], eq["cost"]
    active = ~ctl["done"]
    dg, dp = _step(eq["U"], eq["W"], eq["V"], eq["eg"], eq["ep"], lam, used_f, eyeG)
    cand = problem.retract(state, dg, dp)
    new = _complete(problem.linearize(cand), dp.shape[1])
    cost_n = new["cost"]

    accept = (cost_n < cost) & active
    step = torch.cat([dg.abs(), dp.abs().flatten(1), torch.zeros_like(cost[:, None])], -1).amax(-1)
    small_step = step <= xtol * problem.scale(state)
    small_decrease = (cost - cost_n).abs() <= ftol * cost
    finished = (accept & small_decrease) | small_step | (lam > 1e16)
    finished = active & (finished | (torch.where(accept, cost_n, cost) <= problem.floor))

    mode = "mask"
    if cost.device.type == "cpu":  # reading a flag costs nothing on the host: skip the selects when all agree
        mode = "all" if bool(accept.all()) else ("none" if not bool(accept.any()) else "mask")
    for old, upd in ((eq, new), (state, cand)):
        if mode == "all":
            old.update(upd)
        elif mode == "mask":
            for k, v in upd.items():
                old[k] = torch.where(accept.view(-1, *([1] * (v.dim() - 1))), v, old[k])
    ctl["lam"] = torch.where(active, torch.where(accept, (lam / 10).clamp_min(1e-15), lam * 10), lam)
    ctl["iters"] = ctl["iters"] + active.long()
    ctl["done"] = ctl["done"] | finished
    ctl["converged"] = ctl["converged"] | finished


def schur_lm(
    problem: SchurProblem,
    state: dict[str, torch.Tensor],
    max_iters: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    lambda_init: float = 1e-3,
    check_every: int | None = None,
    stall_tol: float = 0.0,
    groups: torch.Tensor | None = None,
    absolute_weights: bool = False,
    shrink: bool = True,
) -> SchurLMResult:
    r"""Levenberg–Marquardt on a batch of arrow-structured problems (see the module doc and :class:`SchurProblem`).

    Args:
        problem: the :class:`SchurProblem` (B problems).
        state: the initial unknowns, a dict of batch-first tensors (not modified).
        max_iters: iterations at most.
        ftol: a problem stops when an accepted step lowers its cost by at most ``ftol`` relative.
        xtol: a problem stops when its largest step entry is at most ``xtol`` times its ``problem.scale``.
        lambda_init: initial Marquardt damping (relative to the diagonal).
        check_every: iterations between "all done?" checks (a host synchronisation); default 1 on CPU, 10 else.
        stall_tol: a problem also stops (converged) when :data:`STALL_WINDOW` iterations together lowered its cost by
            at most ``stall_tol`` relative (0: never): a crawl along a direction the data barely determine, where
            every step still passes ``ftol`` but the fit no longer changes for any practical purpose.
        groups: :math:`(B,)` integers: problems that are other starts of one problem (the same data). At each "all
            done?" check a problem still iterating stops, not converged, where its cost exceeds
            :data:`DOMINATED_RATIO` times a converged problem's of its group with as many used items.
        absolute_weights: the residuals are weighted by absolute inverse variances: ``sigma2 = 1``.
        shrink: finished problems leave the working set at the checks (the results are the same either way).

    Returns:
        :class:`SchurLMResult`.

    Example:
        A straight line ``y = a + b x`` (two global unknowns, no items):

        >>> class Line:
        ...     def __init__(self, x, y):
        ...         self.x, self.y = x, y  # (B, N)
        ...         self.used = torch.zeros(x.shape[0], 0, dtype=torch.bool)
        ...         self.num_residuals = torch.full((x.shape[0],), x.shape[1])
        ...         self.floor = torch.full((x.shape[0],), 1e-30, dtype=x.dtype)
        ...     def linearize(self, s):
        ...         J = torch.stack([torch.ones_like(self.x), self.x], -1)  # (B, N, 2)
        ...         r = s["ab"][:, :1] + s["ab"][:, 1:] * self.x - self.y
        ...         return {"cost": (r * r).sum(-1), "U": J.mT @ J, "eg": (J.mT @ r[..., None])[..., 0]}
        ...     def retract(self, s, dg, dp):
        ...         return {"ab": s["ab"] + dg}
        ...     def scale(self, s):
        ...         return s["ab"].abs().amax(-1).clamp_min(1.0)
        ...     def take(self, keep):
        ...         return Line(self.x[keep], self.y[keep])
        >>> x = torch.linspace(0.0, 1.0, 5, dtype=torch.float64)[None]
        >>> res = schur_lm(Line(x, 2 + 3 * x), {"ab": torch.zeros(1, 2, dtype=torch.float64)})
        >>> res.state["ab"].round(decimals=6).tolist(), bool(res.converged), res.covariance.shape
        ([[2.0, 3.0]], True, torch.Size([1, 2, 2]))
    """
    used = problem.used
    V = used.shape[-1] if isinstance(used, torch.Tensor) and used.dim() == 2 else 0
    eq = _complete(problem.linearize(state), V)
    _check(problem, eq)
    B = used.shape[0]
    has_data = problem.num_residuals > 0
    cost = eq["cost"]
    dtype, device = cost.dtype, cost.device
    eyeG = torch.eye(eq["U"].shape[-1], dtype=dtype, device=device)
    if check_every is None:
        check_every = 1 if device.type == "cpu" else 10
    done = ~has_data
    ctl = {"lam": torch.full((B,), lambda_init, dtype=dtype, device=device), "done": done, "converged": done.clone(),
           "iters": torch.zeros(B, dtype=torch.long, device=device), "stall_ref": cost.clone()}
    full = {"eq": eq, "state": dict(state), "ctl": ctl}
    # the working set: every problem still iterating; it shrinks (a gather) only at the "all done?" checks
    idx = torch.arange(B, device=device)
    work, wp, used_f = {k: dict(v) for k, v in full.items()}, problem, used.to(dtype)
    owned: set = set()  # entries of ``full`` copied before a write (the problem's or the caller's tensors otherwise)

    def write_back(rows, sel):
        for part, entries in work.items():
            for k, v in entries.items():
                if v is not full[part][k]:  # (an entry never updated is still the full tensor itself)
                    if (part, k) not in owned:
                        full[part][k] = full[part][k].clone()
                        owned.add((part, k))
                    full[part][k][rows] = v if sel is None else v[sel]

    if groups is not None:  # a group per problem and number of used items; its best converged cost so far
        key = groups.to(device).long() * (V + 1) + used.sum(-1)
        best = torch.full((int(key.max()) + 1 if B else 0,), float("inf"), dtype=dtype, device=device)
    for it in range(max_iters):
        w_eq, w_state, w_ctl = work["eq"], work["state"], work["ctl"]
        _iterate(wp, w_eq, w_state, w_ctl, ftol, xtol, eyeG, used_f)
        if stall_tol > 0 and (it + 1) % STALL_WINDOW == 0:
            stalled = ~w_ctl["done"] & (w_ctl["stall_ref"] - w_eq["cost"] <= stall_tol * w_eq["cost"])
            w_ctl["done"] = w_ctl["done"] | stalled
            w_ctl["converged"] = w_ctl["converged"] | stalled
            w_ctl["stall_ref"] = w_eq["cost"].clone()
        if (it + 1) % check_every == 0:
            if groups is not None:
                fit = w_ctl["converged"] & w_eq["cost"].isfinite() & has_data[idx]
                best.scatter_reduce_(0, key[idx], torch.where(fit, w_eq["cost"], float("inf")), "amin")
                w_ctl["done"] = w_ctl["done"] | (w_eq["cost"] > DOMINATED_RATIO * best[key[idx]])
            alive = ~w_ctl["done"]
            if not bool(alive.any()):
                break
            if shrink and not bool(alive.all()):
                leaving = ~alive
                write_back(idx[leaving], leaving)
                idx = idx[alive]
                work = {part: {k: v[alive] for k, v in entries.items()} for part, entries in work.items()}
                wp, used_f = wp.take(alive), used_f[alive]
    if idx.numel() == B:  # no problem left early: the working set is the whole batch
        full = work
    else:
        write_back(idx, None)
    eq, state, ctl = full["eq"], full["state"], full["ctl"]

    # covariance at the solution (no damping)
    U, W, Vb, cost = eq["U"], eq["W"], eq["V"], eq["cost"]
    Vinv = spd_inverse(Vb)
    Vinv = torch.where(used[..., None, None] & Vinv.isfinite(), Vinv, torch.zeros_like(Vinv))
    S = U - ((W @ Vinv) @ W.transpose(-1, -2)).sum(1)
    G = S.shape[-1]
    dof = (problem.num_residuals - G - 6 * used.sum(-1)).clamp_min(1).to(dtype)
    sigma2 = torch.ones_like(cost) if absolute_weights else cost / dof
    cov = spd_inverse(S)
    # a (numerically) singular information matrix gives a huge, not a NaN, variance along the undetermined
    # directions, so the degeneracy checks can tell which parameters the data do not constrain
    singular = ~cov.flatten(1).isfinite().all(-1) & S.flatten(1).isfinite().all(-1) & has_data
    if G and bool(singular.any()):
        cov[singular] = pseudo_inverse(S[singular])
    cov = cov * sigma2[:, None, None]
    return SchurLMResult(state=state, equations=eq, cost=cost, covariance=cov, information=S, sigma2=sigma2,
                         iterations=ctl["iters"], converged=ctl["converged"] & has_data)
