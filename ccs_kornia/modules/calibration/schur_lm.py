r"""The one Levenberg–Marquardt loop of the package, on normal equations with the bundle-adjustment arrow structure.

A *problem* (:class:`SchurProblem`) has, per batch entry, a small dense *global* block of ``G`` unknowns (a camera's
intrinsics, a rig's intrinsics and extrinsics, a hand-eye transform) and ``V`` *item* blocks of ``k`` unknowns each
(one 6-dof board pose per view or frame; ``V`` may be 0). Its normal equations (:class:`NormalEquations`)

.. math::
    \begin{pmatrix} U & W^T \\ W & \mathrm{diag}(V_i) \end{pmatrix}
    \begin{pmatrix} \delta g \\ \delta p \end{pmatrix} = -\begin{pmatrix} e_g \\ e_p \end{pmatrix}

are solved by eliminating the item blocks (:func:`schur_step`), so a step costs time linear in ``V``. The items are
independent (a block-diagonal :math:`V`) or couple their ``w`` next neighbours (a block-banded one, ``Vband``: the
control points of a trajectory spline), eliminated then by a banded solve
(:mod:`~ccs_kornia.modules.calibration.block_banded`: block cyclic reduction), still in time linear in ``V``.
:func:`schur_lm` owns everything else, for every solver alike; what it carries from one iteration to the next is an
:class:`LMState`:

* damping: Marquardt's, relative to the diagonal, divided by 10 after an accepted step, multiplied by 10 after a
  rejected one (a step is accepted when it lowers the cost);
* ending, per problem, with an :class:`LMStatus`: ``CONVERGED`` on an accepted step lowering the cost by at most
  ``ftol`` relative, a step below ``xtol`` times the problem's :meth:`~SchurProblem.scale`, a damping beyond ``1e16``
  or a cost at the problem's ``floor`` (a perfect fit); ``STALLED`` when :data:`STALL_WINDOW` iterations lowered the
  cost by at most ``stall_tol`` relative; ``DOMINATED`` for a start far above a converged start of the same problem
  (``groups``, :data:`DOMINATED_RATIO`); ``MAX_ITERATIONS`` for a problem still running after ``max_iters``;
  ``NO_DATA`` for a problem without residuals (never iterated);
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

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from enum import IntEnum
from typing import Any, Protocol

import torch

from ccs_kornia.geometry.spd_inverse import LARGE_SYSTEM, pseudo_inverse, spd_inverse
from ccs_kornia.modules.calibration.block_banded import block_banded_solve
from ccs_kornia.runtime.checks import check_tensor

__all__ = [
    "DOMINATED_RATIO",
    "LM_STATUS_MESSAGES",
    "MAX_DAMPING",
    "STALL_WINDOW",
    "LMState",
    "LMStatus",
    "NormalEquations",
    "SchurLMResult",
    "SchurProblem",
    "schur_lm",
    "schur_step",
]

#: iterations over which ``stall_tol`` compares the cost
STALL_WINDOW = 10
#: with ``groups``, a problem still iterating stops once its cost exceeds this many times a converged problem's of its
#: group (RMS 10x): one start of a problem crawling far above another start's optimum
DOMINATED_RATIO = 100.0
#: the damping beyond which no step lowers the cost any more: the problem is at its optimum to working precision
MAX_DAMPING = 1e16


class LMStatus(IntEnum):
    """How :func:`schur_lm` ended a problem: the values of ``SchurLMResult.status`` (an int64 tensor, so a member
    compares with its entries: ``res.status == LMStatus.CONVERGED``).

    ``RUNNING`` is the loop's own value for a problem still iterating; a result never holds it.

    Example:
        >>> LMStatus(3), LMStatus.MAX_ITERATIONS.message
        (<LMStatus.MAX_ITERATIONS: 3>, 'stopped at the iteration limit')
        >>> torch.tensor([1, 3]) == LMStatus.CONVERGED
        tensor([ True, False])
    """

    RUNNING = 0
    CONVERGED = 1
    STALLED = 2
    MAX_ITERATIONS = 3
    DOMINATED = 4
    NO_DATA = 5

    @property
    def message(self) -> str:
        """The status in words (e.g. the rig record's ``fit.status``)."""
        return LM_STATUS_MESSAGES[self]

    @property
    def converged(self) -> bool:
        """The fit settled at an optimum: ``CONVERGED``, or ``STALLED`` (the cost no longer changes for any practical
        purpose); not at the iteration limit, not a dominated start, not a problem without data."""
        return self in (LMStatus.CONVERGED, LMStatus.STALLED)


#: each :class:`LMStatus` in words
LM_STATUS_MESSAGES: dict[int, str] = {
    LMStatus.RUNNING: "still iterating",
    LMStatus.CONVERGED: "converged",
    LMStatus.STALLED: "stalled (the cost barely decreased any more)",
    LMStatus.MAX_ITERATIONS: "stopped at the iteration limit",
    LMStatus.DOMINATED: "left off: far above a converged start of the same problem",
    LMStatus.NO_DATA: "no data to fit",
}


@dataclass
class NormalEquations:
    r"""The normal equations of ``B`` problems at one point (what :meth:`SchurProblem.linearize` returns), with ``r``
    the weighted residuals and ``J_g`` / ``J_p`` their derivatives by the global / item unknowns.

    A problem may return a subclass with further batch-first fields (e.g. per-item costs, declared
    ``kw_only``): they travel with the accepted point to ``SchurLMResult.equations``.

    Args:
        cost: :math:`(B,)` ``r^T r`` (``inf`` where not finite).
        U: :math:`(B, G, G)` ``J_g^T J_g``.
        eg: :math:`(B, G)` ``J_g^T r``.
        W: :math:`(B, V, G, k)` ``J_g^T J_{p_i}`` (``None``, with ``V`` and ``ep``, for a problem without items).
        V: :math:`(B, V, k, k)` ``J_{p_i}^T J_{p_i}`` (invertible where an item is not used, e.g. the identity).
        ep: :math:`(B, V, k)` ``J_{p_i}^T r``.
        Vband: :math:`(B, V, w, k, k)` ``J_{p_i}^T J_{p_{i+j}}`` for ``j = 1 .. w`` (entries past the last item are
            ignored), or ``None``: the items are independent.

    Example:
        >>> J, r = torch.tensor([[[1.0], [2.0]]]), torch.tensor([[0.5, -1.0]])
        >>> eq = NormalEquations(cost=(r * r).sum(-1), U=J.mT @ J, eg=(J.mT @ r[..., None])[..., 0])
        >>> eq.U.tolist(), eq.eg.tolist(), eq.W is None
        ([[[5.0]]], [[-1.5]], True)
    """

    cost: torch.Tensor
    U: torch.Tensor
    eg: torch.Tensor
    W: torch.Tensor | None = None
    V: torch.Tensor | None = None
    ep: torch.Tensor | None = None
    Vband: torch.Tensor | None = None


@dataclass
class LMState:
    r"""Where :func:`schur_lm` stands with ``B`` problems: everything it carries from one iteration to the next, each
    entry batch-first (the working set selects and shrinks them by rows).

    Args:
        unknowns: the problem's unknowns at the last accepted step (its own dict of batch-first tensors).
        equations: :class:`NormalEquations` there.
        damping: :math:`(B,)` Marquardt's :math:`\lambda` of the next step.
        iterations: :math:`(B,)` int64 iterations run while the problem was running.
        status: :math:`(B,)` int64 :class:`LMStatus`, ``RUNNING`` until a rule ends the problem.
        stall_cost: :math:`(B,)` the cost at the start of the current :data:`STALL_WINDOW`.
    """

    unknowns: dict[str, torch.Tensor]
    equations: NormalEquations
    damping: torch.Tensor
    iterations: torch.Tensor
    status: torch.Tensor
    stall_cost: torch.Tensor

    @property
    def running(self) -> torch.Tensor:
        """:math:`(B,)` bool, the problems still iterating."""
        return self.status == LMStatus.RUNNING


class SchurProblem(Protocol):
    r"""What :func:`schur_lm` needs of a batch of ``B`` problems; everything is batch-first.

    The unknowns are a ``dict`` of tensors of the caller's choice, each with the batch dimension first (e.g.
    ``{"x": (B, P), "R": (B, V, 3, 3), "t": (B, V, 3)}``). The loop never looks inside it: it selects accepted
    unknowns with :func:`torch.where` and the working set by indexing the first dimension.

    Attributes:
        used: :math:`(B, V)` bool, items with data. Their ``k x k`` blocks are eliminated; the others get a zero step (their
            ``V`` block must be invertible, e.g. the identity). ``V`` may be 0 (global unknowns only).
        num_residuals: :math:`(B,)` number of scalar residuals with a positive weight (2 per image point): the degrees
            of freedom are ``num_residuals - G - k * used.sum(-1)``; a problem with 0 is not solved (``NO_DATA``).
        floor: :math:`(B,)` cost at or below which the fit is perfect and stops (e.g. ``1e-20`` times the sum of the
            weights: an RMS of ``1e-10``).
    """

    used: torch.Tensor
    num_residuals: torch.Tensor
    floor: torch.Tensor

    def linearize(self, unknowns: dict[str, torch.Tensor]) -> NormalEquations:
        """The :class:`NormalEquations` at ``unknowns``."""

    def retract(self, unknowns: dict[str, torch.Tensor], dg: torch.Tensor, dp: torch.Tensor) -> dict[str, torch.Tensor]:
        r"""New unknowns moved by the increments ``dg`` :math:`(B, G)` and ``dp`` :math:`(B, V, k)` (rotations
        multiplicatively, e.g. ``R <- exp(w) R`` with ``w = dp[..., :3]``); never modifies ``unknowns``."""

    def scale(self, unknowns: dict[str, torch.Tensor]) -> torch.Tensor:
        """:math:`(B,)` size of the unknowns (at least 1), against which ``xtol`` measures the largest step entry."""

    def take(self, keep: torch.Tensor) -> SchurProblem:
        """The problems where ``keep`` :math:`(B,)` bool holds (the working set shrinks to them)."""


@dataclass
class SchurLMResult:
    """Output of :func:`schur_lm` (B problems, G global unknowns)."""

    unknowns: dict[str, torch.Tensor]  #: the solution (the initial unknowns where a problem had no data)
    equations: NormalEquations  #: the undamped normal equations at the solution (the problem's own type)
    cost: torch.Tensor  #: (B,) weighted sum of squared residuals
    covariance: torch.Tensor  #: (B, G, G) ``sigma2 * S^-1`` of the global unknowns, the items marginalised
    information: torch.Tensor  #: (B, G, G) ``S``, the Schur complement of the item blocks
    sigma2: torch.Tensor  #: (B,) variance factor applied to the covariance
    iterations: torch.Tensor  #: (B,) int64 iterations run while the problem was active
    status: torch.Tensor  #: (B,) int64 :class:`LMStatus`, how the loop ended each problem (never ``RUNNING``)


def _entries(x: Any) -> list[tuple[str, Any]]:
    """The named entries of a dict or a dataclass."""
    return list(x.items()) if isinstance(x, dict) else [(f.name, getattr(x, f.name)) for f in fields(x)]


def _map(fn: Callable, x: Any, *others: Any, path: tuple = ()) -> Any:
    """``fn(path, tensor, *tensors of others at the same place)`` over the tensors of ``x``, a tensor, ``None`` or a
    dict or dataclass of them (nested); the same structure with the results."""
    if x is None:
        return None
    if isinstance(x, torch.Tensor):
        return fn(path, x, *others)
    get = (lambda o, k: o[k]) if isinstance(x, dict) else getattr
    values = {k: _map(fn, v, *(get(o, k) for o in others), path=(*path, k)) for k, v in _entries(x)}
    return values if isinstance(x, dict) else replace(x, **values)


def _select(keep: torch.Tensor, new: Any, old: Any) -> Any:
    """``new`` where ``keep`` :math:`(B,)` holds, ``old`` elsewhere, entry by entry."""
    return _map(lambda _, a, b: torch.where(keep.view(-1, *([1] * (a.dim() - 1))), a, b), new, old)


def _solve_spd(A: torch.Tensor, b: torch.Tensor, eye: torch.Tensor) -> torch.Tensor:
    """Solve SPD systems (..., F, F) x = b with Jacobi scaling; systems that fail give 0 (``eye``: I_F)."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    L, info = torch.linalg.cholesky_ex(A * (d[..., :, None] * d[..., None, :]))
    bad = info != 0
    # a failed factor is replaced by the identity (its solution is then zeroed)
    L = torch.where(bad[..., None, None], eye, L)
    # (the inverse, not cholesky_solve: a problem's result does not depend on the other problems of the batch; a large
    # system (a spline's) is solved: there the inverse costs seconds)
    if A.shape[-1] > LARGE_SYSTEM:
        x = torch.cholesky_solve((b * d).unsqueeze(-1), L).squeeze(-1) * d
    else:
        x = (torch.cholesky_inverse(L) @ (b * d).unsqueeze(-1)).squeeze(-1) * d
    return x.masked_fill(bad[..., None] | ~x.isfinite(), 0.0)


def _banded_elimination(W, Vd, Vband, ep):
    """``(V^-1 W^T, V^-1 ep)`` of block-banded items: :math:`(B, V, k, G)` and :math:`(B, V, k)`."""
    G = W.shape[-2]
    Z = block_banded_solve(Vd, Vband, torch.cat([W.transpose(-1, -2), ep[..., None]], -1))[0]
    return Z[..., :G], Z[..., G]


def _items_product(Y: torch.Tensor, W: torch.Tensor) -> torch.Tensor:
    """``sum_i Y_i W_i^T`` :math:`(B, G, G)` of :math:`(B, V, G, k)` blocks; for a large ``G`` (a spline's) one product
    over the items and their unknowns at once, without the :math:`(B, V, G, G)` terms."""
    if W.shape[-2] <= LARGE_SYSTEM:
        return (Y @ W.transpose(-1, -2)).sum(1)
    B, V, G, k = W.shape
    return Y.transpose(1, 2).reshape(B, G, V * k) @ W.transpose(1, 2).reshape(B, G, V * k).transpose(-1, -2)


def _step(U, W, Vb, eg, ep, lam, used_f, eyeG, Vband=None):
    """:func:`schur_step` with the item mask as a float and the identity given (the loop's form)."""
    dU = U.diagonal(dim1=-2, dim2=-1)
    # a floor keeps the damped system definite where a column vanishes (e.g. a distortion centre at k = 0)
    if dU.shape[-1]:
        dU = torch.maximum(dU, 1e-12 * dU.amax(-1, keepdim=True).clamp_min(1e-300))
    Ud = U.clone()
    Ud.diagonal(dim1=-2, dim2=-1).add_(dU * lam[:, None])
    Vd = Vb.clone()
    Vd.diagonal(dim1=-2, dim2=-1).mul_((1 + lam)[:, None, None])
    if Vband is not None:
        ZW, Ze = _banded_elimination(W, Vd, Vband, ep)
        S = Ud - (W @ ZW).sum(1)
        dg = _solve_spd(S, (W @ Ze[..., None]).sum(1)[..., 0] - eg, eyeG)
        dp = Ze + (ZW @ dg[:, None, :, None])[..., 0]
        return dg, dp * (-used_f)[..., None]
    # the damped item blocks are definite (unused items: the identity); a failed inverse is zeroed
    Vinv = torch.linalg.inv_ex(Vd)[0].nan_to_num_(0.0, 0.0, 0.0)
    Y = W @ Vinv  # (B, V, G, 6)
    S = Ud - _items_product(Y, W)
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
    Vband: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Damped Gauss-Newton step of arrow-structured normal equations: eliminate the item blocks, solve the global
    block (Schur complement), back-substitute.

    Solves :math:`(U + \lambda D_U) \delta g + W^T \delta p = -e_g`, :math:`W \delta g + (1 + \lambda) V \delta p =
    -e_p` with :math:`D_U` the diagonal of ``U`` (floored at ``1e-12`` of its largest entry). A system that cannot be
    solved gives a zero step.

    Args:
        U: :math:`(B, G, G)`; W: :math:`(B, V, G, k)`; V: :math:`(B, V, k, k)` (invertible where not ``used``);
        eg: :math:`(B, G)`; ep: :math:`(B, V, k)`: the normal equations (:meth:`SchurProblem.linearize`).
        used: :math:`(B, V)` items that move (the others get a zero step).
        damping: :math:`(B,)` Marquardt's :math:`\lambda` (default 0: the Gauss-Newton step).
        Vband: :math:`(B, V, w, k, k)` the couplings of banded items (:class:`NormalEquations`), or ``None``.

    Returns:
        ``(dg, dp)``: :math:`(B, G)` and :math:`(B, V, k)`.

    Example:
        >>> U = torch.tensor([[[4.0, 1.0], [1.0, 3.0]]], dtype=torch.float64)
        >>> dg, dp = schur_step(U, U.new_zeros(1, 0, 2, 6), U.new_zeros(1, 0, 6, 6), U.new_tensor([[1.0, 2.0]]),
        ...                     U.new_zeros(1, 0, 6), torch.zeros(1, 0, dtype=torch.bool))
        >>> torch.allclose(U[0] @ dg[0], -U.new_tensor([1.0, 2.0])), dp.shape
        (True, torch.Size([1, 0, 6]))
    """
    lam = U.new_zeros(U.shape[0]) if damping is None else damping.to(U)
    eyeG = torch.eye(U.shape[-1], dtype=U.dtype, device=U.device)
    return _step(U, W, V, eg, ep, lam, used.to(U.dtype), eyeG, Vband)


def _complete(eq: NormalEquations, V: int) -> NormalEquations:
    """The normal equations with empty item blocks filled in for a problem without items."""
    if eq.W is not None:
        return eq
    B, G = eq.U.shape[:2]
    U = eq.U
    return replace(eq, W=U.new_zeros(B, V, G, 6), V=U.new_zeros(B, V, 6, 6), ep=U.new_zeros(B, V, 6))


def _check(problem, eq: NormalEquations) -> None:
    """The problem's masks and its first normal equations have the shapes of the protocol."""
    used = problem.used
    check_tensor(used, "problem.used", ["B", "V"], what="bool")
    if used.dtype != torch.bool:
        raise ValueError(f"problem.used must be (B, V) bool, got {used.dtype}.")
    B, V = used.shape
    for name in ("num_residuals", "floor"):
        check_tensor(getattr(problem, name), f"problem.{name}", [B])
    G = eq.U.shape[-1] if eq.U.dim() == 3 else "G"
    k = eq.V.shape[-1] if eq.V is not None and eq.V.dim() == 4 else "k"
    shapes = {"cost": (B,), "U": (B, G, G), "W": (B, V, G, k), "V": (B, V, k, k), "eg": (B, G), "ep": (B, V, k)}
    if eq.Vband is not None:
        shapes["Vband"] = (B, V, "w", k, k)
    for name, shape in shapes.items():
        check_tensor(getattr(eq, name), name, shape, what=f"(B={B} problems, V={V} items, G={G}, k={k})")


def _iterate(problem, s: LMState, ftol, xtol, eyeG, used_f) -> None:
    """One LM iteration of every problem of the working set ``s`` (updated in place); problems that are not running
    keep their values."""
    eq, lam, cost = s.equations, s.damping, s.equations.cost
    active = s.running
    dg, dp = _step(eq.U, eq.W, eq.V, eq.eg, eq.ep, lam, used_f, eyeG, eq.Vband)
    cand = problem.retract(s.unknowns, dg, dp)
    new = _complete(problem.linearize(cand), dp.shape[1])
    cost_n = new.cost

    accept = (cost_n < cost) & active
    step = torch.cat([dg.abs(), dp.abs().flatten(1), torch.zeros_like(cost[:, None])], -1).amax(-1)
    small_step = step <= xtol * problem.scale(s.unknowns)
    small_decrease = (cost - cost_n).abs() <= ftol * cost
    finished = (accept & small_decrease) | small_step | (lam > MAX_DAMPING)
    finished = active & (finished | (torch.where(accept, cost_n, cost) <= problem.floor))

    mode = "mask"
    if cost.device.type == "cpu":  # reading a flag costs nothing on the host: skip the selects when all agree
        mode = "all" if bool(accept.all()) else ("none" if not bool(accept.any()) else "mask")
    if mode == "all":
        s.equations, s.unknowns = new, cand
    elif mode == "mask":
        s.equations, s.unknowns = _select(accept, new, eq), _select(accept, cand, s.unknowns)
    s.damping = torch.where(active, torch.where(accept, (lam / 10).clamp_min(1e-15), lam * 10), lam)
    s.iterations = s.iterations + active.long()
    s.status = s.status.masked_fill(finished, LMStatus.CONVERGED)


def schur_lm(
    problem: SchurProblem,
    unknowns: dict[str, torch.Tensor],
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
        unknowns: the initial unknowns, a dict of batch-first tensors (not modified).
        max_iters: iterations at most (a problem still running then ends ``MAX_ITERATIONS``).
        ftol: a problem converges when an accepted step lowers its cost by at most ``ftol`` relative.
        xtol: a problem converges when its largest step entry is at most ``xtol`` times its ``problem.scale``.
        lambda_init: initial Marquardt damping (relative to the diagonal).
        check_every: iterations between "all done?" checks (a host synchronisation); default 1 on CPU, 10 else.
        stall_tol: a problem also ends (``STALLED``) when :data:`STALL_WINDOW` iterations together lowered its cost
            by at most ``stall_tol`` relative (0: never): a crawl along a direction the data barely determine, where
            every step still passes ``ftol`` but the fit no longer changes for any practical purpose.
        groups: :math:`(B,)` integers: problems that are other starts of one problem (the same data). At each "all
            done?" check a problem still iterating ends (``DOMINATED``) where its cost exceeds
            :data:`DOMINATED_RATIO` times a converged (or stalled) problem's of its group with as many used items.
        absolute_weights: the residuals are weighted by absolute inverse variances: ``sigma2 = 1``.
        shrink: finished problems leave the working set at the checks (the results are the same either way).

    Returns:
        :class:`SchurLMResult`, with the :class:`LMStatus` of every problem.

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
        ...         return NormalEquations(cost=(r * r).sum(-1), U=J.mT @ J, eg=(J.mT @ r[..., None])[..., 0])
        ...     def retract(self, s, dg, dp):
        ...         return {"ab": s["ab"] + dg}
        ...     def scale(self, s):
        ...         return s["ab"].abs().amax(-1).clamp_min(1.0)
        ...     def take(self, keep):
        ...         return Line(self.x[keep], self.y[keep])
        >>> x = torch.linspace(0.0, 1.0, 5, dtype=torch.float64)[None]
        >>> res = schur_lm(Line(x, 2 + 3 * x), {"ab": torch.zeros(1, 2, dtype=torch.float64)})
        >>> res.unknowns["ab"].round(decimals=6).tolist(), LMStatus(int(res.status)), res.covariance.shape
        ([[2.0, 3.0]], <LMStatus.CONVERGED: 1>, torch.Size([1, 2, 2]))
    """
    used = problem.used
    V = used.shape[-1] if isinstance(used, torch.Tensor) and used.dim() == 2 else 0
    eq = problem.linearize(unknowns)
    if not isinstance(eq, NormalEquations):
        raise TypeError(f"problem.linearize must return NormalEquations, got {type(eq).__name__}.")
    eq = _complete(eq, V)
    _check(problem, eq)
    B = used.shape[0]
    has_data = problem.num_residuals > 0
    cost = eq.cost
    dtype, device = cost.dtype, cost.device
    eyeG = torch.eye(eq.U.shape[-1], dtype=dtype, device=device)
    if check_every is None:
        check_every = 1 if device.type == "cpu" else 10
    status = torch.full((B,), LMStatus.RUNNING, dtype=torch.long, device=device).masked_fill(~has_data,
                                                                                             LMStatus.NO_DATA)
    full = LMState(unknowns=dict(unknowns), equations=eq, damping=torch.full((B,), lambda_init, dtype=dtype,
                   device=device), iterations=torch.zeros(B, dtype=torch.long, device=device), status=status,
                   stall_cost=cost.clone())
    # the working set: every problem still iterating; it shrinks (a gather) only at the "all done?" checks. The loop
    # replaces its entries, never writes into them, so it starts as a shallow copy of ``full``
    idx = torch.arange(B, device=device)
    work, wp, used_f = replace(full), problem, used.to(dtype)
    owned: set = set()  # entries of ``full`` copied before a write (the problem's or the caller's tensors otherwise)

    def write_back(rows, sel):
        def put(path, dst, src):
            if src is dst:  # (an entry never updated is still the full tensor itself)
                return dst
            if path not in owned:
                dst = dst.clone()
                owned.add(path)
            dst[rows] = src if sel is None else src[sel]
            return dst

        return _map(put, full, work)

    if groups is not None:  # a group per problem and number of used items; its best converged cost so far
        key = groups.to(device).long() * (V + 1) + used.sum(-1)
        best = torch.full((int(key.max()) + 1 if B else 0,), float("inf"), dtype=dtype, device=device)
    for it in range(max_iters):
        _iterate(wp, work, ftol, xtol, eyeG, used_f)
        if stall_tol > 0 and (it + 1) % STALL_WINDOW == 0:
            cost = work.equations.cost
            work.status = work.status.masked_fill(work.running & (work.stall_cost - cost <= stall_tol * cost),
                                                  LMStatus.STALLED)
            work.stall_cost = cost.clone()
        if (it + 1) % check_every == 0:
            if groups is not None:
                cost = work.equations.cost
                fit = ((work.status == LMStatus.CONVERGED) | (work.status == LMStatus.STALLED)) & cost.isfinite()
                best.scatter_reduce_(0, key[idx], torch.where(fit, cost, float("inf")), "amin")
                work.status = work.status.masked_fill(work.running & (cost > DOMINATED_RATIO * best[key[idx]]),
                                                      LMStatus.DOMINATED)
            alive = work.running
            if not bool(alive.any()):
                break
            if shrink and not bool(alive.all()):
                leaving = ~alive
                full = write_back(idx[leaving], leaving)
                idx = idx[alive]
                work = _map(lambda _, v, keep=alive: v[keep], work)
                wp, used_f = wp.take(alive), used_f[alive]
    full = work if idx.numel() == B else write_back(idx, None)  # (no problem left early: the working set is all)
    eq = full.equations
    status = full.status.masked_fill(full.running, LMStatus.MAX_ITERATIONS)

    # covariance at the solution (no damping)
    U, W, Vb, cost = eq.U, eq.W, eq.V, eq.cost
    if eq.Vband is not None:
        S = U - (W @ _banded_elimination(W, Vb, eq.Vband, eq.ep)[0]).sum(1)
    else:
        Vinv = spd_inverse(Vb)
        Vinv = torch.where(used[..., None, None] & Vinv.isfinite(), Vinv, torch.zeros_like(Vinv))
        S = U - _items_product(W @ Vinv, W)
    G = S.shape[-1]
    dof = (problem.num_residuals - G - Vb.shape[-1] * used.sum(-1)).clamp_min(1).to(dtype)
    sigma2 = torch.ones_like(cost) if absolute_weights else cost / dof
    cov = spd_inverse(S)
    # a (numerically) singular information matrix gives a huge, not a NaN, variance along the undetermined
    # directions, so the degeneracy checks can tell which parameters the data do not constrain
    singular = ~cov.flatten(1).isfinite().all(-1) & S.flatten(1).isfinite().all(-1) & has_data
    if G and bool(singular.any()):
        cov[singular] = pseudo_inverse(S[singular])
    cov = cov * sigma2[:, None, None]
    return SchurLMResult(unknowns=full.unknowns, equations=eq, cost=cost, covariance=cov, information=S,
                         sigma2=sigma2, iterations=full.iterations, status=status)
