r"""Sub-pixel corner positions from a corner heatmap (paper Sec. III-B, "sub-pixel refinement with outlier rejection").

Three batched stages, each a function plus a thin ``nn.Module``:

1. :func:`heatmap_peaks` -- seeds: strict local maxima (kornia ``nms2d``) above a threshold, the ``max_peaks``
   strongest per image, each moved to the weighted mean of the heatmap in a small window around it (kornia
   ``spatial_expectation2d``).
2. :func:`gaussian_fit` -- the paper's Gaussian surface fit. Around every seed, a heatmap Gaussian
   :math:`I = A \exp(-\frac{(x-\mu_x)^2}{2\sigma_x^2} - \frac{(y-\mu_y)^2}{2\sigma_y^2})` satisfies
   :math:`\ln I = c_0 + c_1 x + c_2 y + c_3 x^2 + c_4 y^2`; multiplying each pixel's equation by :math:`I`
   (less weight on the noisy, low tails) gives the paper's linear system

   .. math::
       I_i \ln I_i = [I_i,\ I_i x_i,\ I_i y_i,\ I_i x_i^2,\ I_i y_i^2] \cdot c,

   solved in the least-squares sense for all peaks at once, then
   :math:`\mu_x = -c_1 / (2 c_3)`, :math:`\sigma_x = \sqrt{-1 / (2 c_3)}` (same for ``y`` with :math:`c_2, c_4`).
3. :func:`sigma_outlier_rejection` -- the network is trained to draw every corner with the same sigma, so a blob
   whose fitted sigma differs from it is an unreliable detection and is dropped.

Coordinates follow the project convention: the centre of the top-left pixel is ``(0, 0)``, ``x`` is the column,
``y`` the row. Variable peak counts are padded to ``M`` with a boolean mask.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from kornia.geometry.subpix import nms2d, spatial_expectation2d
from torch import nn

__all__ = [
    "heatmap_peaks",
    "gaussian_fit",
    "sigma_outlier_rejection",
    "HeatmapPeaks",
    "GaussianFit",
    "SigmaOutlierRejection",
]


def _check_heatmap(heatmap: torch.Tensor) -> None:
    if not isinstance(heatmap, torch.Tensor):
        raise TypeError(f"heatmap must be a torch.Tensor, got {type(heatmap)}.")
    if heatmap.ndim != 4 or heatmap.shape[1] != 1:
        raise ValueError(f"Expected heatmap of shape (B, 1, H, W), got {tuple(heatmap.shape)}.")
    if not heatmap.is_floating_point():
        raise ValueError(f"heatmap must be a floating point tensor, got {heatmap.dtype}.")


def _check_window(window: int, name: str = "window") -> None:
    if not isinstance(window, int) or window < 3 or window % 2 == 0:
        raise ValueError(f"{name} must be an odd integer >= 3, got {window!r}.")


def _window_offsets(window: int, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Row-major offsets ``(dx, dy)`` of a ``window x window`` patch relative to its centre, each ``(K*K,)``."""
    radius = window // 2
    steps = torch.arange(-radius, radius + 1, device=device, dtype=dtype)
    dy, dx = torch.meshgrid(steps, steps, indexing="ij")
    return dx.reshape(-1), dy.reshape(-1)


def _gather_windows(heatmap: torch.Tensor, centres: torch.Tensor, window: int) -> torch.Tensor:
    """``window x window`` patches of ``heatmap`` (B,1,H,W) centred on integer ``centres`` (B,M,2) xy.

    Pixels outside the image read as ``0``, so a peak near the border keeps its in-image pixels only. Centres
    must lie inside the image. Differentiable with respect to ``heatmap``.

    Returns:
        patches of shape (B, M, window, window).
    """
    batch, _, height, width = heatmap.shape
    num = centres.shape[1]
    radius = window // 2
    padded = F.pad(heatmap[:, 0], (radius, radius, radius, radius))  # (B, H+2r, W+2r), zeros outside
    padded_width = width + 2 * radius
    steps = torch.arange(window, device=heatmap.device)
    rows = centres[..., 1, None, None] + steps[:, None]  # (B, M, K, 1): row in padded = y - r + k + r
    cols = centres[..., 0, None, None] + steps[None, :]  # (B, M, 1, K)
    index = (rows * padded_width + cols).reshape(batch, num * window * window)
    patches = padded.reshape(batch, -1).gather(1, index)
    return patches.reshape(batch, num, window, window)


def heatmap_peaks(
    heatmap: torch.Tensor,
    threshold: float = 0.3,
    max_peaks: int = 256,
    nms_kernel: int = 5,
    refine_window: int = 5,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Seed points: the strongest local maxima of a corner heatmap, refined to sub-pixel by a local weighted mean.

    A pixel is a peak when it is strictly greater than every other pixel in its ``nms_kernel`` window (kornia
    ``nms2d``; the map is padded with ``-inf`` so corners near the border can be peaks too) and greater than
    ``threshold``. The ``max_peaks`` highest peaks are kept, sorted by score. Each seed is then the heatmap-weighted
    mean position (kornia ``spatial_expectation2d``) in the ``refine_window`` around the peak pixel. That mean is
    pulled towards the peak pixel (the window truncates the blob): for sigma 1.5 seeds are within 0.25 px with the
    default 5x5 window (0.5 px with 3x3); :func:`gaussian_fit` gives the precise position.

    Args:
        heatmap: corner heatmap :math:`(B, 1, H, W)`.
        threshold: minimum heatmap value of a peak.
        max_peaks: ``M``, the number of slots per image (unused slots have ``mask == False``).
        nms_kernel: odd size of the non-maximum-suppression window; keep it below the corner spacing in pixels.
        refine_window: odd size of the window of the weighted mean.

    Returns:
        - seeds :math:`(B, M, 2)` sub-pixel ``(x, y)`` (``0`` where masked out),
        - scores :math:`(B, M)` heatmap value at the peak pixel (``0`` where masked out),
        - mask :math:`(B, M)` bool, ``True`` for real peaks; real peaks come first, by decreasing score.

    Example:
        >>> heat = torch.zeros(1, 1, 32, 32)
        >>> heat[0, 0, 10, 20] = 1.0
        >>> seeds, scores, mask = heatmap_peaks(heat, max_peaks=4)
        >>> seeds[0, 0], mask[0]
        (tensor([20., 10.]), tensor([ True, False, False, False]))
    """
    _check_heatmap(heatmap)
    _check_window(nms_kernel, "nms_kernel")
    _check_window(refine_window, "refine_window")
    if not isinstance(max_peaks, int) or max_peaks < 1:
        raise ValueError(f"max_peaks must be a positive integer, got {max_peaks!r}.")
    batch, _, height, width = heatmap.shape
    radius = nms_kernel // 2
    with torch.no_grad():
        padded = F.pad(heatmap, (radius, radius, radius, radius), value=float("-inf"))
        is_peak = nms2d(padded, (nms_kernel, nms_kernel), mask_only=True)[..., radius:-radius, radius:-radius]
        candidates = is_peak & (heatmap > threshold)
        flat = torch.where(candidates, heatmap, torch.full_like(heatmap, float("-inf"))).reshape(batch, -1)
        k = min(max_peaks, height * width)
        top_values, top_index = flat.topk(k, dim=1)
        mask = torch.isfinite(top_values)
        if k < max_peaks:  # fewer pixels than slots: pad to the fixed size M
            top_values = F.pad(top_values, (0, max_peaks - k))
            top_index = F.pad(top_index, (0, max_peaks - k))
            mask = F.pad(mask, (0, max_peaks - k), value=False)
        top_index = torch.where(mask, top_index, torch.zeros_like(top_index))
        centres = torch.stack([top_index % width, top_index // width], dim=-1)  # (B, M, 2) integer xy

    patches = _gather_windows(heatmap, centres, refine_window).clamp_min(0)  # (B, M, K, K)
    total = patches.sum(dim=(-2, -1), keepdim=True)
    weights = patches / total.clamp_min(torch.finfo(heatmap.dtype).tiny)
    local = spatial_expectation2d(weights, normalized_coordinates=False)  # (B, M, 2) in patch coordinates
    seeds = centres.to(heatmap.dtype) + local - refine_window // 2
    seeds = torch.where(mask[..., None], seeds, torch.zeros_like(seeds))
    scores = torch.where(mask, top_values, torch.zeros_like(top_values)).to(heatmap.dtype)
    return seeds, scores, mask


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
    _check_heatmap(heatmap)
    _check_window(window)
    if seeds.ndim != 3 or seeds.shape[0] != heatmap.shape[0] or seeds.shape[-1] != 2:
        raise ValueError(f"Expected seeds of shape (B, M, 2) with B={heatmap.shape[0]}, got {tuple(seeds.shape)}.")
    if mask is None:
        mask = torch.ones(seeds.shape[:2], dtype=torch.bool, device=seeds.device)
    if mask.shape != seeds.shape[:2]:
        raise ValueError(f"Expected mask of shape {tuple(seeds.shape[:2])}, got {tuple(mask.shape)}.")
    batch, _, height, width = heatmap.shape
    num = seeds.shape[1]
    radius = window // 2
    out_dtype = heatmap.dtype

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

    patches = _gather_windows(heatmap, centres, window).reshape(batch * num, window * window).double()
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


def sigma_outlier_rejection(
    sigma: torch.Tensor,
    mask: torch.Tensor,
    expected_sigma: float | torch.Tensor,
    tolerance: float = 0.5,
) -> torch.Tensor:
    r"""Distribution-aware outlier rejection: drop peaks whose fitted sigma is not the training sigma.

    A peak is kept when ``mask`` is set and both :math:`|\sigma_x - \sigma^*| \le \text{tol}\,\sigma^*` and
    :math:`|\sigma_y - \sigma^*| \le \text{tol}\,\sigma^*` (non-finite sigmas are rejected).

    Args:
        sigma: fitted standard deviations :math:`(B, M, 2)` from :func:`gaussian_fit`.
        mask: :math:`(B, M)` bool, peaks to consider (typically ``mask & ok``).
        expected_sigma: the sigma of the training targets, a positive float or a tensor broadcastable to
            :math:`(B, M, 2)` (e.g. per axis ``(2,)`` or per image ``(B, 1, 1)``).
        tolerance: allowed relative deviation.

    Returns:
        :math:`(B, M)` bool mask of the kept peaks.

    Example:
        >>> sigma = torch.tensor([[[1.5, 1.4], [3.5, 1.5], [1.5, 1.5]]])
        >>> sigma_outlier_rejection(sigma, torch.tensor([[True, True, False]]), 1.5, 0.5)
        tensor([[ True, False, False]])
    """
    if sigma.ndim != 3 or sigma.shape[-1] != 2:
        raise ValueError(f"Expected sigma of shape (B, M, 2), got {tuple(sigma.shape)}.")
    if mask.shape != sigma.shape[:2]:
        raise ValueError(f"Expected mask of shape {tuple(sigma.shape[:2])}, got {tuple(mask.shape)}.")
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}.")
    expected = torch.as_tensor(expected_sigma, dtype=sigma.dtype, device=sigma.device)
    if not bool((expected > 0).all()):
        raise ValueError(f"expected_sigma must be positive, got {expected_sigma!r}.")
    try:
        deviation = (sigma - expected).abs() / expected
        deviation = torch.broadcast_to(deviation, sigma.shape)
    except RuntimeError as err:
        raise ValueError(
            f"expected_sigma of shape {tuple(expected.shape)} does not broadcast to sigma {tuple(sigma.shape)}."
        ) from err
    within = (deviation <= tolerance) & torch.isfinite(sigma)
    return mask.bool() & within.all(-1)


class HeatmapPeaks(nn.Module):
    r"""Module form of :func:`heatmap_peaks`: seeds, scores and mask from a corner heatmap.

    Args:
        threshold: minimum heatmap value of a peak.
        max_peaks: number of slots ``M`` per image.
        nms_kernel: odd non-maximum-suppression window.
        refine_window: odd window of the local weighted mean.

    Example:
        >>> seeds, scores, mask = HeatmapPeaks(max_peaks=8)(torch.rand(2, 1, 32, 32))
        >>> seeds.shape, scores.shape, mask.shape
        (torch.Size([2, 8, 2]), torch.Size([2, 8]), torch.Size([2, 8]))
    """

    def __init__(
        self, threshold: float = 0.3, max_peaks: int = 256, nms_kernel: int = 5, refine_window: int = 5
    ) -> None:
        super().__init__()
        _check_window(nms_kernel, "nms_kernel")
        _check_window(refine_window, "refine_window")
        self.threshold = threshold
        self.max_peaks = max_peaks
        self.nms_kernel = nms_kernel
        self.refine_window = refine_window

    def forward(self, heatmap: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return heatmap_peaks(heatmap, self.threshold, self.max_peaks, self.nms_kernel, self.refine_window)

    def extra_repr(self) -> str:
        return (
            f"threshold={self.threshold}, max_peaks={self.max_peaks}, nms_kernel={self.nms_kernel}, "
            f"refine_window={self.refine_window}"
        )


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
        _check_window(window)
        self.window = window
        self.eps = eps

    def forward(
        self, heatmap: torch.Tensor, seeds: torch.Tensor, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return gaussian_fit(heatmap, seeds, mask, self.window, self.eps)

    def extra_repr(self) -> str:
        return f"window={self.window}, eps={self.eps}"


class SigmaOutlierRejection(nn.Module):
    r"""Module form of :func:`sigma_outlier_rejection`.

    Args:
        expected_sigma: sigma of the training heatmaps (pixels).
        tolerance: allowed relative deviation of each fitted sigma.

    Example:
        >>> reject = SigmaOutlierRejection(expected_sigma=1.5, tolerance=0.5)
        >>> reject(torch.tensor([[[1.6, 1.4], [0.5, 1.5]]]), torch.tensor([[True, True]]))
        tensor([[ True, False]])
    """

    def __init__(self, expected_sigma: float = 1.5, tolerance: float = 0.5) -> None:
        super().__init__()
        if expected_sigma <= 0:
            raise ValueError(f"expected_sigma must be positive, got {expected_sigma}.")
        if tolerance < 0:
            raise ValueError(f"tolerance must be >= 0, got {tolerance}.")
        self.expected_sigma = float(expected_sigma)
        self.tolerance = float(tolerance)

    def forward(self, sigma: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return sigma_outlier_rejection(sigma, mask, self.expected_sigma, self.tolerance)

    def extra_repr(self) -> str:
        return f"expected_sigma={self.expected_sigma}, tolerance={self.tolerance}"
