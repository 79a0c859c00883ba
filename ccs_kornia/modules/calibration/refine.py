"""Joint Levenberg–Marquardt refinement of intrinsics, distortion and all poses, batched over cameras.

Unknowns per camera: the free intrinsics (``fx, fy, cx, cy``, or fewer with ``fix_aspect_ratio`` /
``fix_principal_point``), the free OpenCV distortion coefficients of the chosen model, and one 6-dof pose
per view. The normal equations have the classic bundle-adjustment arrow structure (a small dense block for
the camera, independent 6x6 blocks for the views), so each step eliminates the pose blocks with a Schur
complement: the cost is linear in the number of views and every camera of the batch is solved in the same
tensor ops (no Python loop over cameras or views).

The Jacobians are analytic (:mod:`~ccs_kornia.modules.calibration.projection`: the OpenCV projection
re-implemented with its derivatives; a test checks it agrees with :func:`ccs_kornia.camera.project_points` to
float64 rounding and that the Jacobian matches autograd). Rotations are updated multiplicatively,
``R <- exp(delta) R``, so axis-angle singularities never occur inside the solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ccs_kornia.camera import axis_angle_to_rotation_matrix, num_distortion_coeffs, rotation_matrix_to_axis_angle
from ccs_kornia.modules.calibration.projection import _intrinsics_basis, _projection_columns

__all__ = ["RefinementResult", "joint_refinement", "JointRefinement", "FREE_DISTORTION"]

#: indices (OpenCV order k1,k2,p1,p2,k3,k4,k5,k6) estimated by each model; the rest stay 0
FREE_DISTORTION: dict[str, list[int]] = {
    "none": [],
    "k1k2": [0, 1],
    "opencv5": [0, 1, 2, 3, 4],
    "rational": [0, 1, 2, 3, 4, 5, 6, 7],
}


@dataclass
class RefinementResult:
    """Output of :func:`joint_refinement` (C cameras, V views, D coefficients)."""

    K: torch.Tensor  #: (C, 3, 3)
    dist: torch.Tensor  #: (C, D) OpenCV order
    rvec: torch.Tensor  #: (C, V, 3)
    tvec: torch.Tensor  #: (C, V, 3)
    view_rms: torch.Tensor  #: (C, V) RMS reprojection error per view in px, NaN for unused views
    rms: torch.Tensor  #: (C,) sqrt(sum squared error / number of points), as cv2.calibrateCamera
    std_intrinsics: torch.Tensor  #: (C, 4) standard deviations of fx, fy, cx, cy (0 where fixed)
    std_dist: torch.Tensor  #: (C, D) standard deviations of the coefficients (0 where fixed)
    converged: torch.Tensor  #: (C,) bool
    iterations: torch.Tensor  #: (C,) LM iterations used
    num_points: torch.Tensor  #: (C,) corners used
    #: (C, 4 + D, 4 + D) covariance of (fx, fy, cx, cy, dist) (zero rows/columns for fixed parameters)
    cov_camera: torch.Tensor | None = None


def _sym_solve(A: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Solve SPD systems (..., P, P) x = b (..., P) with Jacobi scaling; failed ones give 0."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    As = A * d[..., :, None] * d[..., None, :]
    L, info = torch.linalg.cholesky_ex(As)
    good = info == 0
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    L = torch.where(good[..., None, None], L, eye)
    x = torch.cholesky_solve((b * d).unsqueeze(-1), L).squeeze(-1) * d
    return torch.where(good[..., None] & x.isfinite(), x, torch.zeros_like(x))


def _sym_inverse(A: torch.Tensor) -> torch.Tensor:
    """Inverse of SPD matrices with Jacobi scaling; failures give NaN."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    As = A * d[..., :, None] * d[..., None, :]
    L, info = torch.linalg.cholesky_ex(As)
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    good = info == 0
    inv = torch.cholesky_inverse(torch.where(good[..., None, None], L, eye))
    inv = inv * d[..., :, None] * d[..., None, :]
    return torch.where(good[..., None, None], inv, torch.full_like(inv, float("nan")))


def _pseudo_inverse(A: torch.Tensor, rcond: float = 1e-15) -> torch.Tensor:
    """Inverse of symmetric PSD matrices (Jacobi-scaled) with eigenvalues clamped at ``rcond`` times the
    largest: finite, and huge along (nearly) null directions."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    As = A * d[..., :, None] * d[..., None, :]
    ev, U = torch.linalg.eigh(As)
    ev = ev.clamp_min(rcond * ev.amax(-1, keepdim=True).clamp_min(1e-300))
    inv = (U / ev[..., None, :]) @ U.transpose(-1, -2)
    return inv * d[..., :, None] * d[..., None, :]


def _normalize_inputs(corners, valid, object_points, K, rvec, tvec, dist, view_mask):
    """Add the camera dim to unbatched inputs; returns tensors plus an ``unbatched`` flag."""
    unbatched = corners.dim() == 3
    if unbatched:
        corners, valid, rvec, tvec = corners[None], valid[None], rvec[None], tvec[None]
        K = K[None] if K.dim() == 2 else K
        if dist is not None and dist.dim() == 1:
            dist = dist[None]
        if view_mask is not None:
            view_mask = view_mask[None]
        if object_points.dim() == 3:
            object_points = object_points[None]
    if corners.dim() != 4 or corners.shape[-1] != 2:
        raise ValueError(f"corners must be (C, V, N, 2) or (V, N, 2), got {tuple(corners.shape)}.")
    C, V, N = corners.shape[:3]
    if valid.shape != (C, V, N):
        raise ValueError(f"valid must be {(C, V, N)}, got {tuple(valid.shape)}.")
    if object_points.shape not in ((N, 3), (C, N, 3)):
        raise ValueError(f"object_points must be ({N}, 3) or ({C}, {N}, 3), got {tuple(object_points.shape)}.")
    if K.shape != (C, 3, 3):
        raise ValueError(f"K must be ({C}, 3, 3), got {tuple(K.shape)}.")
    if rvec.shape != (C, V, 3) or tvec.shape != (C, V, 3):
        raise ValueError(f"rvec/tvec must be ({C}, {V}, 3), got {tuple(rvec.shape)} and {tuple(tvec.shape)}.")
    if view_mask is not None and view_mask.shape != (C, V):
        raise ValueError(f"view_mask must be ({C}, {V}), got {tuple(view_mask.shape)}.")
    return corners, valid, object_points, K, rvec, tvec, dist, view_mask, unbatched


def joint_refinement(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    K: torch.Tensor,
    rvec: torch.Tensor,
    tvec: torch.Tensor,
    dist: torch.Tensor | None = None,
    view_mask: torch.Tensor | None = None,
    model: str = "opencv5",
    fix_aspect_ratio: bool = False,
    fix_principal_point: bool = False,
    max_iters: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    lambda_init: float = 1e-3,
    dtype: torch.dtype = torch.float64,
    fix_intrinsics: bool = False,
    fix_distortion: bool = False,
) -> RefinementResult:
    r"""Batched Levenberg–Marquardt over intrinsics, distortion and per-view poses (see module doc).

    Args:
        corners: :math:`(C, V, N, 2)` observed pixels (or :math:`(V, N, 2)`); invalid entries may be NaN.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` board points.
        K: :math:`(C, 3, 3)` initial camera matrices (skew is ignored: zero-skew model).
        rvec: :math:`(C, V, 3)` initial axis-angle rotations.
        tvec: :math:`(C, V, 3)` initial translations.
        dist: :math:`(C, D')` initial coefficients in OpenCV order (any length <= 8; default zeros).
        view_mask: :math:`(C, V)` bool, views to use (default: views with >= 1 valid corner).
        model: ``none`` | ``k1k2`` | ``opencv5`` | ``rational``.
        fix_aspect_ratio: keep ``fx / fy`` at its initial value (OpenCV's ``CALIB_FIX_ASPECT_RATIO``).
        fix_principal_point: keep ``cx, cy`` at their initial values.
        max_iters: LM iterations at most.
        ftol: stop when the cost decreases by less than ``ftol`` relative.
        xtol: stop when the step is below ``xtol`` relative to the parameters.
        lambda_init: initial Marquardt damping (relative to the diagonal).
        dtype: solve precision.
        fix_intrinsics: keep ``fx, fy, cx, cy`` fixed (with ``fix_distortion``: poses only).
        fix_distortion: keep the distortion coefficients at their initial values.

    Returns:
        :class:`RefinementResult`; the camera dim is dropped again for unbatched input.

    Example:
        >>> from ccs_kornia.camera import board_object_points, project_points
        >>> obj = board_object_points(4, 3, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rvec = torch.tensor([[0.2, 0.1, 0.0], [-0.2, 0.3, 0.1], [0.1, -0.3, 0.2]], dtype=torch.float64)
        >>> tvec = torch.tensor([[-0.1, -0.1, 1.0]], dtype=torch.float64).expand(3, 3)
        >>> uv = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rvec, tvec)
        >>> res = joint_refinement(uv, torch.ones(3, 12, dtype=torch.bool), obj, K * 1.01 + 0.0, rvec, tvec,
        ...                        model="none")
        >>> bool(res.rms < 1e-6)
        True
    """
    if model not in FREE_DISTORTION:
        raise ValueError(f"Unknown distortion model {model!r}; expected one of {sorted(FREE_DISTORTION)}.")
    corners, valid, object_points, K, rvec, tvec, dist, view_mask, unbatched = _normalize_inputs(
        corners, valid, object_points, K, rvec, tvec, dist, view_mask
    )
    device = corners.device
    C, V, N = corners.shape[:3]
    D = num_distortion_coeffs(model)
    free_d = [] if fix_distortion else FREE_DISTORTION[model]
    n_d = len(free_d)

    valid = valid.bool()
    if view_mask is None:
        view_mask = valid.any(-1)
    view_mask = view_mask.bool()
    w = valid & view_mask[..., None] & corners.isfinite().all(-1)
    used = w.any(-1)
    wf = w.to(dtype)
    obs = torch.where(w[..., None], corners.to(dtype), torch.zeros((), dtype=dtype, device=device))
    obj = object_points.to(dtype)
    obj = obj.expand(C, N, 3) if obj.dim() == 2 else obj

    intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1).to(dtype)
    dist8 = torch.zeros(C, 8, dtype=dtype, device=device)
    if dist is not None and dist.shape[-1] > 0:
        d0 = dist.to(dtype).expand(C, -1)
        dist8[:, : min(8, d0.shape[-1])] = d0[:, :8]
    keep = torch.zeros(8, dtype=dtype, device=device)
    keep[FREE_DISTORTION[model]] = 1
    dist8 = dist8 * keep  # coefficients outside the model are zero

    rv = torch.where(rvec.isfinite(), rvec.to(dtype), torch.zeros((), dtype=dtype, device=device))
    tv = torch.where(tvec.isfinite(), tvec.to(dtype), torch.zeros((), dtype=dtype, device=device))
    # Unused views are parked far in front of the camera so their (masked) projections stay finite.
    park = torch.zeros(3, dtype=dtype, device=device)
    park[2] = 1.0 + 10.0 * float(obj.abs().amax()) if obj.numel() else 1.0
    rv = torch.where(used[..., None], rv, torch.zeros_like(rv))
    tv = torch.where(used[..., None], tv, park)
    R = axis_angle_to_rotation_matrix(rv.reshape(-1, 3)).reshape(C, V, 3, 3)

    aspect = intr[:, 0] / intr[:, 1]
    P = _intrinsics_basis(fix_aspect_ratio, fix_principal_point, aspect, fix_intrinsics)  # (C, 4, n_i)
    intr_cols = {(False, False): "all", (True, False): "aspect", (True, True): "aspect_fixpp", (False, True): "fixpp"}[
        (fix_aspect_ratio, fix_principal_point)
    ]
    if fix_intrinsics:
        intr_cols = "none"
    n_i = P.shape[-1]
    n_g = n_i + n_d
    eye6 = torch.eye(6, dtype=dtype, device=device)

    all_valid = bool(w.all())
    # "perfect" fit: an RMS of 1e-10 px is far below any meaningful corner precision
    cost_floor = (wf.sum((1, 2)) * 1e-20).clamp_min(1e-300)

    def residuals(idx, R_, t_, intr_, dist_, jac: bool):
        """Residuals (and Jacobian) of the cameras ``idx`` (None: all) at the given parameters."""
        sel = (lambda x: x) if idx is None else (lambda x: x[idx])
        q = torch.einsum("cvij,cnj->cvni", R_, sel(obj))
        uv, J = _projection_columns(q, t_, intr_, dist_, n_d, intr_cols, sel(aspect), jac)
        r = torch.where(sel(w)[..., None], uv - sel(obs), torch.zeros((), dtype=dtype, device=device))
        return r, J

    def cost_of(r):
        c = (r * r).sum((1, 2, 3))
        return torch.where(c.isfinite(), c, torch.full_like(c, float("inf")))

    def normal_equations(idx):
        sel = lambda x: x[idx]  # noqa: E731
        q = torch.einsum("cvij,cnj->cvni", sel(R), sel(obj))
        _, J = _projection_columns(q, sel(tv), sel(intr), sel(dist8), n_d, intr_cols, sel(aspect), True, sel(obs))
        if not all_valid:  # masked rows must not contribute (skipped when every corner is used: a full pass)
            J = J * sel(wf)[..., None, None]
        J = J.flatten(2, 3)  # (c, V, 2N, n_g + 6 + 1): Jacobian and residual column
        A = J.transpose(-1, -2) @ J  # per-view normal blocks, J^T r and r^T r in the last row
        P_ = n_g + 6
        cost_ = A[..., P_, P_].sum(1)
        cost_ = torch.where(cost_.isfinite(), cost_, torch.full_like(cost_, float("inf")))
        Vb_ = torch.where(sel(used)[..., None, None], A[..., n_g:P_, n_g:P_], eye6)
        e = A[..., :P_, P_]
        return cost_, A[..., :n_g, :n_g].sum(1), A[..., :n_g, n_g:P_], Vb_, e[..., :n_g].sum(1), e[..., n_g:]

    lam = torch.full((C,), lambda_init, dtype=dtype, device=device)
    done = ~used.any(-1)
    converged = done.clone()
    iters = torch.zeros(C, dtype=torch.long, device=device)
    everyone = torch.arange(C, device=device)
    cost, U, W, Vb, eg, ep = normal_equations(everyone)
    for _ in range(max_iters):
        # Only the cameras still iterating are computed: the batch shrinks as cameras converge.
        act = (~done).nonzero().squeeze(1)
        if act.numel() == 0:
            break
        iters[act] += 1
        lam_a, used_a = lam[act], used[act].to(dtype)
        U_a, W_a, Vb_a, eg_a, ep_a = U[act], W[act], Vb[act], eg[act], ep[act]
        Ud = U_a + torch.diag_embed(U_a.diagonal(dim1=-2, dim2=-1) * lam_a[:, None])
        Vd = Vb_a + torch.diag_embed(Vb_a.diagonal(dim1=-2, dim2=-1) * lam_a[:, None, None])
        Vinv = _sym_inverse(Vd)
        Vinv = torch.where(Vinv.isfinite(), Vinv, torch.zeros_like(Vinv))
        Y = W_a @ Vinv  # (c, V, n_g, 6)
        S = Ud - (Y @ W_a.transpose(-1, -2)).sum(1)
        rhs = -eg_a + (Y @ ep_a.unsqueeze(-1)).squeeze(-1).sum(1)
        dg = _sym_solve(S, rhs)
        dp = (Vinv @ (-ep_a - (W_a.transpose(-1, -2) @ dg[:, None, :, None]).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
        dp = dp * used_a[..., None]

        # trial parameters
        R_a, t_a, intr_a, dist_a = R[act], tv[act], intr[act], dist8[act]
        intr_n = intr_a + (P[act] @ dg[:, :n_i, None]).squeeze(-1)
        dist_n = dist_a.clone()
        if n_d:
            dist_n[:, free_d] = dist_a[:, free_d] + dg[:, n_i:]
        dR = axis_angle_to_rotation_matrix(dp[..., :3].reshape(-1, 3)).reshape(-1, V, 3, 3)
        R_n, t_n = dR @ R_a, t_a + dp[..., 3:]
        r_n, _ = residuals(act, R_n, t_n, intr_n, dist_n, False)
        cost_n = cost_of(r_n)
        cost_a = cost[act]
        accept = cost_n < cost_a
        # relative step size over all parameters of the camera
        scale = torch.cat([intr_a.abs(), dist_a.abs(), t_a.abs().flatten(1), torch.ones_like(intr_a[:, :1])], -1)
        step = torch.cat([dg.abs(), dp.abs().flatten(1)], -1).amax(-1)
        small_step = step <= xtol * scale.amax(-1)
        small_decrease = (cost_a - cost_n).abs() <= ftol * cost_a
        finished = (accept & small_decrease) | small_step | (lam_a > 1e16)
        finished = finished | (torch.where(accept, cost_n, cost_a) <= cost_floor[act])

        R[act] = torch.where(accept[:, None, None, None], R_n, R_a)
        tv[act] = torch.where(accept[:, None, None], t_n, t_a)
        intr[act] = torch.where(accept[:, None], intr_n, intr_a)
        dist8[act] = torch.where(accept[:, None], dist_n, dist_a)
        lam[act] = torch.where(accept, (lam_a / 10).clamp_min(1e-15), lam_a * 10)
        converged[act] = converged[act] | finished
        done[act] = done[act] | finished
        # fresh normal equations where the step was taken and the camera goes on
        acc = act[accept & ~finished]
        if acc.numel():
            cost[acc], U[acc], W[acc], Vb[acc], eg[acc], ep[acc] = normal_equations(acc)

    # statistics at the solution
    r, _ = residuals(None, R, tv, intr, dist8, False)
    _, U, W, Vb, _, _ = normal_equations(everyone)
    sq = (r * r).sum(-1)  # (C, V, N)
    n_pts_view = wf.sum(-1)
    view_rms = (sq.sum(-1) / n_pts_view.clamp_min(1)).sqrt()
    view_rms = torch.where(used, view_rms, torch.full_like(view_rms, float("nan")))
    n_pts = wf.sum((1, 2))
    rms = (sq.sum((1, 2)) / n_pts.clamp_min(1)).sqrt()
    rms = torch.where(n_pts > 0, rms, torch.full_like(rms, float("nan")))

    Vinv = _sym_inverse(Vb)
    Vinv = torch.where(used[..., None, None] & Vinv.isfinite(), Vinv, torch.zeros_like(Vinv))
    S = U - ((W @ Vinv) @ W.transpose(-1, -2)).sum(1)
    n_params = n_g + 6 * used.sum(-1)
    dof = (2 * n_pts - n_params.to(dtype)).clamp_min(1)
    sigma2 = sq.sum((1, 2)) / dof
    cov_g = _sym_inverse(S)
    # trust (issue 12): a (numerically) singular information matrix gives a huge, not a NaN, variance along the
    # undetermined directions, so the checks can tell which parameters the views do not constrain
    singular = ~cov_g.flatten(1).isfinite().all(-1) & S.flatten(1).isfinite().all(-1)
    if bool(singular.any()):
        cov_g[singular] = _pseudo_inverse(S[singular])
    cov_g = cov_g * sigma2[:, None, None]
    cov_i = P @ cov_g[:, :n_i, :n_i] @ P.transpose(-1, -2)
    std_intr = cov_i.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
    # full covariance of (fx, fy, cx, cy, dist[:D]): free parameters mapped through the intrinsics basis
    E = torch.zeros(C, 4 + D, n_g, dtype=dtype, device=device)
    E[:, :4, :n_i] = P
    for k, j in enumerate(free_d):
        E[:, 4 + j, n_i + k] = 1
    cov_camera = E @ cov_g @ E.transpose(-1, -2)
    std8 = torch.zeros(C, 8, dtype=dtype, device=device)
    if n_d:
        std8[:, free_d] = cov_g[:, n_i:, n_i:].diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()

    K_out = torch.zeros(C, 3, 3, dtype=dtype, device=device)
    K_out[:, 0, 0], K_out[:, 1, 1] = intr[:, 0], intr[:, 1]
    K_out[:, 0, 2], K_out[:, 1, 2] = intr[:, 2], intr[:, 3]
    K_out[:, 2, 2] = 1
    rvec_out = rotation_matrix_to_axis_angle(R.reshape(-1, 3, 3)).reshape(C, V, 3)
    # unused views keep their initial pose
    rvec_out = torch.where(used[..., None], rvec_out, rvec.to(dtype))
    tv = torch.where(used[..., None], tv, tvec.to(dtype))
    res = RefinementResult(
        K=K_out,
        dist=dist8[:, :D],
        rvec=rvec_out,
        tvec=tv,
        view_rms=view_rms,
        rms=rms,
        std_intrinsics=std_intr,
        std_dist=std8[:, :D],
        converged=converged & used.any(-1),
        iterations=iters,
        num_points=n_pts.long(),
        cov_camera=cov_camera,
    )
    if unbatched:
        res = RefinementResult(**{k: v[0] for k, v in res.__dict__.items()})
    return res


class JointRefinement(nn.Module):
    r"""Module wrapper of :func:`joint_refinement`; the options are fixed at construction.

    Args:
        model: ``none`` | ``k1k2`` | ``opencv5`` | ``rational``.
        fix_aspect_ratio: keep ``fx / fy`` at its initial value.
        fix_principal_point: keep ``cx, cy`` at their initial values.
        max_iters: LM iterations at most.
        ftol: relative cost-decrease tolerance.
        xtol: relative step tolerance.
        dtype: solve precision (float64 recommended).

    Shape:
        corners :math:`(C, V, N, 2)`, valid :math:`(C, V, N)`, object_points :math:`(N, 3)`, K :math:`(C, 3, 3)`,
        rvec/tvec :math:`(C, V, 3)`, dist :math:`(C, D)` optional, view_mask :math:`(C, V)` optional
        -> :class:`RefinementResult`.
    """

    def __init__(
        self,
        model: str = "opencv5",
        fix_aspect_ratio: bool = False,
        fix_principal_point: bool = False,
        max_iters: int = 100,
        ftol: float = 1e-12,
        xtol: float = 1e-12,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        super().__init__()
        if model not in FREE_DISTORTION:
            raise ValueError(f"Unknown distortion model {model!r}; expected one of {sorted(FREE_DISTORTION)}.")
        self.model = model
        self.fix_aspect_ratio = fix_aspect_ratio
        self.fix_principal_point = fix_principal_point
        self.max_iters = max_iters
        self.ftol = ftol
        self.xtol = xtol
        self.dtype = dtype

    def forward(
        self,
        corners: torch.Tensor,
        valid: torch.Tensor,
        object_points: torch.Tensor,
        K: torch.Tensor,
        rvec: torch.Tensor,
        tvec: torch.Tensor,
        dist: torch.Tensor | None = None,
        view_mask: torch.Tensor | None = None,
    ) -> RefinementResult:
        return joint_refinement(
            corners, valid, object_points, K, rvec, tvec, dist, view_mask, model=self.model,
            fix_aspect_ratio=self.fix_aspect_ratio, fix_principal_point=self.fix_principal_point,
            max_iters=self.max_iters, ftol=self.ftol, xtol=self.xtol, dtype=self.dtype,
        )
