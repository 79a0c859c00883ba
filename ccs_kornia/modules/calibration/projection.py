"""The OpenCV projection with its analytic Jacobians, as the joint refinement needs it (elementwise, batched).

The projection is the OpenCV model as in :func:`ccs_kornia.camera.project_points` (which goes through kornia's
``distort_points``); it is re-implemented here together with its derivatives because ``project_points`` skips
distortion when all coefficients are zero, which would give zero derivatives for the distortion at the usual
zero start. Rotations are updated multiplicatively, ``R <- exp(delta) R``, so the pose Jacobian is simply
``-[R X]_x``.
"""

from __future__ import annotations

import torch

__all__ = ["project_with_jacobians"]


def _projection_columns(
    q: torch.Tensor,
    t: torch.Tensor,
    intr: torch.Tensor,
    dist8: torch.Tensor,
    n_dist: int,
    intr_cols: str,
    aspect: torch.Tensor | None,
    jacobians: bool,
    observed: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Projection and its Jacobian columns, all elementwise (no tiny batched matmuls).

    ``intr_cols``: "all" (fx, fy, cx, cy), "aspect" (f with fx = aspect * f), "aspect_fixpp", "fixpp", "none".
    Returns uv (C, V, N, 2) and J (C, V, N, 2, P) with P = n_intr + n_dist + 6 (pose: rotation, translation).
    With ``observed`` (C, V, N, 2), the residual ``uv - observed`` is appended as column P, so one product
    ``J^T J`` also yields ``J^T r`` and the cost.
    """
    Xc = q + t[:, :, None, :]
    inv_z = 1.0 / Xc[..., 2]
    x, y = Xc[..., 0] * inv_z, Xc[..., 1] * inv_z
    k = dist8[:, None, None, :]
    k1, k2, p1, p2, k3, k4, k5, k6 = k.unbind(-1)
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    a = 1 + k1 * r2 + k2 * r4 + k3 * r6
    inv_b = 1.0 / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    rad = a * inv_b
    xy2 = 2 * x * y
    xd = x * rad + p1 * xy2 + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + p2 * xy2
    fx, fy = intr[:, 0, None, None], intr[:, 1, None, None]
    uv = torch.stack([fx * xd + intr[:, 2, None, None], fy * yd + intr[:, 3, None, None]], -1)
    if not jacobians:
        return uv, None

    zero, one = torch.zeros_like(x), torch.ones_like(x)
    if intr_cols == "none":
        ju, jv = [], []
    elif intr_cols in ("aspect", "aspect_fixpp"):
        asp = aspect[:, None, None]
        ju, jv = [asp * xd], [yd]
    else:
        ju, jv = [xd, zero], [zero, yd]
    if intr_cols in ("all", "aspect"):
        ju += [one, zero]
        jv += [zero, one]

    xb, yb = x * inv_b, y * inv_b
    du = [xb * r2, xb * r4, xy2, r2 + 2 * x * x, xb * r6]
    dv = [yb * r2, yb * r4, r2 + 2 * y * y, xy2, yb * r6]
    if n_dist > 5:
        xab, yab = -xb * rad, -yb * rad
        du += [xab * r2, xab * r4, xab * r6]
        dv += [yab * r2, yab * r4, yab * r6]
    ju += [fx * c for c in du[:n_dist]]
    jv += [fy * c for c in dv[:n_dist]]

    # d uv / d Xc = diag(fx, fy) d(xd, yd)/d(x, y) d(x, y)/d Xc
    da = k1 + 2 * k2 * r2 + 3 * k3 * r4
    db = k4 + 2 * k5 * r2 + 3 * k6 * r4
    drad = (da - rad * db) * inv_b
    cross_term = xy2 * drad + 2 * p1 * x + 2 * p2 * y
    gx0 = fx * (rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x) * inv_z
    gx1 = fx * cross_term * inv_z
    gy0 = fy * cross_term * inv_z
    gy1 = fy * (rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x) * inv_z
    ax = (gx0, gx1, -(gx0 * x + gx1 * y))  # d u / d Xc
    ay = (gy0, gy1, -(gy0 * x + gy1 * y))  # d v / d Xc
    qx, qy, qz = q.unbind(-1)
    # rotation R <- exp(w) R: d Xc / d w = -[q]_x, so d u / d w = q x (d u / d Xc)
    ju += [qy * ax[2] - qz * ax[1], qz * ax[0] - qx * ax[2], qx * ax[1] - qy * ax[0], *ax]
    jv += [qy * ay[2] - qz * ay[1], qz * ay[0] - qx * ay[2], qx * ay[1] - qy * ay[0], *ay]
    if observed is not None:
        ju.append(uv[..., 0] - observed[..., 0])
        jv.append(uv[..., 1] - observed[..., 1])
    J = torch.stack(ju + jv, -1).unflatten(-1, (2, len(ju)))
    return uv, J


def project_with_jacobians(
    q: torch.Tensor, t: torch.Tensor, intr: torch.Tensor, dist8: torch.Tensor, jacobians: bool = True
) -> tuple[torch.Tensor, ...]:
    r"""OpenCV projection of rotated points ``q = R X`` and its analytic derivatives.

    Args:
        q: :math:`(C, V, N, 3)` rotated world points ``R X``.
        t: :math:`(C, V, 3)` translations.
        intr: :math:`(C, 4)` ``fx, fy, cx, cy``.
        dist8: :math:`(C, 8)` ``k1, k2, p1, p2, k3, k4, k5, k6``.
        jacobians: also return the derivatives.

    Returns:
        uv :math:`(C, V, N, 2)`; with ``jacobians``: d uv / d intr :math:`(C,V,N,2,4)`,
        d uv / d dist :math:`(C,V,N,2,8)`, d uv / d pose :math:`(C,V,N,2,6)` for the update
        ``R <- exp(w) R, t <- t + dt`` with pose ``(w, dt)`` at ``w = 0``.
    """
    uv, J = _projection_columns(q, t, intr, dist8, 8, "all", None, jacobians)
    if not jacobians:
        return (uv,)
    return uv, J[..., :4], J[..., 4:12], J[..., 12:]


def _intrinsics_basis(
    fix_aspect_ratio: bool, fix_principal_point: bool, aspect: torch.Tensor, fix_focal: bool = False
) -> torch.Tensor:
    """(C, 4, n_i) map from free intrinsic increments to (dfx, dfy, dcx, dcy)."""
    C = aspect.shape[0]
    cols = []
    z, o = torch.zeros_like(aspect), torch.ones_like(aspect)
    if fix_focal:  # all intrinsics fixed
        return torch.zeros(C, 4, 0, dtype=aspect.dtype, device=aspect.device)
    if fix_aspect_ratio:
        cols.append(torch.stack([aspect, o, z, z], -1))
    else:
        cols += [torch.stack([o, z, z, z], -1), torch.stack([z, o, z, z], -1)]
    if not fix_principal_point:
        cols += [torch.stack([z, z, o, z], -1), torch.stack([z, z, z, o], -1)]
    if not cols:
        return torch.zeros(C, 4, 0, dtype=aspect.dtype, device=aspect.device)
    return torch.stack(cols, -1).reshape(C, 4, len(cols))
