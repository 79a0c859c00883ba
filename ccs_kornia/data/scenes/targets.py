"""Training targets of the corner network: Gaussian heatmaps at the ground-truth corners."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ccs_kornia.data.batching import check_image_size

__all__ = ["gaussian_heatmaps"]


def gaussian_heatmaps(corners: Tensor, valid: Tensor, image_size: tuple[int, int], sigma: float = 1.5) -> Tensor:
    """Target heatmaps: the maximum over valid corners of ``exp(-|x - c|^2 / (2 sigma^2))``.

    Each corner only writes a ``(2 ceil(3 sigma) + 1)^2`` window around it (scatter with ``amax``), so the
    cost does not grow with ``H * W * N`` as a dense rendering would.

    Args:
        corners: :math:`(B, N, 2)` pixel coordinates (pixel centres at integers).
        valid: :math:`(B, N)` bool.
        image_size: ``(W, H)``.
        sigma: Gaussian standard deviation in pixels.

    Returns:
        :math:`(B, 1, H, W)` in ``[0, 1]``, exactly 1 at a corner lying on a pixel centre.

    Example:
        >>> hm = gaussian_heatmaps(torch.tensor([[[5.0, 3.0]]]), torch.tensor([[True]]), (10, 8))
        >>> float(hm[0, 0, 3, 5]), hm.shape
        (1.0, torch.Size([1, 1, 8, 10]))
    """
    if corners.dim() != 3 or corners.shape[-1] != 2:
        raise ValueError(f"corners must be (B, N, 2), got {tuple(corners.shape)}.")
    if valid.shape != corners.shape[:2]:
        raise ValueError(f"valid must be {tuple(corners.shape[:2])}, got {tuple(valid.shape)}.")
    if sigma <= 0:
        raise ValueError(f"sigma must be positive, got {sigma}.")
    w, h = check_image_size(image_size)
    b, n = corners.shape[:2]
    dev = corners.device
    dt = corners.dtype if corners.is_floating_point() else torch.float32
    out = torch.zeros(b * h * w + 1, device=dev, dtype=dt)
    if n == 0:
        return out[:-1].view(b, 1, h, w)
    rad = int(math.ceil(3.0 * sigma))
    offs = torch.arange(-rad, rad + 1, device=dev)
    oy, ox = torch.meshgrid(offs, offs, indexing="ij")
    safe = torch.where(torch.isfinite(corners), corners, torch.zeros_like(corners)).to(dt)
    base = safe.round().long()
    px = base[..., 0, None] + ox.reshape(1, 1, -1)
    py = base[..., 1, None] + oy.reshape(1, 1, -1)
    d2 = (px.to(dt) - safe[..., 0, None]) ** 2 + (py.to(dt) - safe[..., 1, None]) ** 2
    val = torch.exp(-d2 / (2.0 * sigma * sigma))
    keep = valid.bool().unsqueeze(-1) & (px >= 0) & (px < w) & (py >= 0) & (py < h)
    bidx = torch.arange(b, device=dev).view(b, 1, 1)
    flat = torch.where(keep, bidx * (h * w) + py * w + px, torch.full_like(px, b * h * w))
    out.scatter_reduce_(0, flat.reshape(-1), val.reshape(-1), reduce="amax", include_self=True)
    return out[:-1].view(b, 1, h, w)
