"""Levenberg–Marquardt of cameras: camera parameters and all board poses, batched over cameras.

Unknowns per camera: the free camera parameters (a :class:`~ccs_kornia.geometry.models.CameraModel`'s
intrinsics and distortion, possibly fixed or tied through a basis) and one 6-dof pose per view. The normal
equations have the bundle-adjustment arrow structure (a small dense camera block, independent 6x6 pose
blocks): this module builds them, the LM core (:func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm`: damping,
stopping rules, batching, covariance) solves them, eliminating the pose blocks with a Schur complement, so the cost
is linear in the number of views and all cameras are solved by the same tensor ops.

* Rotations are updated multiplicatively, ``R <- exp(w) R``, so the pose derivatives are
  ``d uv / d w = (d uv / d Xc) (-[R X]_x)`` and ``d uv / d t = d uv / d Xc``, built from the model's
  derivative with respect to the camera-frame point.
* Per-corner weights :math:`(C, V, N)` are inverse variances (0: corner unused); the cost is
  ``sum w |uv - observed|^2``.
* The covariance of the free camera parameters is marginalised over the poses and scaled by
  ``sigma^2 = cost / dof`` (or 1 when the weights are absolute inverse variances).
* ``board_warp``: the board's sag (:mod:`~ccs_kornia.geometry.board_warp`, mrcal's two parameters) joins
  the global unknowns after the camera's: ``d uv / d c_k = (d uv / d Xc) R e_z b_k``, ``b_k`` the sag's shape at the
  point. The camera's covariance is then marginalised over the sag too.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.so3 import exp_so3 as _exp_so3
from ccs_kornia.geometry.so3 import log_so3 as _log_so3
from ccs_kornia.geometry.board_warp import board_warp_basis
from ccs_kornia.modules.calibration.schur_lm import NormalEquations, schur_lm
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["LMResult", "parameter_basis", "levenberg_marquardt", "LevenbergMarquardt"]


@dataclass
class LMResult:
    """Output of :func:`levenberg_marquardt` (C cameras, V views, P parameters, F free coordinates)."""

    params: torch.Tensor  #: (C, P) camera parameters
    rvec: torch.Tensor  #: (C, V, 3) axis-angle, world-to-camera (initial value kept for unused views)
    tvec: torch.Tensor  #: (C, V, 3)
    cost: torch.Tensor  #: (C,) weighted sum of squared residuals
    view_rms: torch.Tensor  #: (C, V) RMS reprojection error in px over the used corners, NaN for unused views
    rms: torch.Tensor  #: (C,) sqrt(sum squared error / number of corners) over the used corners (px)
    covariance: torch.Tensor  #: (C, F, F) covariance of the free coordinates, marginalised over the poses
    information: torch.Tensor  #: (C, F, F) J^T W J of the free coordinates, poses eliminated (Schur complement)
    basis: torch.Tensor  #: (C, P, F) parameter increment = basis @ free increment
    sigma2: torch.Tensor  #: (C,) variance factor applied to the covariance
    iterations: torch.Tensor  #: (C,) int64 iterations run while the camera was active
    status: torch.Tensor  #: (C,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus` of each camera
    num_points: torch.Tensor  #: (C,) int64 corners with positive weight
    view_used: torch.Tensor  #: (C, V) bool, views with at least one weighted corner
    #: (C, 2) the board's sag (mrcal's ``calobject_warp``, board units) where ``board_warp`` was estimated, else None
    warp: torch.Tensor | None = None
    #: (C, 2, 2) its covariance (marginalised over the camera and the poses), or None
    warp_covariance: torch.Tensor | None = None

    @property
    def param_covariance(self) -> torch.Tensor:
        """(C, P, P) covariance of all parameters (zero rows/columns for fixed ones)."""
        return self.basis @ self.covariance @ self.basis.transpose(-1, -2)

    @property
    def param_std(self) -> torch.Tensor:
        """(C, P) standard deviations of the parameters (0 where fixed)."""
        return self.param_covariance.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()


def parameter_basis(
    model: CameraModel,
    params: torch.Tensor,
    free: Sequence[bool] | Sequence[str] | None = None,
    fix_aspect_ratio: bool = False,
) -> torch.Tensor:
    """Basis :math:`(C, P, F)` mapping free increments to parameter increments.

    Args:
        model: the camera model (gives ``P`` and the parameter names).
        params: :math:`(C, P)` current parameters (the aspect ratio is taken from them).
        free: which parameters move: ``P`` booleans or a list of parameter names (default
            ``model.default_free()``).
        fix_aspect_ratio: tie ``fx`` and ``fy`` so that ``fx / fy`` keeps its current value (both must be free);
            the tied coordinate moves ``fy`` by 1 and ``fx`` by the aspect ratio.

    Returns:
        The basis; the tied focal coordinate comes first, then the other free parameters in order.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> m = K1K2
        >>> p = torch.tensor([[600., 500., 320., 240., 0., 0.]])
        >>> B = parameter_basis(m, p, free=["fx", "fy", "k1", "k2"], fix_aspect_ratio=True)
        >>> B.shape, B[0, :2, 0].tolist()
        (torch.Size([1, 6, 3]), [1.2000000476837158, 1.0])
    """
    P = model.num_params
    check_tensor(params, "params", ["C", P])
    if free is None:
        mask = list(model.default_free())
    elif len(free) and all(isinstance(f, str) for f in free):
        unknown = set(free) - set(model.param_names)
        if unknown:
            raise ValueError(f"Unknown parameter names {sorted(unknown)}; the model has {model.param_names}.")
        mask = [n in free for n in model.param_names]
    else:
        mask = [bool(f) for f in free]
    if len(mask) != P:
        raise ValueError(f"free must name or flag the {P} parameters {model.param_names}, got {len(mask)} entries.")
    C = params.shape[0]
    eye = torch.eye(P, dtype=params.dtype, device=params.device)
    if all(mask) and not fix_aspect_ratio:
        return eye.expand(C, P, P)
    cols = []
    if fix_aspect_ratio:
        if not (mask[0] and mask[1]):
            raise ValueError("fix_aspect_ratio needs both fx and fy free.")
        col = torch.zeros(C, P, dtype=params.dtype, device=params.device)
        col[:, 0], col[:, 1] = params[:, 0] / params[:, 1], 1.0
        cols.append(col)
    for i in range(P):
        if mask[i] and not (fix_aspect_ratio and i < 2):
            cols.append(eye[i].expand(C, P))
    if not cols:
        return params.new_zeros(C, P, 0)
    return torch.stack(cols, -1)


def _check(model, params, rvec, tvec, object_points, corners, weights):
    if not isinstance(model, CameraModel):
        raise TypeError(f"model must be a CameraModel, got {type(model).__name__}.")
    check_tensor(corners, "corners", ["C", "V", "N", "2"])
    C, V, N = corners.shape[:3]
    check_tensor(params, "params", [C, model.num_params])
    check_tensor(rvec, "rvec", [C, V, 3])
    check_tensor(tvec, "tvec", [C, V, 3])
    check_tensor(object_points, "object_points", [N, 3], [C, N, 3])
    if weights is not None:
        check_tensor(weights, "weights", [C, V, N])


def _normal_equations(model, R, t, params, obj, obs, sw, basis, used, eye6, expanded, sag=None):
    """Per-camera normal equations at (R, t, params): cost, U (C,F,F), W (C,V,F,6), V (C,V,6,6), eg, ep. With
    ``sag`` :math:`(C, N, 2)` (the board's sag shapes) the last two entries of ``params`` are the sag's coefficients
    and ``obj`` is bent by them."""
    C, V = R.shape[:2]
    if sag is not None:
        params, warp = params[:, :-2], params[:, -2:]
        obj = torch.cat([obj[..., :2], obj[..., 2:] + (sag * warp[:, None, :]).sum(-1, keepdim=True)], -1)
    q = torch.matmul(obj[:, None].expand(C, V, -1, 3), R.transpose(-1, -2))  # (C, V, N, 3) = R X
    local = None
    if model.local_support:  # most parameters in local form: (index, columns) per point, assembled below
        uv, dp, index, d_local, (dx, dy, dz) = model.local_columns(q + t[:, :, None, :], params)
        local = (index, d_local)
    else:
        uv, dp, (dx, dy, dz) = model.columns(q + t[:, :, None, :], params)
    qx, qy, qz = q[..., 0:1], q[..., 1:2], q[..., 2:3]
    if sag is not None:  # d Xc / d c_k = R e_z b_k
        ez = R[..., :, 2][:, :, None, :, None]  # (C, V, 1, 3, 1)
        along = dx * ez[..., 0, :] + dy * ez[..., 1, :] + dz * ez[..., 2, :]  # (C, V, N, 2)
        dp = [*dp, along * sag[:, None, :, 0:1], along * sag[:, None, :, 1:2]]
    # rotation R <- exp(w) R: d Xc / d w = -[q]_x, so d uv / d w = q x (d uv / d Xc), both rows at once
    cols = [*dp, qy * dz - qz * dy, qz * dx - qx * dz, qx * dy - qy * dx, dx, dy, dz, uv - obs]
    shape = uv.shape
    for i, col in enumerate(cols):  # constant columns (e.g. d uv / d cx) are expanded once per solve
        if col.shape != shape:
            key = (id(col), shape)
            if key not in expanded:
                expanded[key] = (col, col.expand(shape).contiguous())  # (col kept alive: its id stays unique)
            cols[i] = expanded[key][1]
    A = torch.stack(cols, 2)  # (C, V, K, N, 2), K = P + 7: contiguous columns
    if sw is not None:
        A = A * sw[:, :, None, :, None]
    A = A.view(C, V, len(cols), -1)
    G = A @ A.transpose(-1, -2)  # (C, V, K, K): J^T J, J^T r and r^T r per view
    P = len(dp)  # the camera's parameters (and the sag's two)
    Gpp, Gpk, Gkk = G[..., :P, :P].sum(1), G[..., :P, P : P + 6], G[..., P : P + 6, P : P + 6]
    gp, gk = G[..., :P, P + 6].sum(1), G[..., P : P + 6, P + 6]
    if local is not None:
        Gpp, Gpk, gp = _with_local(model, local, A.view(C, V, len(cols), -1, 2), sw, Gpp, Gpk, gp)
    view_cost = G[..., P + 6, P + 6]  # (C, V) weighted squared residuals per view
    cost = view_cost.sum(1)
    cost = torch.where(cost.isfinite(), cost, torch.full_like(cost, float("inf")))
    pick = None
    if basis is not None and local is not None:  # (the basis is the solve's: its selection is read once per solve)
        key = ("selection", id(basis))
        if key not in expanded:
            expanded[key] = (basis, _selection(basis))
        pick = expanded[key][1]
    if pick is not None:  # a basis that selects parameters (a spline's, the core fixed): indexing, not products
        Gpp = torch.gather(torch.gather(Gpp, 1, pick[:, :, None].expand(-1, -1, Gpp.shape[-1])), 2,
                           pick[:, None, :].expand(-1, pick.shape[1], -1))
        gp = torch.gather(gp, 1, pick)
        Gpk = torch.gather(Gpk, 2, pick[:, None, :, None].expand(-1, Gpk.shape[1], -1, 6))
    elif basis is not None:
        Bt = basis.transpose(-1, -2)
        Gpp, gp = Bt @ Gpp @ basis, (Bt @ gp.unsqueeze(-1)).squeeze(-1)
        Gpk = torch.einsum("cpf,cvpk->cvfk", basis, Gpk)
    Gkk = torch.where(used[..., None, None], Gkk, eye6)
    return cost, Gpp, Gpk, Gkk, gp, gk, view_cost


def _selection(basis: torch.Tensor) -> torch.Tensor | None:
    """The parameters :math:`(C, F)` a basis :math:`(C, P, F)` selects where each of its columns is a unit vector,
    else ``None``."""
    pick = basis.argmax(-2)
    unit = (basis.gather(1, pick[:, None, :]) == 1).all() & (basis.sum(-2) == 1).all() & (basis >= 0).all()
    return pick if bool(unit) else None


def _with_local(model, local, A, sw, Gpp, Gpk, gp):
    """The normal equations of a model with parameters in local form (each point depends on ``S`` pairs of them, one
    moving ``u`` and the next moving ``v``: a spline's control points): ``Gpp``, ``Gpk``, ``gp`` of the dense columns
    ``A`` :math:`(C, V, K, N, 2)` (the core, the sag, the pose, the residual) grown to every parameter, the local ones'
    blocks summed in by their places.

    Every point's pairs are its first pair's place plus one pattern of offsets (a patch of the spline's grid): the
    points' ``S x S`` products and their products with the dense columns are summed per first place (whole rows at a
    time), then placed once; the poses' are summed per view and first place the same way."""
    index, d_local = local  # (C, V, N, S) the pairs' first parameters, (C, V, N, S, 2) d u / d first, d v / d second
    C, V = A.shape[:2]
    D = Gpp.shape[-1]  # the dense columns: the model's core (its first ones), then the sag's
    core = model.num_params - model.num_local
    Pt = model.num_params + (D - core)
    if sw is not None:
        d_local = d_local * sw[..., None, None]
    S = d_local.shape[-2]
    device = index.device
    first = index[..., 0]  # (C, V, N)
    pattern = index.reshape(-1, S)[0] - index.reshape(-1, S)[0, 0] if index.numel() else index.new_zeros(S)
    if not bool((index - first[..., None] == pattern).all()):
        raise ValueError("a model's local parameters must be, for every point, its first one's place plus one pattern "
                         "of offsets (local_columns).")
    # (C, V, N, 2, K): the dense columns by coordinate
    dense = A.permute(0, 1, 3, 4, 2)
    # the places in the camera's unknowns a first place's pattern reaches (the grid's last places reach past the end:
    # nothing is summed there, the rows are cut off)
    places = torch.arange(Pt, device=device)
    reach = places[:, None] + pattern[None, :]  # (Pt, S)
    inside = places + pattern.amax() < Pt
    reach = reach[inside]
    cams = torch.arange(C, device=device).view(C, 1, 1)
    pair = Gpp.new_zeros(C, Pt, S, S)
    cross = Gpp.new_zeros(C, Pt, S, D + 1)  # against the dense core and sag, and the residual
    # the poses': per view and first place, over the (view, place) pairs that occur only
    key, at_key = torch.unique((torch.arange(C * V, device=device).view(C, V, 1) * Pt + first).reshape(-1),
                               return_inverse=True)
    pose = Gpk.new_zeros(2, key.numel(), S * 6)
    for axis in range(2):  # u's parameters, then v's: each moves one coordinate only
        a = d_local[..., axis]  # (C, V, N, S)
        d = dense[..., axis, :]  # (C, V, N, K)
        rows = (cams * Pt + first + axis).reshape(-1)
        # (index_add_ of 2-D rows: one pass over the points; 3-D ones are added slice by slice)
        pair.view(C * Pt, S * S).index_add_(0, rows, (a[..., :, None] * a[..., None, :]).reshape(-1, S * S))
        both = torch.cat([d[..., :D], d[..., D + 6 :]], -1)  # (C, V, N, D + 1)
        cross.view(C * Pt, S * (D + 1)).index_add_(0, rows,
                                                   (a[..., :, None] * both[..., None, :]).reshape(-1, S * (D + 1)))
        pose[axis].index_add_(0, at_key, (a[..., :, None] * d[..., None, D : D + 6]).reshape(-1, S * 6))
    pair, cross = pair[:, inside], cross[:, inside]  # (C, R, S, S), (C, R, S, D + 1)
    full = Gpp.new_zeros(C * Pt * Pt)
    full.index_add_(0, ((cams * Pt + reach)[..., None] * Pt + reach[:, None, :]).reshape(-1), pair.reshape(-1))
    full = full.view(C, Pt, Pt)
    lc = Gpp.new_zeros(C * Pt, D + 1)
    lc.index_add_(0, (cams * Pt + reach).reshape(-1), cross.reshape(-1, D + 1))
    lc = lc.view(C, Pt, D + 1)
    g = lc[..., D].clone()
    lc = lc[..., :D]
    Gk = Gpk.new_zeros(C * V * Pt, 6)
    rows = (key[:, None] + torch.arange(2, device=device)[:, None, None] + pattern).reshape(-1)  # (axis, pair, S)
    Gk.index_add_(0, rows, pose.reshape(-1, 6))
    Gk = Gk.view(C, V, Pt, 6)
    at = torch.cat([torch.arange(core), torch.arange(model.num_params, Pt)]).to(device)  # the dense ones' places
    full[:, at[:, None], at[None, :]] += Gpp
    full[:, :, at] += lc  # the local rows only: the dense ones of lc stay zero
    full[:, at, :] += lc.transpose(-1, -2)
    Gk[:, :, at] += Gpk
    g[:, at] += gp
    return full, Gk, g


@dataclass(kw_only=True)
class _CameraEquations(NormalEquations):
    """The cameras' normal equations with the weighted squared residuals per view."""

    view_cost: torch.Tensor  #: (C, V)


class _CameraProblem:
    """The cameras of :func:`levenberg_marquardt` as a :class:`~ccs_kornia.modules.calibration.schur_lm.SchurProblem`:
    global unknowns the free camera coordinates, items the views' poses; the unknowns ``{"x": (C, P) parameters,
    "R": (C, V, 3, 3), "t": (C, V, 3)}``, the normal equations :class:`_CameraEquations`."""

    def __init__(self, model, obj, obs, sw, basis, tied, used, num_residuals, floor, eye6, expanded, sag=None,
                 prior=None):
        self.model, self.obj, self.obs, self.sw, self.basis, self.tied = model, obj, obs, sw, basis, tied
        self.used, self.num_residuals, self.floor = used, num_residuals, floor
        self.eye6, self.expanded, self.sag, self.prior = eye6, expanded, sag, prior
        # the prior's block of the free coordinates (constant: the basis is)
        self.prior_free = None if prior is None else basis.transpose(-1, -2) @ prior @ basis

    def linearize(self, s):
        cost, U, W, V, eg, ep, view_cost = _normal_equations(self.model, s["R"], s["t"], s["x"], self.obj, self.obs,
                                                             self.sw, self.tied, self.used, self.eye6, self.expanded,
                                                             self.sag)
        if self.prior is not None:  # cost x^T Lambda x: the regularisation's residuals
            lx = (self.prior @ s["x"].unsqueeze(-1)).squeeze(-1)
            cost = cost + (s["x"] * lx).sum(-1)
            U = U + self.prior_free
            eg = eg + (self.basis.transpose(-1, -2) @ lx.unsqueeze(-1)).squeeze(-1)
        return _CameraEquations(cost=cost, U=U, eg=eg, W=W, V=V, ep=ep, view_cost=view_cost)

    def retract(self, s, dg, dp):
        x = s["x"] + (dg if self.tied is None else (self.basis @ dg.unsqueeze(-1)).squeeze(-1))
        return {"x": x, "R": _exp_so3(dp[..., :3]) @ s["R"], "t": s["t"] + dp[..., 3:]}

    def scale(self, s):
        x = s["x"]
        return torch.cat([x.abs(), s["t"].abs().flatten(1), torch.ones_like(x[:, :1])], -1).amax(-1)

    def take(self, keep):
        sub = [None if v is None else v[keep] for v in (self.obj, self.obs, self.sw, self.basis, self.tied, self.used,
                                                         self.num_residuals, self.floor)]
        return _CameraProblem(self.model, *sub, self.eye6, self.expanded,
                              None if self.sag is None else self.sag[keep],
                              None if self.prior is None else self.prior[keep])


def levenberg_marquardt(
    model: CameraModel,
    params: torch.Tensor,
    rvec: torch.Tensor,
    tvec: torch.Tensor,
    object_points: torch.Tensor,
    corners: torch.Tensor,
    weights: torch.Tensor | None = None,
    free: Sequence[bool] | Sequence[str] | None = None,
    fix_aspect_ratio: bool = False,
    basis: torch.Tensor | None = None,
    max_iters: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    lambda_init: float = 1e-3,
    check_every: int | None = None,
    absolute_weights: bool = False,
    dtype: torch.dtype = torch.float64,
    stall_tol: float = 0.0,
    groups: torch.Tensor | None = None,
    board_warp: torch.Tensor | None = None,
    prior: torch.Tensor | None = None,
) -> LMResult:
    r"""Batched Levenberg–Marquardt over camera parameters and per-view poses (see the module doc).

    Args:
        model: camera model (``project`` with analytic derivatives).
        params: :math:`(C, P)` initial parameters.
        rvec: :math:`(C, V, 3)` initial axis-angle rotations (world to camera).
        tvec: :math:`(C, V, 3)` initial translations.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` board points.
        corners: :math:`(C, V, N, 2)` observed pixels (entries with weight 0 may be NaN).
        weights: :math:`(C, V, N)` per-corner inverse variances (bool accepted; 0 = unused). Default: finite
            corners with weight 1.
        free: parameters to estimate (``P`` booleans or names; default ``model.default_free()``).
        fix_aspect_ratio: keep ``fx / fy`` at its initial value.
        basis: :math:`(C, P, F)` explicit basis of the free increments (overrides ``free``/``fix_aspect_ratio``),
            for any tie between parameters.
        max_iters: iterations at most (a camera still iterating then ends ``MAX_ITERATIONS``).
        ftol: a camera converges when an accepted step decreases its cost by less than ``ftol`` relative.
        xtol: a camera converges when its step is below ``xtol`` times its largest parameter magnitude.
        lambda_init: initial Marquardt damping (relative to the diagonal).
        check_every: iterations between "all cameras done?" checks (a host sync); default 1 on CPU, 10 else.
        absolute_weights: the weights are absolute inverse variances: covariance without the ``sigma^2`` factor.
        dtype: solve precision.
        stall_tol: a camera also ends (``STALLED``) when
            :data:`~ccs_kornia.modules.calibration.schur_lm.STALL_WINDOW` iterations together lowered its cost by
            at most ``stall_tol`` relative (0: never): a crawl along a direction the data barely determine, where
            every step still passes ``ftol`` but the fit no longer changes for any practical purpose.
        groups: :math:`(C,)` integers: cameras that are other starts of one problem (the same data). At each "all
            done?" check a camera still iterating ends (``DOMINATED``) where its cost exceeds
            :data:`~ccs_kornia.modules.calibration.schur_lm.DOMINATED_RATIO` times a converged camera's of its group with as many used views (it cannot be
            the group's best; fisheye hypotheses crawled 70-100 iterations at 3-44 px RMS beside a 0.17 px optimum).
        board_warp: :math:`(C, 2)` the board's sag to start from, estimated with the rest
            (:mod:`~ccs_kornia.geometry.board_warp`); ``None``: the board is flat.
        prior: :math:`(C, P, P)` a regularisation ``x^T Lambda x`` of the parameters added to the cost (symmetric,
            positive semi-definite; e.g. a spline's control points pulled towards zero and towards a smooth surface:
            :func:`~ccs_kornia.modules.calibration.splined.spline_prior`).

    Returns:
        :class:`LMResult` (with ``warp`` and ``warp_covariance`` where ``board_warp`` is given).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> obj = board_object_points(4, 3, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rvec = torch.tensor([[[0.2, 0.1, 0.0], [-0.2, 0.3, 0.1], [0.1, -0.3, 0.2]]], dtype=torch.float64)
        >>> tvec = torch.tensor([-0.1, -0.1, 1.0], dtype=torch.float64).expand(1, 3, 3)
        >>> uv = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rvec[0], tvec[0])[None]
        >>> p0 = torch.tensor([[505., 495., 322., 238.]], dtype=torch.float64)
        >>> res = levenberg_marquardt(PINHOLE, p0, rvec, tvec, obj, uv)
        >>> res.params.round(decimals=6).tolist(), res.covariance.shape
        ([[500.0, 500.0, 320.0, 240.0]], torch.Size([1, 4, 4]))
    """
    _check(model, params, rvec, tvec, object_points, corners, weights)
    device = corners.device
    C, V, N = corners.shape[:3]
    finite = corners.isfinite().all(-1)
    w = finite.to(dtype) if weights is None else torch.where(finite, weights.to(dtype), 0.0)
    w = w.clamp_min(0)
    on = w > 0
    used = on.any(-1)
    # rows are weighted by sqrt(w); skipped when every weight is 0 or 1 and every corner is used
    sw = None if bool((w == 1).all()) else w.sqrt()
    obs = torch.where(on[..., None], corners.to(dtype), torch.zeros((), dtype=dtype, device=device))
    obj = object_points.to(device=device, dtype=dtype)
    obj = obj.expand(C, N, 3) if obj.dim() == 2 else obj
    x = params.to(device=device, dtype=dtype).clone()
    if basis is None:
        B = parameter_basis(model, x, free, fix_aspect_ratio)
        identity = B.shape[-1] == x.shape[-1] and not fix_aspect_ratio
    else:
        check_tensor(basis, "basis", [C, x.shape[-1], "F"])
        B, identity = basis.to(device=device, dtype=dtype), False
    Bn = None if identity else B
    sag = None
    if board_warp is not None:  # the sag's two coefficients after the camera's parameters, always free
        check_tensor(board_warp, "board_warp", [C, 2])
        sag = board_warp_basis(obj)
        F = B.shape[-1]
        Bw = B.new_zeros(C, x.shape[-1] + 2, F + 2)
        Bw[:, :-2, :F] = B
        Bw[:, -2:, F:] = torch.eye(2, dtype=dtype, device=device)
        x = torch.cat([x, board_warp.to(device=device, dtype=dtype)], -1)
        B, Bn = Bw, (None if identity else Bw)

    # unused views are parked in front of the camera so their (zero-weighted) projections stay finite
    rv = torch.where(used[..., None] & rvec.isfinite(), rvec.to(dtype), 0.0)
    park = torch.zeros(3, dtype=dtype, device=device)
    park[2] = 1.0 + 10.0 * float(obj.abs().amax()) if obj.numel() else 1.0
    tv = torch.where(used[..., None] & tvec.isfinite(), tvec.to(dtype), park)

    n_view = on.sum(-1)
    n_pts = n_view.sum(-1)
    floor = (w.sum((1, 2)) * 1e-20).clamp_min(1e-300)  # an RMS of 1e-10 px: a perfect fit
    if prior is not None:
        check_tensor(prior, "prior", [C, model.num_params, model.num_params])
        prior = torch.nn.functional.pad(prior.to(device=device, dtype=dtype), [0, x.shape[-1] - model.num_params] * 2)
    problem = _CameraProblem(model, obj, obs, sw, B, Bn, used, 2 * n_pts, floor,
                             torch.eye(6, dtype=dtype, device=device), {}, sag, prior)
    sol = schur_lm(problem, {"x": x, "R": _exp_so3(rv), "t": tv}, max_iters=max_iters, ftol=ftol, xtol=xtol,
                   lambda_init=lambda_init, check_every=check_every, stall_tol=stall_tol, groups=groups,
                   absolute_weights=absolute_weights)
    x, R, tv = sol.unknowns["x"], sol.unknowns["R"], sol.unknowns["t"]
    covariance, information, warp, warp_cov = sol.covariance, sol.information, None, None
    if sag is not None:  # the camera's blocks marginalised over the sag; the sag's own
        x, warp = x[:, :-2], x[:, -2:]
        obj = torch.cat([obj[..., :2], obj[..., 2:] + (sag * warp[:, None, :]).sum(-1, keepdim=True)], -1)
        B = B[:, :-2, :-2]
        warp_cov = covariance[:, -2:, -2:]
        covariance = covariance[:, :-2, :-2]
        S_ww = information[:, -2:, -2:]
        S_cw = information[:, :-2, -2:]
        information = information[:, :-2, :-2] - S_cw @ torch.linalg.pinv(S_ww) @ S_cw.transpose(-1, -2)

    # statistics at the solution (unit weights: the squared residuals per view are in the normal equations)
    if sw is None:
        sq_view = sol.equations.view_cost
    else:
        q = torch.matmul(obj[:, None].expand(C, V, N, 3), R.transpose(-1, -2))
        uv = model.columns(q + tv[:, :, None, :], x, jacobians=False)[0]
        sq_view = torch.where(on, ((uv - obs) ** 2).sum(-1), 0.0).sum(-1)
    view_rms = (sq_view / n_view.clamp_min(1)).sqrt().masked_fill(~used, float("nan"))
    rms = (sq_view.sum(-1) / n_pts.clamp_min(1)).sqrt().masked_fill(n_pts == 0, float("nan"))

    rvec_out = _log_so3(R)
    rvec_out = torch.where(used[..., None], rvec_out, rvec.to(dtype))
    tvec_out = torch.where(used[..., None], tv, tvec.to(dtype))
    return LMResult(
        params=x, rvec=rvec_out, tvec=tvec_out, cost=sol.cost, view_rms=view_rms, rms=rms, covariance=covariance,
        information=information, basis=B, sigma2=sol.sigma2, iterations=sol.iterations, status=sol.status,
        num_points=n_pts, view_used=used, warp=warp, warp_covariance=warp_cov,
    )


class LevenbergMarquardt(nn.Module):
    r"""Module form of :func:`levenberg_marquardt`: the model and options are fixed at construction.

    Args:
        model: camera model.
        free: parameters to estimate (booleans or names).
        fix_aspect_ratio: keep ``fx / fy``.
        max_iters, ftol, xtol, lambda_init, check_every, absolute_weights, dtype, stall_tol: see
            :func:`levenberg_marquardt`.

    Shape:
        params :math:`(C, P)`, rvec/tvec :math:`(C, V, 3)`, object_points :math:`(N, 3)`, corners
        :math:`(C, V, N, 2)`, weights :math:`(C, V, N)` -> :class:`LMResult`.

    Example:
        >>> from ccs_kornia.geometry.models import KannalaBrandtModel
        >>> lm = LevenbergMarquardt(KannalaBrandtModel(), free=["fx", "fy", "cx", "cy", "k1", "k2"])
        >>> lm.max_iters
        100
    """

    def __init__(
        self,
        model: CameraModel,
        free: Sequence[bool] | Sequence[str] | None = None,
        fix_aspect_ratio: bool = False,
        max_iters: int = 100,
        ftol: float = 1e-12,
        xtol: float = 1e-12,
        lambda_init: float = 1e-3,
        check_every: int | None = None,
        absolute_weights: bool = False,
        dtype: torch.dtype = torch.float64,
        stall_tol: float = 0.0,
    ) -> None:
        super().__init__()
        self.stall_tol = stall_tol
        self.model = model
        self.free = None if free is None else list(free)
        self.fix_aspect_ratio = fix_aspect_ratio
        self.max_iters = max_iters
        self.ftol, self.xtol, self.lambda_init = ftol, xtol, lambda_init
        self.check_every = check_every
        self.absolute_weights = absolute_weights
        self.dtype = dtype

    def forward(
        self,
        params: torch.Tensor,
        rvec: torch.Tensor,
        tvec: torch.Tensor,
        object_points: torch.Tensor,
        corners: torch.Tensor,
        weights: torch.Tensor | None = None,
    ) -> LMResult:
        return levenberg_marquardt(
            self.model, params, rvec, tvec, object_points, corners, weights, free=self.free,
            fix_aspect_ratio=self.fix_aspect_ratio, max_iters=self.max_iters, ftol=self.ftol, xtol=self.xtol,
            lambda_init=self.lambda_init, check_every=self.check_every, absolute_weights=self.absolute_weights,
            dtype=self.dtype, stall_tol=self.stall_tol,
        )
