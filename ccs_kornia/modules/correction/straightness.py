"""Residual distortion without knowing the camera: how straight the rows and columns of a board are."""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.runtime.checks import check_points, check_shape, check_tensor

__all__ = ["straightness_rms"]


def straightness_rms(
    corners: torch.Tensor, valid: torch.Tensor, board_size: torch.Tensor | tuple[int, int], min_points: int = 3
) -> tuple[torch.Tensor, torch.Tensor]:
    """RMS distance (px) of board corners from total-least-squares lines fitted to each row and column.

    Under a pinhole camera every row and column of board corners is straight, so this measures residual lens
    distortion (and detection noise) without knowing the camera. Each corner counts once for its row and once
    for its column; lines with fewer than ``min_points`` valid corners are skipped.

    Args:
        corners: :math:`(B, N, 2)` corners in grid order ``n = j * cols + i`` (padded).
        valid: :math:`(B, N)` bool.
        board_size: ``(cols, rows)`` or a :math:`(B, 2)` long tensor.
        min_points: smallest line that counts.

    Returns:
        per-image RMS :math:`(B,)` (0 where no line counts) and the number of point-on-line terms :math:`(B,)`.

    Example:
        >>> xy = torch.stack(torch.meshgrid(torch.arange(3.), torch.arange(4.), indexing="xy"), -1).reshape(1, 12, 2)
        >>> rms, n = straightness_rms(xy, torch.ones(1, 12, dtype=torch.bool), (3, 4))
        >>> float(rms), int(n)
        (0.0, 24)
    """
    check_points(corners, "corners")
    b, n = corners.shape[:2]
    check_tensor(valid, "valid", [b, n])
    bs = torch.as_tensor(board_size, device=corners.device, dtype=torch.long)
    if bs.shape == (2,):
        bs = bs.expand(b, 2)
    check_shape(bs, [b, 2], f"board_size must be (cols, rows) or (B, 2) with B={b}")
    cols, rows = bs[:, 0:1], bs[:, 1:2]
    idx = torch.arange(n, device=corners.device).unsqueeze(0)
    exists = idx < cols * rows
    i = torch.remainder(idx, cols)
    j = torch.div(idx, cols, rounding_mode="floor")
    w = (valid.bool() & exists & torch.isfinite(corners).all(-1)).to(torch.float64)
    r_max, c_max = int(bs[:, 1].max()), int(bs[:, 0].max())
    member = torch.cat(
        [
            nn.functional.one_hot(j.clamp(0, r_max - 1), r_max),
            nn.functional.one_hot(i.clamp(0, c_max - 1), c_max),
        ],
        -1,
    ).to(torch.float64) * w.unsqueeze(-1)  # (B, N, L)
    p = torch.where(torch.isfinite(corners), corners, torch.zeros_like(corners)).to(torch.float64)
    count = member.sum(1)  # (B, L)
    mean = torch.einsum("bnl,bnd->bld", member, p) / count.clamp_min(1.0).unsqueeze(-1)
    d = p.unsqueeze(2) - mean.unsqueeze(1)  # (B, N, L, 2), centred before the products (float64, no cancellation)
    sxx = (member * d[..., 0] ** 2).sum(1)
    syy = (member * d[..., 1] ** 2).sum(1)
    sxy = (member * d[..., 0] * d[..., 1]).sum(1)
    # smallest eigenvalue of the 2x2 scatter matrix = sum of squared perpendicular distances to the TLS line
    sse = (0.5 * (sxx + syy) - torch.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)).clamp_min(0.0)
    use = count >= min_points
    total = torch.where(use, sse, torch.zeros_like(sse)).sum(-1)
    terms = torch.where(use, count, torch.zeros_like(count)).sum(-1)
    rms = torch.sqrt(total / terms.clamp_min(1.0))
    return rms.to(corners.dtype), terms.to(torch.long)
