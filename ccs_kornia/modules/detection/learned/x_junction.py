"""X-junction test of candidate corners on the image: keep a peak only where a circle around it crosses its mean
intensity exactly four times (a chessboard corner), which drops board edges, clutter and blobs the heatmap network may
fire on."""

from __future__ import annotations

import torch

from ccs_kornia.modules.detection.refine.saddle_refine import sample_bilinear

__all__ = ["x_junction_mask"]


def x_junction_mask(
    image: torch.Tensor,
    points: torch.Tensor,
    mask: torch.Tensor,
    radius_factor: float = 0.35,
    min_radius: float = 2.0,
    max_radius: float = 15.0,
    samples: int = 32,
) -> torch.Tensor:
    r"""Keep only points where the image shows an X-junction (a chessboard corner), ``(B, M)`` bool.

    The intensity is sampled on a circle around each point (radius a fraction of the distance to the
    nearest other point, i.e. of the local square size) and must cross its own mean exactly four
    times: light, dark, light, dark. A T- or L-junction (a board's outer edge against a dark
    background, a keyboard key) crosses twice and is rejected, which a heatmap alone cannot tell.

    Args:
        image: :math:`(B, 1, H, W)`.
        points: :math:`(B, M, 2)` candidate corners.
        mask: :math:`(B, M)` bool, candidates to test.
        radius_factor: circle radius as a fraction of the nearest-neighbour distance.
        min_radius, max_radius: clamp of the radius in px.
        samples: points on the circle.

    Returns:
        :math:`(B, M)` bool: ``mask`` and an X-junction.
    """
    b, m = points.shape[:2]
    count = mask.sum(1)
    k = int(count.max()) if b and m else 0
    if k == 0:
        return torch.zeros_like(mask)
    if k < m:
        # only the candidates are tested: each image's first (a detector pads its peaks to a fixed count, of which
        # a few dozen are candidates; 16 renders of 640x480: 512 peaks, at most 75 candidates)
        order = torch.argsort((~mask).to(torch.int8), dim=1, stable=True)[:, :k]
        sub = x_junction_mask(image, points.gather(1, order[..., None].expand(-1, -1, 2)), mask.gather(1, order),
                              radius_factor, min_radius, max_radius, samples)
        return torch.zeros_like(mask).scatter_(1, order, sub)
    pts = points.float()
    d = torch.cdist(pts, pts)
    d = d.masked_fill(~(mask[:, :, None] & mask[:, None, :]), float("inf"))
    d.diagonal(dim1=1, dim2=2).fill_(float("inf"))
    nn = d.min(-1).values
    spacing = torch.nan_to_num(nn, posinf=4 * max_radius)
    ang = torch.arange(samples, device=pts.device, dtype=pts.dtype) * (2 * torch.pi / samples)
    ring = torch.stack([ang.cos(), ang.sin()], -1)  # (S,2)
    keep = mask.clone()
    # two circles: the outer one sees the four squares, the inner one cannot reach past a thin board
    # border, where a board's outer edge against a dark background looks like a corner from afar
    for factor in (radius_factor, 0.4 * radius_factor):
        rad = (factor * spacing).clamp(min_radius, max_radius)
        loc = pts[:, :, None, :] + rad[..., None, None] * ring[None, None]
        prof = sample_bilinear(image.float(), loc)[:, 0]  # (B,M,S)
        # circular 3-tap smoothing so pixel noise does not add crossings
        prof = (prof + prof.roll(1, -1) + prof.roll(-1, -1)) / 3
        centred = prof - prof.mean(-1, keepdim=True)
        sign = centred > 0
        crossings = (sign != sign.roll(1, -1)).sum(-1)
        keep = keep & (crossings == 4) & (centred.abs().mean(-1) > 1e-3)
    return keep
