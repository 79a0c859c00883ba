r"""A rigid body's trajectory as a uniform cubic B-spline on SO(3) x R^3: pose, angular velocity and acceleration at any
time, differentiable in the control points and in time.

The orientation is the *cumulative* B-spline of Lie groups (Kim et al. 1995; Sommer et al., "Efficient derivative
computation for cumulative B-splines on Lie groups", CVPR 2020) and the position the ordinary one. With knot spacing
``dt`` and first knot ``t0``, time ``t`` falls in segment ``i = floor((t - t0) / dt)`` at ``u = (t - t0) / dt - i``,
and only the four control points ``i .. i + 3`` shape it:

.. math::
    R(t) = R_i \prod_{j=1}^{3} \exp\big(\tilde B_j(u)\, d_j\big), \quad d_j = \log(R_{i+j-1}^T R_{i+j}), \qquad
    p(t) = \sum_{j=0}^{3} B_j(u)\, p_{i+j}

The body-frame angular velocity (what a gyroscope measures) follows Sommer's recursion
:math:`\omega^{(j)} = A_j^T \omega^{(j-1)} + \dot{\tilde B}_j d_j` with :math:`A_j = \exp(\tilde B_j d_j)`,
:math:`\omega = \omega^{(3)} / dt`; the acceleration is :math:`\sum_j \ddot B_j p_{i+j} / dt^2`. Each control point
touching only four segments is what makes a long recording's normal equations banded (cost linear in its length).

Example:
    >>> R = exp_so3(torch.tensor([[0.0, 0.0, 0.1 * k] for k in range(6)], dtype=torch.float64))
    >>> p = torch.zeros(6, 3, dtype=torch.float64)
    >>> spline = SE3Spline(t0=0.0, dt=0.1, R=R, p=p)
    >>> spline.time_range
    (0.0, 0.30000000000000004)
    >>> w = spline.angular_velocity(torch.tensor([0.05, 0.25], dtype=torch.float64))
    >>> torch.allclose(w, torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=torch.float64))
    True
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.geometry.so3 import (
    exp_so3,
    log_so3,
    right_jacobian,
    right_jacobian_inverse,
    skew,
)

__all__ = ["SE3Spline", "fit_r3_spline", "r3_spline", "segment_of", "so3_spline", "spline_basis"]

#: the uniform cubic B-spline's basis: ``B(u) = _BASIS @ (1, u, u^2, u^3)``
_BASIS = torch.tensor([[1.0, -3.0, 3.0, -1.0], [4.0, 0.0, -6.0, 3.0], [1.0, 3.0, 3.0, -3.0], [0.0, 0.0, 0.0, 1.0]], dtype=torch.float64) / 6
#: its cumulative form: ``B~_j(u) = sum_{k >= j} B_k(u)``
_CUMULATIVE = _BASIS.flip(0).cumsum(0).flip(0)


def segment_of(t: torch.Tensor, t0: float, dt: float, num_points: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The segment index ``i`` (int64, clamped to ``0 .. num_points - 4``) and the position ``u`` in it of times ``t``
    (``u`` runs past ``[0, 1)`` outside the spline's time range: the end segments extend as polynomials).

    Args:
        t: :math:`(*)` times.
        t0: the first knot's time. dt: the knot spacing. num_points: the control points (at least 4).

    Returns:
        ``(i, u)``, each :math:`(*)`.

    Example:
        >>> segment_of(torch.tensor([0.0, 0.25, 0.99]), 0.0, 0.1, 10)
        (tensor([0, 2, 6]), tensor([0.0000, 0.5000, 3.9000]))
    """
    s = (t - t0) / dt
    i = s.floor().clamp(0, num_points - 4)
    return i.long(), s - i


def spline_basis(u: torch.Tensor, derivative: int = 0, cumulative: bool = False) -> torch.Tensor:
    """The four basis weights of the uniform cubic B-spline (or their ``derivative``-th derivative by ``u``) at ``u``.

    Args:
        u: :math:`(*)` positions in the segment.
        derivative: 0, 1 or 2.
        cumulative: the cumulative weights ``B~_j`` (the orientation's) instead of ``B_j``.

    Returns:
        :math:`(*, 4)`.

    Example:
        >>> spline_basis(torch.tensor([0.0, 1.0])).sum(-1)
        tensor([1., 1.])
    """
    ones, zeros = torch.ones_like(u), torch.zeros_like(u)
    if derivative == 0:
        powers = torch.stack([ones, u, u * u, u * u * u], -1)
    elif derivative == 1:
        powers = torch.stack([zeros, ones, 2 * u, 3 * u * u], -1)
    elif derivative == 2:
        powers = torch.stack([zeros, zeros, 2 * ones, 6 * u], -1)
    else:
        raise ValueError(f"derivative must be 0, 1 or 2, got {derivative}.")
    M = (_CUMULATIVE if cumulative else _BASIS).to(u)
    return powers @ M.T


def so3_spline(R: torch.Tensor, u: torch.Tensor, dt: float, jacobians: bool = False):
    r"""The orientation and the body-frame angular velocity of the cumulative cubic B-spline on SO(3) in one segment,
    and optionally their derivatives by the control rotations.

    The derivatives are by right perturbations ``R_k <- R_k exp(delta_k)`` of the four control rotations, for the
    orientation as its own right perturbation (``R(t) <- R(t) exp(sum_k E_k delta_k)``), written out along the
    product (:func:`~ccs_kornia.geometry.so3.right_jacobian` of each factor) and, for the angular velocity, along
    Sommer's recursion.

    Args:
        R: :math:`(*, 4, 3, 3)` the segment's four control rotations.
        u: :math:`(*)` the position in the segment.
        dt: the knot spacing (s).
        jacobians: also return ``E`` and ``d omega / d delta``.

    Returns:
        ``(R(t), omega(t))``: :math:`(*, 3, 3)` and :math:`(*, 3)` (rad/s, ``R^T dR/dt = [omega]_x``); with
        ``jacobians`` also ``E`` :math:`(*, 4, 3, 3)` and ``d omega / d delta`` :math:`(*, 4, 3, 3)`.

    Example:
        >>> R = exp_so3(torch.tensor([[0.0, 0.0, 0.1 * k] for k in range(4)]))
        >>> Rt, w = so3_spline(R, torch.tensor(0.5), 0.1)
        >>> w
        tensor([0.0000, 0.0000, 1.0000])
    """
    X = R[..., :-1, :, :].transpose(-1, -2) @ R[..., 1:, :, :]
    d = log_so3(X)  # (*, 3, 3)
    b = spline_basis(u, 0, cumulative=True)
    db = spline_basis(u, 1, cumulative=True) / dt
    out = R[..., 0, :, :]
    w = torch.zeros_like(d[..., 0, :])
    A, ws = [], [w]
    for j in range(3):
        Aj = exp_so3(b[..., j + 1, None] * d[..., j, :])
        out = out @ Aj
        w = (Aj.transpose(-1, -2) @ w[..., None])[..., 0] + db[..., j + 1, None] * d[..., j, :]
        A.append(Aj)
        ws.append(w)
    if not jacobians:
        return out, w
    eye = torch.eye(3, dtype=R.dtype, device=R.device)
    shape = (*d.shape[:-2], 4, 3, 3)
    Jinv = right_jacobian_inverse(d)  # (*, 3, 3, 3)
    # P_j = A_{j+1} ... A_3: what follows factor j in the product
    P = [None] * 4
    P[3] = eye.expand(*d.shape[:-2], 3, 3)
    for j in range(2, -1, -1):
        P[j] = A[j] @ P[j + 1]
    E = R.new_zeros(shape)
    E[..., 0, :, :] = P[0].transpose(-1, -2)
    Dw = R.new_zeros(shape)
    for j in range(1, 4):
        # d_j = log(R_{j-1}^T R_j) moves by J_r^-1(d_j) (delta_j - X_j^T delta_{j-1})
        Dd = R.new_zeros(shape)
        Dd[..., j, :, :] = Jinv[..., j - 1, :, :]
        Dd[..., j - 1, :, :] = -Jinv[..., j - 1, :, :] @ X[..., j - 1, :, :].transpose(-1, -2)
        # A_j = exp(b_j d_j) moves on its right by N_j dd_j
        lam = b[..., j, None, None]
        N = lam * right_jacobian(b[..., j, None] * d[..., j - 1, :])
        E = E + P[j].transpose(-1, -2)[..., None, :, :] @ (N[..., None, :, :] @ Dd)
        At = A[j - 1].transpose(-1, -2)
        G = skew((At @ ws[j - 1][..., None])[..., 0]) @ N + db[..., j, None, None] * eye
        Dw = At[..., None, :, :] @ Dw + G[..., None, :, :] @ Dd
    return out, w, E, Dw


def r3_spline(p: torch.Tensor, u: torch.Tensor, dt: float, derivative: int = 0) -> torch.Tensor:
    """The position (or its ``derivative``-th time derivative) of the cubic B-spline in R^n in one segment.

    Args:
        p: :math:`(*, 4, n)` the segment's four control points.
        u: :math:`(*)` the position in the segment.
        dt: the knot spacing (s).
        derivative: 0 (position), 1 (velocity) or 2 (acceleration).

    Returns:
        :math:`(*, n)`.

    Example:
        >>> p = torch.tensor([[0.0], [1.0], [2.0], [3.0]])
        >>> r3_spline(p, torch.tensor(0.5), 0.1, 1)
        tensor([10.])
    """
    w = spline_basis(u, derivative) / dt**derivative
    return (w[..., None, :] @ p)[..., 0, :]


def fit_r3_spline(t: torch.Tensor, x: torch.Tensor, t0: float, dt: float, num_points: int,
                  smoothing: float = 1e-6) -> torch.Tensor:
    """Control points of the cubic B-spline closest to samples ``x`` at times ``t`` in least squares (with a small
    penalty on the control points' second differences, so knots without samples are determined).

    Args:
        t: :math:`(N,)` times. x: :math:`(N, n)` values.
        t0, dt, num_points: the spline's knots.
        smoothing: weight of the second-difference penalty, relative to the samples' (1 per sample).

    Returns:
        :math:`(num\\_points, n)`.

    Example:
        >>> t = torch.linspace(0, 1, 50, dtype=torch.float64)
        >>> p = fit_r3_spline(t, torch.stack([2 * t], -1), 0.0, 0.1, 13)
        >>> i, u = segment_of(t, 0.0, 0.1, 13)
        >>> float((r3_spline(p[i[:, None] + torch.arange(4)], u, 0.1)[:, 0] - 2 * t).abs().max()) < 1e-6
        True
    """
    i, u = segment_of(t, t0, dt, num_points)
    A = t.new_zeros(t.shape[0], num_points)
    A.scatter_add_(1, i[:, None] + torch.arange(4, device=t.device), spline_basis(u))
    D = t.new_zeros(num_points - 2, num_points)
    idx = torch.arange(num_points - 2, device=t.device)
    D[idx, idx], D[idx, idx + 1], D[idx, idx + 2] = 1.0, -2.0, 1.0
    H = A.T @ A + smoothing * (D.T @ D) + 1e-12 * torch.eye(num_points, dtype=t.dtype, device=t.device)
    return torch.linalg.solve(H, A.T @ x)


@dataclass
class SE3Spline:
    """A trajectory: control rotations ``R`` :math:`(M, 3, 3)` (body to world) and positions ``p`` :math:`(M, 3)` (the
    body's origin in the world) on uniform knots from ``t0`` spaced ``dt``.

    Segment ``i`` spans ``t0 + i dt .. t0 + (i + 1) dt``: the time range is ``t0 .. t0 + (M - 3) dt``.
    """

    t0: float
    dt: float
    R: torch.Tensor
    p: torch.Tensor

    @property
    def num_points(self) -> int:
        """The control points ``M``."""
        return self.R.shape[0]

    @property
    def time_range(self) -> tuple[float, float]:
        """The first and the last time with four control points."""
        return self.t0, self.t0 + (self.num_points - 3) * self.dt

    def _local(self, t: torch.Tensor):
        i, u = segment_of(t, self.t0, self.dt, self.num_points)
        idx = i[..., None] + torch.arange(4, device=t.device)
        return self.R[idx], self.p[idx], u

    def pose(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotations :math:`(*, 3, 3)` and positions :math:`(*, 3)` at times ``t`` :math:`(*)`."""
        R, p, u = self._local(t)
        return so3_spline(R, u, self.dt)[0], r3_spline(p, u, self.dt)

    def angular_velocity(self, t: torch.Tensor) -> torch.Tensor:
        """Body-frame angular velocities :math:`(*, 3)` (rad/s) at times ``t`` :math:`(*)`."""
        R, _, u = self._local(t)
        return so3_spline(R, u, self.dt)[1]

    def acceleration(self, t: torch.Tensor) -> torch.Tensor:
        """World-frame accelerations :math:`(*, 3)` at times ``t`` :math:`(*)`."""
        _, p, u = self._local(t)
        return r3_spline(p, u, self.dt, 2)
