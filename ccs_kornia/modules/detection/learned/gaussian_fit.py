r"""Sub-pixel corner positions from a corner heatmap by Gaussian surface fitting (paper Sec. III-B).

The sub-pixel stage has three batched steps, each a function plus a thin ``nn.Module``:

1. :func:`~ccs_kornia.modules.detection.learned.peaks.heatmap_peaks` -- seeds: strict local maxima of the heatmap;
2. :func:`gaussian_fit` (here) -- the paper's Gaussian surface fit. Around every seed, a heatmap Gaussian
   :math:`I = A \exp(-\frac{(x-\mu_x)^2}{2\sigma_x^2} - \frac{(y-\mu_y)^2}{2\sigma_y^2})` satisfies
   :math:`\ln I = c_0 + c_1 x + c_2 y + c_3 x^2 + c_4 y^2`; multiplying each pixel's equation by :math:`I`
   (less weight on the noisy, low tails) gives the paper's linear system

   .. math::
       I_i \ln I_i = [I_i,\ I_i x_i,\ I_i y_i,\ I_i x_i^2,\ I_i y_i^2] \cdot c,

   solved in the least-squares sense for all peaks at once, then
   :math:`\mu_x = -c_1 / (2 c_3)`, :math:`\sigma_x = \sqrt{-1 / (2 c_3)}` (same for ``y`` with :math:`c_2, c_4`);
3. :func:`~ccs_kornia.modules.detection.learned.sigma_rejection.sigma_outlier_rejection` -- peaks whose fitted sigma
   differs from the training sigma are dropped.

Coordinates follow the project convention: the centre of the top-left pixel is ``(0, 0)``, ``x`` is the column,
``y`` the row. Variable peak counts are padded to ``M`` with a boolean mask.
"""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.modules.detection.learned.peaks import (
    check_heatmap,
    check_odd_window,
    gather_windows,
)
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["GaussianFit", "gaussian_fit"]


def _window_offsets(window: int, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Row-major offsets ``(dx, dy)`` of a ``window x window`` patch relative to its centre, each ``(K*K,)``."""
    radius = window // 2
    steps = torch.arange(-radius, radius + 1, device=device, dtype=dtype)
    dy, dx = torch.meshgrid(steps, steps, indexing="ij")
    return dx.reshape(-1), dy.reshape(-1)


def gaussian_fit(
    heatmap: torch.Tensor,
    seeds: torch.Tensor,
    mask: torch.Tensor | None = None,
    window: int = 7,
    eps: float = 1e-6,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Fit a 2-D axis-aligned Gaussian around every seed: the paper's weighted log-space least squares, batched.

    For each seed, the ``window x window`` patch centred on the rounded seed gives one equation per pixel,
    :math:`I_i \ln I_i = [I_i, I_i x_i, I_i y_i, I_i x_i^2, I_i y_i^2] \cdot c` with :math:`(x_i, y_i)` relative to
    the patch centre (for conditioning). All ``B*M`` systems are solved at once through their ``5x5`` normal
    equations in float64. Pixels with :math:`I \le` ``eps`` (and pixels outside the image) get zero weight,
    which also keeps the logarithm finite. The result is exact for a noise-free Gaussian of any amplitude.

    A fit is not ``ok`` when the seed is masked out or outside the image, fewer than 6 pixels are usable, the
    system is singular, a quadratic coefficient is not negative (no peak: a saddle, valley or flat patch; a
    sigma above ``10 * window`` counts as flat, which catches rounding noise around zero), or the fitted centre
    lies outside the window. Such slots return ``mu = seed`` and ``sigma = 0``.

    Differentiable with respect to ``heatmap`` (the rounding of the seeds picks the window only).

    Args:
        heatmap: corner heatmap :math:`(B, 1, H, W)`.
        seeds: approximate centres :math:`(B, M, 2)` ``(x, y)``, e.g. from :func:`heatmap_peaks`.
        mask: :math:`(B, M)` bool, which seeds to fit; ``None`` fits all.
        window: odd patch size; about ``4 * sigma`` covers the informative part of a blob.
        eps: heatmap values at or below this are ignored.

    Returns:
        - mu :math:`(B, M, 2)` sub-pixel centres ``(x, y)``,
        - sigma :math:`(B, M, 2)` standard deviations ``(sigma_x, sigma_y)`` in pixels,
        - ok :math:`(B, M)` bool, ``mask`` and a well-posed fit.

    Example:
        >>> ys, xs = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
        >>> heat = torch.exp(-((xs - 12.3) ** 2 + (ys - 20.6) ** 2) / (2 * 1.5**2))[None, None]
        >>> mu, sigma, ok = gaussian_fit(heat, torch.tensor([[[12.0, 21.0]]]))
        >>> mu.round(decimals=4), sigma.round(decimals=4), ok
        (tensor([[[12.3000, 20.6000]]]), tensor([[[1.5000, 1.5000]]]), tensor([[True]]))
    """
    check_heatmap(heatmap)
    check_odd_window(window)
    check_tensor(seeds, "seeds", ["B", "M", "2"], B=heatmap.shape[0])
    if mask is None:
        mask = torch.ones(seeds.shape[:2], dtype=torch.bool, device=seeds.device)
    check_tensor(mask, "mask", seeds.shape[:2])
    batch, _, height, width = heatmap.shape
    num = seeds.shape[1]
    radius = window // 2
    out_dtype = heatmap.dtype
    k = int(mask.sum(1).max()) if batch and num else 0
    if k < num:
        # only the seeds asked for are fitted, each image's first (peak finders pad to a fixed count of which a
        # few dozen are above threshold: 16 renders of 640x480, 512 seeds, at most 92 masked in); the others
        # come back as unfitted slots
        order = torch.argsort((~mask.bool()).to(torch.int8), dim=1, stable=True)[:, :k]
        pick = order[..., None].expand(-1, -1, 2)
        mu_k, sigma_k, ok_k = gaussian_fit(heatmap, seeds.gather(1, pick), mask.gather(1, order), window, eps)
        mu = seeds.to(out_dtype).scatter(1, pick, mu_k)
        sigma = torch.zeros_like(mu).scatter(1, pick, sigma_k)
        return mu, sigma, torch.zeros_like(mask, dtype=torch.bool).scatter(1, order, ok_k)

    with torch.no_grad():
        finite = torch.isfinite(seeds).all(-1)
        centres_f = torch.where(finite[..., None], seeds, torch.zeros_like(seeds)).round()
        inside = (
            (centres_f[..., 0] >= 0)
            & (centres_f[..., 0] <= width - 1)
            & (centres_f[..., 1] >= 0)
            & (centres_f[..., 1] <= height - 1)
        )
        ok = mask.bool() & finite & inside
        centres = torch.where(ok[..., None], centres_f, torch.zeros_like(centres_f)).long()

    patches = gather_windows(heatmap, centres, window).reshape(batch * num, window * window).double()
    usable = patches > eps
    intensity = torch.where(usable, patches, torch.zeros_like(patches))
    log_intensity = torch.log(torch.where(usable, patches, torch.ones_like(patches)))
    dx, dy = _window_offsets(window, heatmap.device, torch.float64)
    basis = torch.stack([torch.ones_like(dx), dx, dy, dx * dx, dy * dy], dim=-1)  # (K*K, 5)
    design = intensity[..., None] * basis  # (B*M, K*K, 5): rows [I, I x, I y, I x^2, I y^2]
    rhs = intensity * log_intensity  # (B*M, K*K): I ln I

    normal = design.transpose(-1, -2) @ design  # (B*M, 5, 5)
    moment = (design.transpose(-1, -2) @ rhs[..., None]).squeeze(-1)  # (B*M, 5)
    ok = ok.reshape(-1) & (usable.sum(-1) >= 6)
    identity = torch.eye(5, dtype=normal.dtype, device=normal.device).expand_as(normal)
    normal = torch.where(ok[:, None, None], normal, identity)  # keep the batched solve well posed everywhere
    coeffs, info = torch.linalg.solve_ex(normal, moment)
    ok = ok & (info == 0) & torch.isfinite(coeffs).all(-1)

    quad = coeffs[:, 3:5]  # (c3, c4) = -1 / (2 sigma^2), must be negative for a peak
    flat_limit = -0.5 / (10.0 * window) ** 2  # sigma > 10 * window: a flat patch, not a peak
    ok = ok & (quad < flat_limit).all(-1)
    safe_quad = torch.where(ok[:, None], quad, -torch.ones_like(quad))
    offset = -coeffs[:, 1:3] / (2.0 * safe_quad)
    sigma = torch.sqrt(-0.5 / safe_quad)
    ok = ok & (offset.abs() <= radius).all(-1)

    ok = ok.reshape(batch, num)
    offset = offset.reshape(batch, num, 2)
    sigma = sigma.reshape(batch, num, 2)
    mu = torch.where(ok[..., None], centres.double() + offset, seeds.double())
    sigma = torch.where(ok[..., None], sigma, torch.zeros_like(sigma))
    return mu.to(out_dtype), sigma.to(out_dtype), ok


class GaussianFit(nn.Module):
    r"""Module form of :func:`gaussian_fit`: sub-pixel centre and sigma of the heatmap blob at every seed.

    Args:
        window: odd patch size of the fit.
        eps: heatmap values at or below this are ignored.

    Example:
        >>> heat = torch.rand(1, 1, 32, 32)
        >>> mu, sigma, ok = GaussianFit()(heat, torch.tensor([[[10.0, 12.0]]]))
        >>> mu.shape, sigma.shape, ok.shape
        (torch.Size([1, 1, 2]), torch.Size([1, 1, 2]), torch.Size([1, 1]))
    """

    def __init__(self, window: int = 7, eps: float = 1e-6) -> None:
        super().__init__()
        check_odd_window(window)
        self.window = window
        self.eps = eps

    def forward(
        self, heatmap: torch.Tensor, seeds: torch.Tensor, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return gaussian_fit(heatmap, seeds, mask, self.window, self.eps)

    def extra_repr(self) -> str:
        return f"window={self.window}, eps={self.eps}"
