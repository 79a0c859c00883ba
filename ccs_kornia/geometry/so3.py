"""Rotation vectors and matrices for the solver: lean batched exp and log maps of SO(3).

The solver converts every pose at least once per call and the LM core once per iteration; these are a few fused
tensor ops each (kornia's general conversions take about five times as many), branch-free near 0 and exact at pi.

Example:
    >>> w = torch.tensor([[0.0, 0.0, 3.141592653589793], [0.1, -0.2, 0.3]], dtype=torch.float64)
    >>> torch.allclose(log_so3(exp_so3(w)).abs(), w.abs())
    True
"""

from __future__ import annotations

import math

import torch

__all__ = ["exp_so3", "log_so3", "right_jacobian", "right_jacobian_inverse", "skew"]

#: index of the entries of [w]_x in a flat 3x3 (row-major) from (0, w1, w2, w3, -w1, -w2, -w3)
_SKEW = torch.tensor([0, 6, 2, 3, 0, 4, 5, 1, 0])


def exp_so3(w: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula ``I + sinc(t) K + (1 - cos t) / t^2 K^2`` for (..., 3) rotation vectors, ``t = |w|``,
    with ``K = [w]_x``; ``torch.sinc`` is exact at and near 0, so there is no branch (and the angle's square is
    floored at the smallest normal number, so forward- and reverse-mode derivatives at ``w = 0`` are finite)."""
    t = (w * w).sum(-1).clamp_min(torch.finfo(w.dtype).tiny).sqrt()[..., None, None]
    a = torch.sinc(t * (1 / math.pi))
    b = 0.5 * torch.sinc(t * (0.5 / math.pi)).square()
    K = torch.cat([torch.zeros_like(w[..., :1]), w, -w], -1)[..., _SKEW.to(w.device)].view(*w.shape[:-1], 3, 3)
    R = a * K + b * (K @ K)
    R.diagonal(dim1=-2, dim2=-1).add_(1.0)
    return R


def log_so3(R: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3): the inverse of :func:`exp_so3` (angle in
    [0, pi]); the axis from the skew part, or from the symmetric part beyond 90 degrees (exact at pi)."""
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) * 0.5).clamp(-1.0, 1.0)
    v = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin2 = (v * v).sum(-1).sqrt()  # 2 sin(theta)
    theta = torch.atan2(0.5 * sin2, cos)
    # below 90 degrees: w = theta / (2 sin theta) v (-> v / 2 at 0)
    small = (theta / sin2.clamp_min(1e-300)).masked_fill(sin2 < 1e-12, 0.5)[..., None] * v
    # beyond: (R + R^T) / 2 - cos I = (1 - cos) a a^T; its largest column gives +-a, the skew part the sign
    B = 0.5 * (R + R.transpose(-1, -2)) - cos[..., None, None] * torch.eye(3, dtype=R.dtype, device=R.device)
    col = B.gather(-1, B.diagonal(dim1=-2, dim2=-1).argmax(-1)[..., None, None].expand(*B.shape[:-1], 1))[..., 0]
    a = torch.nn.functional.normalize(col, dim=-1)
    a = torch.where((a * v).sum(-1, keepdim=True) < 0, -a, a)
    return torch.where((cos < 0)[..., None], a * theta[..., None], small)


def skew(v: torch.Tensor) -> torch.Tensor:
    """The cross-product matrices ``[v]_x`` :math:`(..., 3, 3)` of vectors :math:`(..., 3)`: ``[v]_x w = v x w``.

    Example:
        >>> skew(torch.tensor([1.0, 2.0, 3.0])) @ torch.tensor([0.0, 0.0, 1.0])
        tensor([ 2., -1.,  0.])
    """
    K = torch.cat([torch.zeros_like(v[..., :1]), v, -v], -1)[..., _SKEW.to(v.device)]
    return K.view(*v.shape[:-1], 3, 3)


def _coefficients(w: torch.Tensor, small, large):
    """``small(t2)`` below 1e-4 rad (a series in ``t2 = |w|^2``), ``large(t, t2)`` above, per vector: :math:`(..., 1, 1)`."""
    t2 = (w * w).sum(-1)
    near = t2 < 1e-8
    t = t2.masked_fill(near, 1.0).sqrt()
    return torch.where(near, small(t2), large(t, t2.masked_fill(near, 1.0)))[..., None, None]


def right_jacobian(w: torch.Tensor) -> torch.Tensor:
    """The right Jacobian of SO(3) :math:`(..., 3, 3)` at rotation vectors :math:`(..., 3)`:
    ``exp(w + d) = exp(w) exp(J_r(w) d)`` to first order in ``d``.

    Example:
        >>> w, d = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64), torch.tensor([1e-7, 2e-7, -1e-7], dtype=torch.float64)
        >>> lhs = exp_so3(w + d)
        >>> rhs = exp_so3(w) @ exp_so3(right_jacobian(w) @ d)
        >>> float((lhs - rhs).abs().max()) < 1e-13
        True
    """
    K = skew(w)
    a = _coefficients(w, lambda t2: 0.5 - t2 / 24, lambda t, t2: (1 - torch.cos(t)) / t2)
    b = _coefficients(w, lambda t2: 1 / 6 - t2 / 120, lambda t, t2: (t - torch.sin(t)) / (t2 * t))
    J = -a * K + b * (K @ K)
    J.diagonal(dim1=-2, dim2=-1).add_(1.0)
    return J


def right_jacobian_inverse(w: torch.Tensor) -> torch.Tensor:
    """The inverse of :func:`right_jacobian` :math:`(..., 3, 3)`: ``log(exp(w) exp(d)) = w + J_r^{-1}(w) d`` to first
    order (below pi).

    Example:
        >>> w = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)
        >>> torch.allclose(right_jacobian_inverse(w) @ right_jacobian(w), torch.eye(3, dtype=torch.float64))
        True
    """
    K = skew(w)
    c = _coefficients(w, lambda t2: 1 / 12 + t2 / 720,
                      lambda t, t2: 1 / t2 - (1 + torch.cos(t)) / (2 * t * torch.sin(t)))
    J = 0.5 * K + c * (K @ K)
    J.diagonal(dim1=-2, dim2=-1).add_(1.0)
    return J
