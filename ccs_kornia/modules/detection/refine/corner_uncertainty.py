r"""Per-corner precision of detected chessboard corners, and the solver weights it gives.

A refined corner is the centre of point symmetry of its window (:mod:`~ccs_kornia.modules.detection.refine.symmetry_refine`):
``c`` minimises ``sum_d w(d) r(d)^2`` with ``r(d) = I(c + d) - I(c - d)``. The Gauss-Newton covariance of that fit,
``s^2 (J^T W J)^{-1}`` with ``J = grad I(c + d) - grad I(c - d)`` and ``s^2 = sum w r^2 / sum w``, is large where the
window has little contrast or edge length (shadows, blur, foreshortened squares) and where what is left is not point
symmetric (noise, glare, a mark beside the corner), which is where corners are less precise.

:func:`corner_uncertainty` returns its standard deviation per corner, :math:`\sqrt{\operatorname{tr}/2}`. The value is
relative: the residuals of the smoothed image are correlated, so it is smaller than the actual error, but it ranks
corners by it (``docs/measurements.md``).

:func:`corner_weights` turns it into the solver's inverse variances, relative to the camera's median corner and clipped
to ``[1 / clip, clip]``. On held-out renders the weights lower the calibration's E_IP and its spread in clean, badly
lit and combined conditions, and leave blur + noise unchanged (``docs/measurements.md``).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ccs_kornia.modules.detection.base import measured_corners
from ccs_kornia.modules.detection.grid.grid_geometry import grid_spacing
from ccs_kornia.modules.detection.refine.saddle_refine import (
    saddle_source,
    sample_window,
    weighted_window,
)
from ccs_kornia.modules.detection.refine.symmetry_refine import symmetry_terms
from ccs_kornia.runtime.checks import (
    check_grey_images,
    check_points,
    check_same_shape,
    check_tensor,
)
from ccs_kornia.runtime.timing import stage

__all__ = ["corner_sigma", "corner_uncertainty", "corner_weights", "CornerUncertainty"]


def corner_uncertainty(
    images: torch.Tensor,
    corners: torch.Tensor,
    valid: torch.Tensor,
    board_size: tuple[int, int],
    radius_factor: float = 0.3,
    smooth_sigma: float = 1.0,
    max_radius: int = 18,
) -> torch.Tensor:
    r"""Standard deviation (px, relative) of each corner's point-symmetry fit on the image.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        corners: :math:`(B, N, 2)` refined corners in grid order, ``N = cols * rows``.
        valid: :math:`(B, N)` bool, the corners to judge (e.g. every corner of a found board).
        board_size: ``(cols, rows)``.
        radius_factor: window radius in grid spacings (clamped to ``[1.5, max_radius]`` px).
        smooth_sigma: Gaussian smoothing of the image (px), as the refinement's.
        max_radius: largest window radius (px).

    Returns:
        :math:`(B, N)` float32 standard deviations; NaN where not ``valid`` or where the window is degenerate.

    Example:
        >>> yy, xx = torch.meshgrid(torch.arange(48), torch.arange(48), indexing="ij")
        >>> img = ((xx // 12 + yy // 12) % 2).float()[None, None]  # corners at 11.5, 23.5, 35.5
        >>> g = torch.arange(3) * 12.0 + 11.5
        >>> pts = torch.stack(torch.meshgrid(g, g, indexing="xy"), -1).reshape(1, 9, 2)
        >>> ok = torch.ones(1, 9, dtype=torch.bool)
        >>> noisy = img + 0.05 * torch.randn(img.shape, generator=torch.Generator().manual_seed(0))
        >>> clean, rough = corner_uncertainty(img, pts, ok, (3, 3)), corner_uncertainty(noisy, pts, ok, (3, 3))
        >>> bool((clean < 1e-4).all()), bool((rough > 10 * clean).all())
        (True, True)
    """
    check_grey_images(images, min_side=0)
    check_points(corners, "corners", B=images.shape[0])
    check_tensor(valid, "valid", corners.shape[:2])
    b, n = corners.shape[:2]
    out = torch.full((b, n), float("nan"), dtype=torch.float32, device=corners.device)
    pts = corners.float()
    radius = (radius_factor * grid_spacing(pts, valid.bool(), board_size)).clamp(1.5, float(max_radius))
    sel = valid.bool() & pts.isfinite().all(-1) & radius.isfinite()
    if not bool(sel.any()):
        return out
    bi, ni = sel.nonzero(as_tuple=True)
    c, r = pts[bi, ni].to(images.device), radius[bi, ni].to(images.device)
    rmax = int(math.ceil(float(r.max())))
    # one region per corner, smoothed there only (bounded cost on 24 Mpx photos): a window of rmax + 1 around the
    # corner's pixel, plus its bilinear neighbour
    q = 2 * rmax + 4
    top_left = torch.floor(c).long() - (rmax + 1)
    src = saddle_source(images.float(), bi.to(images.device), top_left, q, smooth_sigma, 0.0)
    local = c - top_left.to(c.dtype)
    half = (2 * rmax + 1) ** 2 // 2
    odd = symmetry_terms(src, local, rmax, sample_window)  # twice J_x, twice J_y, r
    w = weighted_window(r, rmax)[1][:, :half]
    jx, jy, res = 0.5 * odd[:, 0], 0.5 * odd[:, 1], odd[:, 2]
    # the full window's normal matrix is twice the half's; s^2 is a ratio of the two halves' sums
    axx, axy, ayy = 2 * (w * jx * jx).sum(-1), 2 * (w * jx * jy).sum(-1), 2 * (w * jy * jy).sum(-1)
    s2 = (w * res * res).sum(-1) / w.sum(-1).clamp_min(1e-12)
    det = axx * ayy - axy * axy
    good = det > 1e-12 * (axx + ayy).square().clamp_min(1e-30)
    var = s2 * (axx + ayy) / torch.where(good, det, torch.ones_like(det)) / 2
    out[bi, ni] = torch.where(good, var.clamp_min(0).sqrt(), torch.full_like(var, float("nan"))).to(out.device)
    return out


def corner_sigma(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int],
                 found: torch.Tensor | None = None) -> torch.Tensor:
    """Per-corner precision :math:`(B, N)` of boards :math:`(B, N, 2)` on ``images`` :math:`(B, 1, H, W)`: the
    :func:`corner_uncertainty` of their measured corners (NaN where ``found`` :math:`(B,)` is false, and at a partial
    board's hidden corners), on the corners' device; what the pipeline measures of every board it finds.

    Example:
        >>> corners = 8.0 + 10.0 * torch.stack(torch.meshgrid(torch.arange(4.0), torch.arange(3.0), indexing="xy"), -1)
        >>> sigma = corner_sigma(torch.rand(1, 1, 48, 64), corners.reshape(1, 12, 2), (4, 3), torch.tensor([False]))
        >>> sigma.shape, bool(sigma.isnan().all())
        (torch.Size([1, 12]), True)
    """
    found = torch.ones(corners.shape[0], dtype=torch.bool, device=corners.device) if found is None else found
    with stage("corner uncertainty"):
        return corner_uncertainty(images.float(), corners.float(), measured_corners(corners, found),
                                  board_size).to(corners.device)


def corner_weights(sigma: torch.Tensor, valid: torch.Tensor, clip: float = 10.0) -> torch.Tensor:
    r"""Solver weights (inverse variances) from per-corner standard deviations, relative to the camera's median.

    ``w = (median / sigma)^2`` over the valid corners of each camera (the last three dimensions being views, corners,
    or just corners for one view), clipped to ``[1 / clip, clip]`` (one corner never dominates, none is silenced); 1
    where ``sigma`` is unknown (NaN), 0 where not ``valid``.

    Args:
        sigma: :math:`(..., V, N)` standard deviations (e.g. :func:`corner_uncertainty`), NaN where unknown.
        valid: matching bool mask.
        clip: largest ratio of a weight to the median weight (1: all weights equal).

    Returns:
        Weights of the shape of ``sigma``, float64.

    Example:
        >>> s = torch.tensor([[[0.01, 0.02, float("nan"), 0.001]]])
        >>> corner_weights(s, torch.ones(1, 1, 4, dtype=torch.bool), clip=10.0)
        tensor([[[ 1.0000,  0.2500,  1.0000, 10.0000]]], dtype=torch.float64)
    """
    check_same_shape(sigma, "sigma", valid, "valid")
    if not clip >= 1:
        raise ValueError(f"clip must be at least 1, got {clip}.")
    s = sigma.double()
    known = valid.bool() & s.isfinite() & (s > 0)
    lead = s.shape[:-2] if s.dim() >= 2 else ()
    flat_s = s.reshape(*lead, -1)
    flat_k = known.reshape(*lead, -1)
    median = torch.where(flat_k, flat_s, torch.full_like(flat_s, float("nan"))).nanmedian(-1).values
    median = median.reshape(*lead, *([1] * min(2, s.dim())))
    w = (median / s).square().clamp(1.0 / clip, clip)
    w = torch.where(known, w, torch.ones_like(w))
    return torch.where(valid.bool(), w.nan_to_num(1.0), torch.zeros_like(w))


class CornerUncertainty(nn.Module):
    """Module form of :func:`corner_uncertainty` (options fixed at construction).

    Example:
        >>> CornerUncertainty(radius_factor=0.3).radius_factor
        0.3
    """

    def __init__(self, radius_factor: float = 0.3, smooth_sigma: float = 1.0, max_radius: int = 18) -> None:
        super().__init__()
        self.radius_factor, self.smooth_sigma, self.max_radius = radius_factor, smooth_sigma, max_radius

    def forward(self, images: torch.Tensor, corners: torch.Tensor, valid: torch.Tensor,
                board_size: tuple[int, int]) -> torch.Tensor:
        return corner_uncertainty(images, corners, valid, board_size, self.radius_factor, self.smooth_sigma,
                                  self.max_radius)
