r"""Joint Levenberg–Marquardt of a camera rig, batched over rigs: intrinsics, extrinsics and one board pose per frame.

Unknowns per rig: every camera's parameters (its own :class:`~ccs_kornia.geometry.models.CameraModel`,
so pinhole and fisheye cameras mix), the extrinsics ``(R_c, T_c)`` of cameras ``1..C-1`` (``x_c = R_c x_0 + T_c``;
camera 0 is the reference, ``R_0 = I``, ``T_0 = 0``) and one board pose ``(R_f, t_f)`` per frame, board to camera 0,
shared by all the cameras of that frame. A board corner ``X`` seen by camera ``c`` in frame ``f`` projects as
``model_c(R_c (R_f X + t_f) + T_c)``.

The normal equations have the arrow structure of :mod:`~ccs_kornia.modules.calibration.lm` with the global block
made of all the intrinsics and extrinsics of the rig (a few dozen unknowns) and the 6x6 frame-pose blocks; this
module builds them and the LM core (:func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm`) solves them, each step
eliminating the frame poses by the Schur complement, so the cost is linear in the number of frames. Rotations are
updated multiplicatively (``R <- exp(w) R``):

* ``d uv / d w_f = (R_f X) x (d uv / d q)`` with ``q = R_f X + t_f`` and ``d uv / d q = (d uv / d X_c) R_c``;
* ``d uv / d w_c = (R_c q) x (d uv / d X_c)``, ``d uv / d T_c = d uv / d X_c``.

A camera's intrinsics may carry a Gaussian prior (``prior``): the residual block ``L (p_c - p0_c)`` with
``L^T L = Lambda_c``, e.g. the information its own views give it alone, so the rig refines them where the shared frames
inform them but cannot drag them beyond what the camera's views allow. It adds ``Lambda_c`` to the camera's block of
``U`` and ``Lambda_c (p_c - p0_c)`` to ``e_g``; the frame poses are untouched.

The covariance of the free rig parameters (frame poses marginalised) is ``sigma^2 S^{-1}`` with ``S`` the Schur
complement at the solution and ``sigma^2 = cost / dof`` (1 with absolute weights), a pseudo-inverse where ``S`` is
numerically singular.

A bent board (``RigState.board_warp``: mrcal's two-parameter sag, :mod:`~ccs_kornia.geometry.board_warp`)
adds its two coefficients after the rig's parameters: ``d uv / d c_k = (d uv / d q) R_f e_z b_k``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.geometry.board_warp import board_warp_basis
from ccs_kornia.modules.calibration.schur_lm import NormalEquations, schur_lm
from ccs_kornia.modules.rig.rig_state import RigObservations, RigState
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["RigLMResult", "rig_layout", "rig_levenberg_marquardt"]


@dataclass
class RigLMResult:
    """Output of :func:`rig_levenberg_marquardt` (B rigs, C cameras, F frames, G rig parameters, Gf of them free)."""

    state: RigState  #: the rigs at the solution (frames no camera used: parked in front of camera 0)
    cost: torch.Tensor  #: (B,) weighted sum of squared residuals
    sq_error: torch.Tensor  #: (B, C, F) unweighted sum of squared pixel errors of the used corners
    count: torch.Tensor  #: (B, C, F) used corners
    covariance: torch.Tensor  #: (B, G, G) covariance of all rig parameters (zero rows/columns where fixed)
    sigma2: torch.Tensor  #: (B,)
    iterations: torch.Tensor  #: (B,) int64
    status: torch.Tensor  #: (B,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus` of each rig
    frame_used: torch.Tensor  #: (B, F) bool
    prior_cost: torch.Tensor | None = None  #: (B,) the priors' share of ``cost`` (``None`` without priors)
    warp_covariance: torch.Tensor | None = None  #: (B, 2, 2) of the board's sag where it was estimated


def rig_layout(models: Sequence[CameraModel]) -> tuple[list[slice], list[slice], int]:
    """Where each camera's parameters and extrinsics sit in the rig vector: ``[p_0, .., p_{C-1}, e_1, .., e_{C-1}]``
    with ``e_c = (w_c, T_c)`` (rotation increment, translation).

    Returns:
        ``(intrinsic slices, extrinsic slices (None for camera 0), G)``.

    Example:
        >>> from ccs_kornia.geometry.models import FISHEYE, K1K2, PINHOLE
        >>> intr, ext, G = rig_layout([K1K2, FISHEYE])
        >>> intr, ext, G
        ([slice(0, 6, None), slice(6, 14, None)], [None, slice(14, 20, None)], 20)
    """
    intr, ext, o = [], [], 0
    for m in models:
        intr.append(slice(o, o + m.num_params))
        o += m.num_params
    ext.append(None)
    for _ in models[1:]:
        ext.append(slice(o, o + 6))
        o += 6
    return intr, ext, o


def _cross_cols(q: torch.Tensor, d: Sequence[torch.Tensor]) -> list[torch.Tensor]:
    """Columns ``q x d`` of ``d uv / d w`` for a left rotation increment (``d``: the 3 columns ``d uv / d q``)."""
    qx, qy, qz = q[..., 0:1], q[..., 1:2], q[..., 2:3]
    dx, dy, dz = d
    return [qy * dz - qz * dy, qz * dx - qx * dz, qx * dy - qy * dx]


def _equations(models, params, R, T, Rf, tf, obj, obs, sw, on, layout, frame_used, eye6, jacobians=True, warp=None,
               sag=None):
    """Normal equations of all rigs: cost (B,), U (B,G,G), W (B,F,G,6), V (B,F,6,6), eg (B,G), ep (B,F,6), plus the
    unweighted squared error and count per camera and frame. With ``warp`` :math:`(B, 2)` and ``sag`` :math:`(N, 2)`
    the board is bent and its sag's two coefficients are the last two of ``G``."""
    B, C, F, N = obs.shape[:4]
    intr, ext, G = layout
    dtype, device = obs.dtype, obs.device
    if warp is not None:
        obj = torch.cat([obj.expand(B, N, 3)[..., :2], obj[..., 2:] + (sag * warp[:, None, :]).sum(-1, keepdim=True)],
                        -1)[:, None]
    q_rot = torch.matmul(obj.expand(B, F, N, 3), Rf.transpose(-1, -2))  # (B, F, N, 3) R_f X
    q = q_rot + tf[:, :, None, :]
    U = torch.zeros(B, G, G, dtype=dtype, device=device)
    W = torch.zeros(B, F, G, 6, dtype=dtype, device=device)
    V = torch.zeros(B, F, 6, 6, dtype=dtype, device=device)
    eg = torch.zeros(B, G, dtype=dtype, device=device)
    ep = torch.zeros(B, F, 6, dtype=dtype, device=device)
    cost = torch.zeros(B, dtype=dtype, device=device)
    sq = torch.zeros(B, C, F, dtype=dtype, device=device)
    for c, model in enumerate(models):
        Rc = R[:, c].reshape(B, 1, 1, 3, 3)
        rq = (Rc @ q.unsqueeze(-1)).squeeze(-1)  # (B, F, N, 3)
        Xc = rq + T[:, c].reshape(B, 1, 1, 3)
        uv, dp, dX = model.columns(Xc, params[c], jacobians)
        res = torch.where(on[:, c, ..., None], uv - obs[:, c], 0.0)
        sq[:, c] = (res * res).sum((-1, -2))
        if not jacobians:
            cost = cost + (sw[:, c, ..., None] ** 2 * res * res).sum((1, 2, 3))
            continue
        shape = uv.shape
        # d uv / d q = (d uv / d X_c) R_c: column j is sum_k dX_k R_c[k, j]
        r = R[:, c].reshape(B, 1, 1, 3, 3)
        dq = [sum(dX[k].expand(shape) * r[..., k, j : j + 1] for k in range(3)) for j in range(3)]
        cols = [*(d.expand(shape) for d in dp)]
        gi = list(range(intr[c].start, intr[c].stop))
        if ext[c] is not None:
            cols += [*_cross_cols(rq, [d.expand(shape) for d in dX]), *(d.expand(shape) for d in dX)]
            gi += list(range(ext[c].start, ext[c].stop))
        if warp is not None:  # d q / d c_k = R_f e_z b_k
            ez = Rf[..., :, 2][:, :, None, :, None]  # (B, F, 1, 3, 1)
            along = dq[0] * ez[..., 0, :] + dq[1] * ez[..., 1, :] + dq[2] * ez[..., 2, :]
            cols += [along * sag[:, 0:1], along * sag[:, 1:2]]
            gi += [G - 2, G - 1]
        cols += [*_cross_cols(q_rot, dq), *dq, res]
        A = torch.stack([col.expand(shape) for col in cols], 3)  # (B, F, N, K, 2)
        A = torch.where(on[:, c, :, :, None, None], A * sw[:, c, :, :, None, None], 0.0)
        A = A.permute(0, 1, 3, 2, 4).reshape(B, F, len(cols), N * 2)
        Gm = A @ A.transpose(-1, -2)  # (B, F, K, K)
        k = len(gi)
        gi_t = torch.tensor(gi, device=device)
        U[:, gi_t[:, None], gi_t[None, :]] += Gm[:, :, :k, :k].sum(1)
        W[:, :, gi_t, :] += Gm[:, :, :k, k : k + 6]
        V += Gm[:, :, k : k + 6, k : k + 6]
        eg[:, gi_t] += Gm[:, :, :k, k + 6].sum(1)
        ep += Gm[:, :, k : k + 6, k + 6]
        cost = cost + Gm[:, :, k + 6, k + 6].sum(1)
    cost = torch.where(cost.isfinite(), cost, torch.full_like(cost, float("inf")))
    if not jacobians:
        return cost, sq
    V = torch.where(frame_used[..., None, None], V, eye6)
    return cost, U, W, V, eg, ep, sq


def _prior_terms(prior, params, intr, B, G, dtype, device):
    """The priors' cost (B,), their share of U (B, G, G) and of eg (B, G) at ``params``."""
    cost = torch.zeros(B, dtype=dtype, device=device)
    U = torch.zeros(B, G, G, dtype=dtype, device=device)
    eg = torch.zeros(B, G, dtype=dtype, device=device)
    for c, item in enumerate(prior):
        if item is None:
            continue
        p0, info = item
        d = params[c] - p0
        g = (info @ d.unsqueeze(-1)).squeeze(-1)
        cost = cost + (d * g).sum(-1)
        U[:, intr[c], intr[c]] += info
        eg[:, intr[c]] += g
    return cost, U, eg


@dataclass(kw_only=True)
class _RigEquations(NormalEquations):
    """The rigs' normal equations with the unweighted squared error per camera and frame."""

    sq: torch.Tensor  #: (B, C, F)
    prior_cost: torch.Tensor | None = None  #: (B,) the priors' share of ``cost`` (``None`` without priors)


class _RigProblem:
    """The rigs of :func:`rig_levenberg_marquardt` as a :class:`~ccs_kornia.modules.calibration.schur_lm.SchurProblem`:
    global unknowns the free rig parameters (:func:`rig_layout` order), items the frames' board poses; the unknowns
    ``{"p0", .., "p{C-1}": (B, P_c) parameters, "R": (B, C, 3, 3), "T": (B, C, 3), "Rf": (B, F, 3, 3), "tf": (B, F,
    3)}``, the normal equations :class:`_RigEquations`."""

    def __init__(self, models, layout, fi, obj, obs, sw, on, used, num_residuals, floor, eye6, prior=None, sag=None):
        self.models, self.layout, self.fi, self.obj, self.obs, self.sw, self.on = models, layout, fi, obj, obs, sw, on
        self.used, self.num_residuals, self.floor, self.eye6 = used, num_residuals, floor, eye6
        self.prior = prior  #: per camera ``(p0 (B, P_c), information (B, P_c, P_c))`` or None
        self.sag = sag  #: (N, 2) the board's sag shapes where its sag is estimated (the unknowns' ``"w"``), or None

    def params(self, s):
        return [s[f"p{c}"] for c in range(len(self.models))]

    def linearize(self, s):
        fi = self.fi
        params = self.params(s)
        cost, U, W, V, eg, ep, sq = _equations(self.models, params, s["R"], s["T"], s["Rf"], s["tf"], self.obj,
                                               self.obs, self.sw, self.on, self.layout, self.used, self.eye6,
                                               warp=s.get("w"), sag=self.sag)
        pc = None
        if self.prior is not None:
            pc, pU, pe = _prior_terms(self.prior, params, self.layout[0], *U.shape[:2], U.dtype, U.device)
            cost, U, eg = torch.where(cost.isfinite(), cost + pc, cost), U + pU, eg + pe
        return _RigEquations(cost=cost, U=U[:, fi][:, :, fi], eg=eg[:, fi], W=W[:, :, fi], V=V, ep=ep, sq=sq,
                             prior_cost=pc)

    def retract(self, s, dg, dp):
        intr, ext, G = self.layout
        full = dg.new_zeros(dg.shape[0], G)
        full[:, self.fi] = dg
        out = {f"p{c}": s[f"p{c}"] + full[:, intr[c]] for c in range(len(self.models))}
        R, T = s["R"].clone(), s["T"].clone()
        for c in range(1, len(self.models)):
            e = full[:, ext[c]]
            R[:, c] = exp_so3(e[:, :3]) @ s["R"][:, c]
            T[:, c] = s["T"][:, c] + e[:, 3:]
        if "w" in s:
            out["w"] = s["w"] + full[:, G - 2:]
        return {**out, "R": R, "T": T, "Rf": exp_so3(dp[..., :3]) @ s["Rf"], "tf": s["tf"] + dp[..., 3:]}

    def scale(self, s):
        x = torch.cat(self.params(s), -1)
        return torch.cat([x.abs(), s["tf"].abs().flatten(1), torch.ones_like(x[:, :1])], -1).amax(-1)

    def take(self, keep):
        prior = None if self.prior is None else [None if p is None else (p[0][keep], p[1][keep]) for p in self.prior]
        return _RigProblem(self.models, self.layout, self.fi, self.obj, self.obs[keep], self.sw[keep], self.on[keep],
                           self.used[keep], self.num_residuals[keep], self.floor[keep], self.eye6, prior, self.sag)


def rig_levenberg_marquardt(
    start: RigState,
    observations: RigObservations,
    free: torch.Tensor | None = None,
    max_iters: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    lambda_init: float = 1e-3,
    absolute_weights: bool = False,
    check_every: int | None = None,
    stall_tol: float = 0.0,
    prior: Sequence[tuple[torch.Tensor, torch.Tensor] | None] | None = None,
) -> RigLMResult:
    r"""Refine B rigs jointly (see the module doc); no Python loop over rigs or frames, one over cameras.

    Args:
        start: the rigs to start from (:class:`~ccs_kornia.modules.rig.rig_state.RigState`; ``R[:, 0]`` is kept at
            its value, normally ``I``); with ``board_warp``, the board's sag is estimated too (always free).
        observations: the board points, the corners :math:`(B, C, F, N, 2)` and their weights :math:`(B, C, F, N)`
            (:class:`~ccs_kornia.modules.rig.rig_state.RigObservations`).
        free: :math:`(G,)` bool, which rig parameters move (:func:`rig_layout` order; default all).
        max_iters, ftol, xtol, lambda_init, check_every, stall_tol: as
            :func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm`.
        absolute_weights: the weights are absolute inverse variances (covariance without ``sigma^2``).
        prior: per camera ``None`` or ``(p0, information)``: :math:`(B, P_c)` and :math:`(B, P_c, P_c)` (symmetric,
            positive semi-definite, in the units of the weighted squared pixel residuals): the Gaussian prior
            ``(p_c - p0)^T information (p_c - p0)`` added to the cost (see the module doc; each prior counts
            ``P_c`` residuals in the degrees of freedom). A fixed camera's prior has no effect.

    Returns:
        :class:`RigLMResult`.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> from ccs_kornia.geometry.models import FISHEYE, K1K2, PINHOLE
        >>> from ccs_kornia.modules.calibration.schur_lm import LMStatus
        >>> obj = board_object_points(5, 4, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rv = torch.tensor([[0.2, 0.1, 0.0], [-0.2, 0.3, 0.1], [0.1, -0.3, 0.2]], dtype=torch.float64)
        >>> tv = torch.tensor([-0.2, -0.15, 1.0], dtype=torch.float64).expand(3, 3)
        >>> x0 = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rv, tv)
        >>> x1 = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rv, tv + torch.tensor([-0.1, 0, 0.]))
        >>> corners = torch.stack([x0, x1])[None]
        >>> R = torch.eye(3, dtype=torch.float64).expand(1, 2, 3, 3)
        >>> T = torch.tensor([[[0.0, 0, 0], [-0.09, 0.01, 0]]], dtype=torch.float64)
        >>> p = [torch.tensor([[505., 495., 322., 238.]], dtype=torch.float64)] * 2
        >>> m = [PINHOLE] * 2
        >>> start = RigState(m, p, R, T, exp_so3(rv)[None], tv[None])
        >>> res = rig_levenberg_marquardt(start, RigObservations(obj, corners, torch.ones(1, 2, 3, 20)))
        >>> res.state.T[0, 1].round(decimals=6).tolist(), LMStatus(int(res.status))
        ([-0.1, 0.0, 0.0], <LMStatus.CONVERGED: 1>)
    """
    models, params = list(start.models), start.params
    object_points, corners, weights = observations.object_points, observations.corners, observations.weights
    B, C = corners.shape[:2]
    if len(models) != C or len(params) != C:
        raise ValueError(f"models and params need one entry per camera ({C}), got {len(models)} and {len(params)}.")
    dtype, device = corners.dtype if corners.is_floating_point() else torch.float64, corners.device
    layout = rig_layout(models)
    G = layout[2]
    free = torch.ones(G, dtype=torch.bool) if free is None else free.bool().cpu()
    check_tensor(free, "free", [G])
    bent = start.board_warp is not None
    if bent:  # the sag's two coefficients after the rig's parameters
        check_tensor(start.board_warp, "start.board_warp", [B, 2])
        layout = (layout[0], layout[1], G + 2)
        free = torch.cat([free, torch.ones(2, dtype=torch.bool)])
    fi = torch.nonzero(free).flatten().to(device)
    w = torch.where(corners.isfinite().all(-1), weights.to(dtype), 0.0).clamp_min(0)
    on = w > 0
    sw = w.sqrt()
    obs = torch.where(on[..., None], corners.to(dtype), 0.0)
    obj = object_points.to(device=device, dtype=dtype)
    frame_used = on.any(-1).any(1)  # (B, F)
    park = torch.tensor([0.0, 0.0, 1.0 + 10.0 * float(obj.abs().amax())], dtype=dtype, device=device)
    Rf = torch.where(frame_used[..., None, None], start.frame_R.to(dtype), torch.eye(3, dtype=dtype, device=device))
    tf = torch.where(frame_used[..., None], start.frame_t.to(dtype), park)
    x = [p.to(device=device, dtype=dtype).clone() for p in params]
    eye6 = torch.eye(6, dtype=dtype, device=device)
    count = on.sum(-1)
    floor = (w.sum((1, 2, 3)) * 1e-20).clamp_min(1e-300)  # an RMS of 1e-10 px: a perfect fit
    priors = None
    num_residuals = 2 * count.sum((1, 2))
    if prior is not None:
        if len(prior) != C:
            raise ValueError(f"prior needs one entry (or None) per camera ({C}), got {len(prior)}.")
        priors = []
        for c, item in enumerate(prior):
            P = models[c].num_params
            if item is None or not bool(free[layout[0][c]].any()):
                priors.append(None)
                continue
            p0, info = item
            check_tensor(p0, f"prior of camera {c} (p0)", [B, P])
            check_tensor(info, f"prior of camera {c} (information)", [B, P, P])
            info = info.to(device=device, dtype=dtype)
            priors.append((p0.to(device=device, dtype=dtype), 0.5 * (info + info.transpose(-1, -2))))
            num_residuals = num_residuals + P
        priors = priors if any(p is not None for p in priors) else None
    sag = board_warp_basis(obj) if bent else None
    problem = _RigProblem(models, layout, fi, obj, obs, sw, on, frame_used, num_residuals, floor, eye6, priors, sag)
    state = {**{f"p{c}": x[c] for c in range(C)}, "R": start.R.to(dtype).clone(), "T": start.T.to(dtype).clone(),
             "Rf": Rf, "tf": tf}
    if bent:
        state["w"] = start.board_warp.to(device=device, dtype=dtype)
    sol = schur_lm(problem, state, max_iters=max_iters, ftol=ftol, xtol=xtol, lambda_init=lambda_init,
                   check_every=check_every, stall_tol=stall_tol, absolute_weights=absolute_weights)
    u = sol.unknowns
    x, Rx, Tx, Rf, tf = problem.params(u), u["R"], u["T"], u["Rf"], u["tf"]

    # the unweighted squared errors at the solution
    warp = u.get("w")
    _, sq = _equations(models, x, Rx, Tx, Rf, tf, obj, obs, sw, on, layout, frame_used, eye6, jacobians=False,
                       warp=warp, sag=sag)
    cov = torch.zeros(B, layout[2], layout[2], dtype=dtype, device=device)
    cov[:, fi[:, None], fi[None, :]] = sol.covariance
    return RigLMResult(
        state=RigState(models, x, Rx, Tx, Rf, tf, warp), cost=sol.cost, sq_error=sq, count=count,
        covariance=cov[:, :G, :G], sigma2=sol.sigma2, iterations=sol.iterations, status=sol.status,
        frame_used=frame_used, prior_cost=sol.equations.prior_cost,
        warp_covariance=cov[:, G:, G:] if bent else None,
    )
