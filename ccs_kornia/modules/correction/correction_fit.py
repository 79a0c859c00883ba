"""Radial correction coefficients fitted to point correspondences (closed form, batched)."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.radial import radial_centre_scale
from ccs_kornia.runtime.checks import check_points, check_same_shape

__all__ = ["fit_correction_to_points"]


def fit_correction_to_points(
    distorted: torch.Tensor,
    ideal: torch.Tensor,
    image_size: tuple[int, int],
    mask: torch.Tensor | None = None,
    fix_k0: bool = True,
) -> torch.Tensor:
    """Least-squares correction coefficients mapping ``distorted`` pixels onto ``ideal`` ones.

    ``correct_points`` is linear in the coefficients (``p_c - c = (p_d - c) sum_j k_j' r_d^j``), so this is one
    batched solve. With ``fix_k0`` the scale at the centre stays 1: a zoom about the centre cannot be told from
    the focal length, so leaving it free would let a calibration loop drift.

    Args:
        distorted, ideal: :math:`(B, N, 2)` pixels.
        image_size: ``(W, H)``.
        mask: optional :math:`(B, N)` bool of points to use.
        fix_k0: keep ``k0' = 1``.

    Returns:
        :math:`(B, 5)` correction coefficients.

    Example:
        >>> c = torch.tensor([[1.0, 0.0, 0.3, 0.0, 0.1]], dtype=torch.float64)
        >>> p = torch.rand(1, 50, 2, dtype=torch.float64) * torch.tensor([64.0, 48.0])
        >>> from ccs_kornia.modules.correction.radial_warp import correct_points
        >>> bool(torch.allclose(fit_correction_to_points(p, correct_points(p, c, (64, 48)), (64, 48)), c))
        True
    """
    check_points(distorted, "distorted")
    check_same_shape(ideal, "ideal", distorted, "distorted")
    centre, scale = radial_centre_scale(image_size, distorted)
    d = distorted - centre
    r = d.norm(dim=-1) / scale  # (B, N)
    powers = torch.stack([r**j for j in range(5)], -1)  # (B, N, 5)
    A = (d.unsqueeze(-1) * powers.unsqueeze(-2)).reshape(d.shape[0], -1, 5)  # (B, 2N, 5)
    b = (ideal - centre).reshape(d.shape[0], -1)
    w = torch.ones_like(r) if mask is None else mask.to(r.dtype)
    w = w * (torch.isfinite(ideal).all(-1) & torch.isfinite(distorted).all(-1)).to(r.dtype)
    w = w.repeat_interleave(2, -1)
    A, b = A.nan_to_num(0.0) * w.unsqueeze(-1), b.nan_to_num(0.0) * w
    if fix_k0:
        sol = torch.linalg.lstsq(A[..., 1:], (b - A[..., 0]).unsqueeze(-1)).solution.squeeze(-1)
        return torch.cat([torch.ones_like(sol[:, :1]), sol], -1)
    return torch.linalg.lstsq(A, b.unsqueeze(-1)).solution.squeeze(-1)
