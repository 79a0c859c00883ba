"""Calibration accuracy metrics, as defined in the paper (DESIGN §2).

``E_FL = |fx - fx*| + |fy - fy*|``, ``E_PP = |cx - cx*| + |cy - cy*|``, ``E_IP = (E_FL + E_PP) / 2`` (pixels),
and the RMS reprojection error ``sqrt(sum ||uv - uv*||^2 / number of points)`` (OpenCV's definition, pixels).
Camera arguments are ``(..., 3, 3)`` matrices or ``(..., 4)`` ``(fx, fy, cx, cy)`` vectors.
"""

from __future__ import annotations

import torch

from ccs_kornia.runtime.checks import check_shape, check_tensor

__all__ = ["e_fl", "e_pp", "e_ip", "rms", "per_view_rms"]


def _params(K: torch.Tensor, name: str) -> torch.Tensor:
    check_tensor(K, name, ["*", "3", "3"], ["*", "4"], what="camera matrices or (fx, fy, cx, cy)")
    if K.shape[-2:] == (3, 3):
        return torch.stack([K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]], -1)
    return K


def e_fl(K: torch.Tensor, K_true: torch.Tensor) -> torch.Tensor:
    """Focal-length error ``|fx - fx*| + |fy - fy*|`` in px, shape ``(...)``.

    Example:
        >>> e_fl(torch.tensor([501., 499., 320., 240.]), torch.tensor([500., 500., 320., 240.]))
        tensor(2.)
    """
    d = (_params(K, "K") - _params(K_true, "K_true")).abs()
    return d[..., 0] + d[..., 1]


def e_pp(K: torch.Tensor, K_true: torch.Tensor) -> torch.Tensor:
    """Principal-point error ``|cx - cx*| + |cy - cy*|`` in px, shape ``(...)``."""
    d = (_params(K, "K") - _params(K_true, "K_true")).abs()
    return d[..., 2] + d[..., 3]


def e_ip(K: torch.Tensor, K_true: torch.Tensor) -> torch.Tensor:
    """Intrinsic-parameter error ``(E_FL + E_PP) / 2`` in px, shape ``(...)``.

    Example:
        >>> K = torch.tensor([[501., 0, 321], [0, 499, 240], [0, 0, 1]])
        >>> e_ip(K, torch.tensor([500., 500., 320., 240.]))
        tensor(1.5000)
    """
    return 0.5 * (e_fl(K, K_true) + e_pp(K, K_true))


def rms(projected: torch.Tensor, observed: torch.Tensor, valid: torch.Tensor | None = None, dim=None) -> torch.Tensor:
    """RMS reprojection error ``sqrt(sum ||p - o||^2 / n_points)`` over masked points.

    Args:
        projected: :math:`(*, N, 2)` reprojected pixels.
        observed: :math:`(*, N, 2)` observed pixels (invalid entries may be NaN).
        valid: :math:`(*, N)` bool mask (default all).
        dim: dims of ``(*, N)`` to reduce over (default: all, giving a scalar, like cv2.calibrateCamera's rms).

    Returns:
        RMS in px (NaN where no point is valid).

    Example:
        >>> rms(torch.zeros(2, 2), torch.tensor([[3., 4.], [0., 0.]]))
        tensor(3.5355)
    """
    check_shape(projected, ["*", "2"], "projected must be (*, N, 2)")
    check_shape(observed, ["*", "2"], "observed must be (*, N, 2)")
    sq = (projected - observed).pow(2).sum(-1)
    if valid is None:
        valid = torch.ones_like(sq, dtype=torch.bool)
    valid = valid & sq.isfinite()
    sq = torch.where(valid, sq, torch.zeros_like(sq))
    if dim is None:
        dim = tuple(range(sq.dim()))
    n = valid.to(sq.dtype).sum(dim)
    out = (sq.sum(dim) / n.clamp_min(1)).sqrt()
    return torch.where(n > 0, out, torch.full_like(out, float("nan")))


def per_view_rms(projected: torch.Tensor, observed: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    """RMS per view: :math:`(*, N, 2)` inputs reduced over ``N`` only, shape ``(*)``."""
    return rms(projected, observed, valid, dim=-1)
