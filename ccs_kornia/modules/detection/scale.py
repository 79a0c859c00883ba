r"""Scale selection for the learned chessboard detector: detect on the pyramid level where the squares have the size
the heatmap network was trained on, refine at full resolution.

The heatmap network (:class:`~ccs_kornia.modules.heatmap_unet.CornerUNet`) was trained on squares of about 6 to 17 px
(median 10 px) with sharp edges. Squares of 100 px with an 11 px blur look nothing like that; their 8x area-downscaled
copy does (area downscaling shrinks the squares and the blur alike). Three batched steps:

1. :func:`estimate_square_size`: the board's square size in px, from the image itself. A chessboard corner is a saddle
   of the intensity; the :math:`\gamma`-normalised saddle strength :math:`\sigma^\gamma \sqrt{-\det H_\sigma}` (Hessian
   of the image smoothed at scale :math:`\sigma`) grows with :math:`\sigma` on an isolated X-junction and dies once
   the smoothing reaches the neighbouring corners of opposite sign. On a checker of square :math:`s` it peaks at
   :math:`\sigma^* = \sqrt{\gamma / 2}\, s / \pi`, whatever the blur below that scale. Per image, the scale whose
   strongest saddles (mean of the ``num_peaks`` largest local maxima) are strongest gives the square size. Computed on
   a pyramid (each octave on a 2x area-downscaled image), so its cost is that of a few blurs of a quarter of the
   image.
2. :func:`detection_factor`: the area-downscale factor that brings that square size to ``target_square`` px (in
   quarter-octave steps, so images of one camera share a level and stay batched), never below 1 (no upsampling) and
   large enough that the level has at most ``max_pixels`` pixels (bounded memory and time on 24 Mpx photographs).
3. :func:`detect_at_scale`: run a detector on each level (images grouped by factor), map the corners back to the
   full-resolution pixel grid and refine them there on small patches (:func:`refine_on_patches`, the saddle refiner
   with its window set by the full-resolution grid spacing). Boards missed at the chosen level are looked for at
   the neighbouring levels (``fallback``).

:class:`ScaleSelector` wraps steps 1-2 as a module.
"""

from __future__ import annotations

import math
from typing import Callable

import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d
from torch import nn

from ccs_kornia.modules.corner_refine import grid_spacing, refine_corners

__all__ = [
    "saddle_scale_response",
    "estimate_square_size",
    "detection_factor",
    "resize_to_level",
    "refine_on_patches",
    "edge_blur",
    "refine_from_level",
    "detect_at_scale",
    "ScaleSelector",
    "PEAK_RATIO",
    "level_size",
]

#: sigma* / square where the saddle response (gamma = 3, edge penalty 2) peaks, measured on rendered boards under
#: perspective and blur (median over 96 renders of 8-300 px squares; an ideal sinusoidal checker gives 0.39)
PEAK_RATIO = 0.365


def _check_images(images: torch.Tensor) -> None:
    if not isinstance(images, torch.Tensor) or images.dim() != 4 or images.shape[1] != 1:
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"Expected grey images (B, 1, H, W), got {shape}.")
    if min(images.shape[-2:]) < 8:
        raise ValueError(f"Images must be at least 8x8 px, got {tuple(images.shape[-2:])}.")


def _sigmas(min_sigma: float, max_sigma: float, steps_per_octave: int) -> torch.Tensor:
    n = max(1, int(math.floor(steps_per_octave * math.log2(max_sigma / min_sigma))) + 1)
    return min_sigma * 2.0 ** (torch.arange(n, dtype=torch.float64) / steps_per_octave)


def _blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    k = 2 * int(math.ceil(3 * sigma)) + 1
    k = min(k, 2 * ((min(x.shape[-2:]) - 1) // 2) - 1)
    return gaussian_blur2d(x, (k, k), (sigma, sigma), border_type="reflect", separable=True) if k >= 3 else x


def saddle_scale_response(
    images: torch.Tensor,
    sigmas: torch.Tensor,
    gamma: float = 3.0,
    num_peaks: int = 16,
    base_sigma: float = 1.5,
    edge_penalty: float = 2.0,
) -> torch.Tensor:
    r"""Strength of the strongest X-junction saddles of each image at each scale, :math:`(B, S)`.

    A Gaussian scale space built incrementally on a pyramid (as SIFT's): each scale :math:`\sigma` (px of
    ``images``) is reached by a small extra blur of the previous one, and an octave is halved (2x2 mean) once its
    blur reaches ``2 base_sigma`` of its own px. At each scale the saddle strength
    :math:`\sigma^2 \sqrt{\max(0, f_{xy}^2 - f_{xx} f_{yy})} - \text{edge\_penalty}\, \sigma |\nabla f|`
    (an X-junction has no gradient at its centre; the L- and T-junctions of clutter do), clamped at 0 and scaled by
    :math:`\sigma^{\gamma - 2}` (full-resolution units), is max-pooled over blocks of about :math:`\sigma` and the
    mean of its ``num_peaks`` largest values is returned.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        sigmas: :math:`(S,)` increasing scales in px.
        gamma: scale normalisation exponent (3: on a checker of square ``s`` the response peaks near
            :math:`0.37 s`).
        num_peaks: strongest saddles averaged per image and scale.
        base_sigma: smallest blur of an octave, in its own px (finite differences are accurate above ~1.5 px).
        edge_penalty: weight of the gradient penalty.

    Returns:
        :math:`(B, S)` float32 responses (0 for scales too large for the image).

    Example:
        >>> from ccs_kornia.data.synthetic import make_calibration_set
        >>> K = torch.tensor([[800., 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=0, supersample=1)
        >>> r = saddle_scale_response(views.images, torch.tensor([2.0, 4.0, 8.0, 16.0]))  # squares ~15 px
        >>> r.shape, r.argmax(-1).tolist()  # strongest at sigma ~0.37 x 15 px
        (torch.Size([2, 4]), [1, 1])
    """
    _check_images(images)
    b = images.shape[0]
    sig = torch.as_tensor(sigmas, dtype=torch.float64).flatten()
    if sig.numel() == 0 or not bool((sig[1:] > sig[:-1]).all()) or not float(sig[0]) > 0:
        raise ValueError("sigmas must be positive and increasing.")
    out = torch.zeros(b, sig.numel(), dtype=torch.float32, device=images.device)
    level = images.float()
    step = 1.0
    # skip the octaves below the first scale on the raw image (no blur needed to decimate an unblurred image
    # whose next blur is at least twice the decimation's)
    while float(sig[0]) / step >= 2 * base_sigma and min(level.shape[-2:]) >= 32:
        level = F.avg_pool2d(level, 2)
        step *= 2
    blur = 0.0  # blur of ``level`` in its own px (the image's own blur is ignored)
    for k in range(sig.numel()):
        s = float(sig[k]) / step
        while s >= 2 * base_sigma and min(level.shape[-2:]) >= 32:
            level = F.avg_pool2d(level, 2)
            step *= 2
            blur, s = blur / 2, s / 2
        if 6 * s + 3 >= min(level.shape[-2:]):
            break
        extra = math.sqrt(max(s * s - blur * blur, 0.0))
        if extra > 0.3:
            level = _blur(level, extra)
            blur = s
        # derivatives on every other pixel (the response of a blur >= 1.5 px is smooth; 4x cheaper)
        f = level[:, 0]
        c = f[:, 1:-1:2, 1:-1:2]
        right, left = f[:, 1:-1:2, 2::2], f[:, 1:-1:2, :-2:2]
        down, up = f[:, 2::2, 1:-1:2], f[:, :-2:2, 1:-1:2]
        fxx = right + left - 2 * c
        fyy = down + up - 2 * c
        fxy = 0.25 * (f[:, 2::2, 2::2] - f[:, 2::2, :-2:2] - f[:, :-2:2, 2::2] + f[:, :-2:2, :-2:2])
        gx, gy = 0.5 * (right - left), 0.5 * (down - up)
        sad = torch.sqrt((fxy * fxy - fxx * fyy).clamp_min_(0)).mul_(s * s)
        sad.sub_(torch.sqrt(gx * gx + gy * gy).mul_(edge_penalty * s)).clamp_min_(0)
        sad.mul_((s * step) ** (gamma - 2))
        # strongest response per block of about the scale: one value per saddle, far cheaper than a full-size
        # non-maximum suppression and top-k on large images
        blk = max(1, int(round(s / 2)))
        peaks = F.max_pool2d(sad[:, None], blk, blk, ceil_mode=True).reshape(b, -1)
        out[:, k] = peaks.topk(min(num_peaks, peaks.shape[-1]), dim=-1).values.mean(-1)
    return out


def estimate_square_size(
    images: torch.Tensor,
    min_square: float = 4.0,
    max_square: float | None = None,
    steps_per_octave: int = 4,
    num_peaks: int = 16,
    gamma: float = 3.0,
    base_sigma: float = 1.5,
    edge_penalty: float = 2.0,
    max_pixels: float = 1.0e6,
) -> torch.Tensor:
    r"""Square size of the chessboard in each image, in px, from the image alone :math:`(B,)`.

    The scale of the strongest :func:`saddle_scale_response` (refined by a parabola through the log-responses around
    it) divided by :math:`\sqrt{\gamma/2}/\pi`.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        min_square, max_square: searched range in px (default up to a third of the shorter image side).
        steps_per_octave: scales per octave.
        num_peaks: local maxima averaged per scale (about the number of corners that must agree).
        gamma: scale normalisation exponent.
        base_sigma, edge_penalty: of :func:`saddle_scale_response`.
        max_pixels: larger images are estimated on an area-downscaled copy of this many pixels.

    Returns:
        :math:`(B,)` float32 square sizes in px.

    Example:
        >>> from ccs_kornia.data.synthetic import make_calibration_set
        >>> K = torch.tensor([[800., 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=0, supersample=1)
        >>> estimate_square_size(views.images).round()  # true median squares: 14.1 and 15.2 px
        tensor([15., 15.])
    """
    _check_images(images)
    ratio = PEAK_RATIO * math.sqrt(gamma / 3.0)
    if max_square is None:
        max_square = min(images.shape[-2:]) / 3.0
    if not 0 < min_square < max_square:
        raise ValueError(f"Need 0 < min_square < max_square, got {min_square} and {max_square}.")
    h, w = images.shape[-2:]
    pre = max(1.0, math.sqrt(h * w / max_pixels))
    if pre > 1.0:
        # large images: estimated on an area-downscaled copy (squares below 4 px of it are not searched for)
        images = F.interpolate(images.float(), size=(max(8, round(h / pre)), max(8, round(w / pre))), mode="area")
        pre = math.sqrt(h * w / (images.shape[-2] * images.shape[-1]))
        min_square, max_square = max(4.0, min_square / pre), max_square / pre
        if min_square >= max_square:
            max_square = 2 * min_square
    sig = _sigmas(ratio * min_square, ratio * max_square, steps_per_octave)
    resp = saddle_scale_response(images, sig, gamma=gamma, num_peaks=num_peaks, base_sigma=base_sigma,
                                 edge_penalty=edge_penalty)
    log_r = resp.clamp_min(1e-12).log()
    k = log_r.argmax(-1)
    # sub-step refinement: parabola through the neighbouring log-responses
    km, kp = (k - 1).clamp_min(0), (k + 1).clamp_max(sig.numel() - 1)
    y0, ym, yp = (log_r.gather(1, i[:, None])[:, 0] for i in (k, km, kp))
    denom = ym - 2 * y0 + yp
    inner = (k > 0) & (k < sig.numel() - 1) & (denom < 0)
    delta = torch.where(inner, 0.5 * (ym - yp) / torch.where(inner, denom, torch.ones_like(denom)), torch.zeros_like(y0))
    log_sigma = sig.log().to(resp)[k] + delta.clamp(-0.5, 0.5) * math.log(2.0) / steps_per_octave
    return (log_sigma.exp() / ratio * pre).float()


def detection_factor(
    square_size: torch.Tensor,
    image_size: tuple[int, int],
    target_square: float = 12.0,
    max_pixels: float = 3.2e6,
    steps_per_octave: int = 4,
    min_factor: float = 1.0,
    upsample_square: float = 10.0,
) -> torch.Tensor:
    r"""Area-downscale factor per image that brings its squares to ``target_square`` px, :math:`(B,)`.

    The factor ``square_size / target_square`` is rounded to ``steps_per_octave`` steps per octave (images of similar
    square size share a level, so they stay batched), then raised to ``min_factor`` (1: never upsample) and to the
    smallest factor whose level has at most ``max_pixels`` pixels. Squares smaller than the target are upsampled only
    up to ``upsample_square`` px (upsampling costs time and adds no information: just enough for the network).

    Args:
        square_size: :math:`(B,)` square sizes in px (e.g. from :func:`estimate_square_size`).
        image_size: ``(W, H)`` of the full-resolution images.
        target_square: square size in px at which the detector works best.
        max_pixels: most pixels of a detection level (bounds the network's memory and time).
        steps_per_octave: quantisation of the factor.
        min_factor: smallest factor (``< 1`` allows upsampling of tiny squares).
        upsample_square: square size in px that upsampled squares are brought to.

    Returns:
        :math:`(B,)` float64 factors (full-resolution px per level px).

    Example:
        >>> detection_factor(torch.tensor([12.0, 50.0, 100.0]), (640, 480))
        tensor([1., 4., 8.], dtype=torch.float64)
    """
    if not target_square > 0 or not max_pixels > 0 or steps_per_octave < 1 or not min_factor > 0:
        raise ValueError("target_square, max_pixels, steps_per_octave and min_factor must be positive.")
    w, h = int(image_size[0]), int(image_size[1])
    sq = square_size.double().nan_to_num(target_square, posinf=target_square).clamp_min(1e-6)
    f = sq / target_square
    f = torch.where(f < 1, (sq / upsample_square).clamp_max(1.0), f)
    f = 2.0 ** (torch.round(torch.log2(f) * steps_per_octave) / steps_per_octave)
    floor = max(float(min_factor), math.sqrt(w * h / float(max_pixels)))
    # the memory floor is rounded up to the same grid so every factor is one of a few levels
    floor = 2.0 ** (math.ceil(math.log2(floor) * steps_per_octave - 1e-9) / steps_per_octave)
    return f.clamp_min(floor)


def level_size(image_size: tuple[int, int], factor: float) -> tuple[int, int]:
    """``(H, W)`` of the level of an image of size ``(W, H)`` at ``factor`` (at least 8 px a side)."""
    w, h = int(image_size[0]), int(image_size[1])
    return max(8, int(round(h / factor))), max(8, int(round(w / factor)))


def resize_to_level(images: torch.Tensor, factor: float) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The detection level of ``images`` and the px scale back to full resolution.

    Downscaling is area averaging (each level pixel is the mean of its footprint: anti-aliased, and it shrinks the
    blur with the squares); upscaling (``factor < 1``) is bilinear.

    Args:
        images: :math:`(B, 1, H, W)`.
        factor: full-resolution px per level px.

    Returns:
        level images :math:`(B, 1, h, w)` and ``(sx, sy)`` :math:`(2,)` with
        ``x_full + 0.5 = (x_level + 0.5) * (sx, sy)``.

    Example:
        >>> small, scale = resize_to_level(torch.rand(2, 1, 480, 640), 4.0)
        >>> small.shape, scale.tolist()
        (torch.Size([2, 1, 120, 160]), [4.0, 4.0])
    """
    _check_images(images)
    h, w = images.shape[-2:]
    size = level_size((w, h), factor)
    if size == (h, w):
        level = images.float()
    elif factor > 1:
        level = F.interpolate(images.float(), size=size, mode="area")
    else:
        level = F.interpolate(images.float(), size=size, mode="bilinear", align_corners=False)
    scale = torch.tensor([w / size[1], h / size[0]], dtype=torch.float64, device=images.device)
    return level, scale


def edge_blur(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int], samples: int | None = None) -> torch.Tensor:
    r"""Blur (Gaussian sigma, px) of the square edges of each found board, :math:`(B,)`.

    The intensity is sampled across every edge between two neighbouring corners, at the edge's midpoint, along its
    normal (up to 0.35 of the square on either side: the profile stays within the two squares); the spread of the
    profile's derivative (interquartile range / 1.349, robust to noise in the tails) is the edge's blur, and the
    median over the board's edges is returned.

    Args:
        images: :math:`(B, 1, H, W)` grey images.
        corners: :math:`(B, N, 2)` complete boards in grid order, ``N = cols * rows``.
        board_size: ``(cols, rows)``.
        samples: samples per profile (default: about one per px, 31 to 257).

    Returns:
        :math:`(B,)` float32 blur in px (includes the optics and the pixel footprint; about 0.5-0.7 px for sharp
        images).

    Example:
        >>> img = torch.zeros(1, 1, 64, 64); img[..., :32, :32] = 1; img[..., 32:, 32:] = 1
        >>> from kornia.filters import gaussian_blur2d
        >>> img = gaussian_blur2d(img, (25, 25), (3.0, 3.0))
        >>> pts = torch.tensor([[[31.5, 31.5], [63.5, 31.5]]])  # a 2x1 "board": one edge between two corners
        >>> round(float(edge_blur(img, pts, (2, 1))), 1)
        3.0
    """
    _check_images(images)
    cols, rows = int(board_size[0]), int(board_size[1])
    b = corners.shape[0]
    g = corners.float().reshape(b, rows, cols, 2)
    pairs = [(g[:, :, :-1], g[:, :, 1:])] if cols > 1 else []
    pairs += [(g[:, :-1], g[:, 1:])] if rows > 1 else []
    a = torch.cat([p[0].reshape(b, -1, 2) for p in pairs], 1)
    c = torch.cat([p[1].reshape(b, -1, 2) for p in pairs], 1)
    mid, d = 0.5 * (a + c), c - a
    length = d.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    if samples is None:
        samples = int(min(257, max(31, 0.7 * float(length.nan_to_num(0).max()) + 1)))
    normal = torch.stack([-d[..., 1], d[..., 0]], -1) / length  # (B, E, 2)
    u = torch.linspace(-0.35, 0.35, samples, device=corners.device)  # in squares
    offs = u[None, None, :, None] * length[..., None] * normal[:, :, None, :]  # (B, E, S, 2) px
    pts = mid[:, :, None, :] + offs
    h, w = images.shape[-2:]
    grid = torch.stack([pts[..., 0] * (2.0 / max(w - 1, 1)) - 1.0, pts[..., 1] * (2.0 / max(h - 1, 1)) - 1.0], -1)
    prof = F.grid_sample(images.float(), grid, mode="bilinear", padding_mode="border", align_corners=True)[:, 0]
    step = (prof[..., -1] - prof[..., 0]).sign()[..., None]
    deriv = ((prof[..., 1:] - prof[..., :-1]) * step).clamp_min(0)  # (B, E, S-1)
    cdf = deriv.cumsum(-1)
    total = cdf[..., -1:].clamp_min(1e-6)
    q = cdf / total
    pos = 0.5 * (u[1:] + u[:-1])  # positions of the derivative samples, in squares
    # interquartile range of the derivative's distribution, by linear interpolation of the cdf
    def quantile(p: float) -> torch.Tensor:
        k = (q < p).sum(-1).clamp(1, samples - 2)
        q0, q1 = q.gather(-1, (k - 1)[..., None])[..., 0], q.gather(-1, k[..., None])[..., 0]
        x0, x1 = pos[k - 1], pos[k]
        t = ((p - q0) / (q1 - q0).clamp_min(1e-9)).clamp(0, 1)
        return x0 + t * (x1 - x0)
    iqr = (quantile(0.75) - quantile(0.25)) * length[..., 0]  # px
    sigma = iqr / 1.349
    contrast = total[..., 0]
    ok = contrast > 0.5 * contrast.median(-1, keepdim=True).values  # edges with the board's contrast
    sigma = torch.where(ok, sigma, torch.full_like(sigma, float("nan")))
    return sigma.nanmedian(-1).values


def refine_on_patches(
    images: torch.Tensor,
    corners: torch.Tensor,
    board_size: tuple[int, int],
    radius_factor: float = 0.2,
    max_radius: int = 12,
    method: str = "saddle",
    iterations: int = 5,
    smooth_sigma: float = 1.0,
    normalize_sigma: float = 6.0,
    return_ok: bool = False,
    blur: torch.Tensor | None = None,
    blur_factor: float = 2.0,
    max_fraction: float = 0.3,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Refine whole boards at full resolution, each corner on its own small patch.

    The refiner (:func:`~ccs_kornia.modules.corner_refine.refine_corners`) smooths and normalises the image it is given;
    on a 24 Mpx photo that alone costs seconds and hundreds of MB, so every corner gets a patch of window plus smoothing
    margin, and all patches are refined in one batch. The window half-size is ``radius_factor`` times the distance to
    the nearest grid neighbour (clamped to ``[1.5, max_radius]``), as in
    :class:`~ccs_kornia.modules.corner_refine.CornerRefiner`; with ``blur`` (e.g. from :func:`edge_blur`) it is widened
    to ``blur_factor`` blur widths where the edges are soft (a saddle fit needs a window about as wide as the blur;
    large squares are often blurred in proportion), but never beyond ``max_fraction`` of the spacing.

    Args:
        images: :math:`(B, 1, H, W)` full-resolution images.
        corners: :math:`(B, N, 2)` corners of complete boards in grid order, ``N = cols * rows``.
        board_size: ``(cols, rows)``.
        radius_factor, max_radius, method, iterations, smooth_sigma, normalize_sigma: of the refiner.
        return_ok: also return the refiner's :math:`(B, N)` mask of corners that found a proper saddle.
        blur: optional :math:`(B,)` edge blur (Gaussian sigma, px) per board.
        blur_factor, max_fraction: see above.

    Returns:
        :math:`(B, N, 2)` refined corners (and the mask with ``return_ok``).

    Example:
        >>> img = torch.zeros(1, 1, 64, 64); img[..., :32, :32] = 1; img[..., 32:, 32:] = 1
        >>> refine_on_patches(img, torch.tensor([[[31.0, 32.2], [10.0, 31.5]]]), (2, 1))[0, 0].round(decimals=2)
        tensor([31.5000, 31.5000])
    """
    _check_images(images)
    if corners.dim() != 3 or corners.shape[0] != images.shape[0] or corners.shape[-1] != 2:
        raise ValueError(f"corners must be (B, N, 2) with B={images.shape[0]}, got {tuple(corners.shape)}.")
    b, n = corners.shape[:2]
    h, w = images.shape[-2:]
    if n == 0 or b == 0:
        ok = torch.zeros(b, n, dtype=torch.bool, device=corners.device)
        return (corners, ok) if return_ok else corners
    valid = torch.ones(b, n, dtype=torch.bool, device=corners.device)
    spacing = grid_spacing(corners.float(), valid, board_size).to(images.device)
    radius = (radius_factor * spacing).clamp(max=float(max_radius))
    if blur is not None:
        soft = blur_factor * blur.to(radius).nan_to_num(0.0)[:, None]
        radius = torch.maximum(radius, torch.minimum(soft, max_fraction * spacing))
    radius = radius.nan_to_num(5.0, posinf=float(max_radius))
    r_max = int(math.ceil(float(radius.max())))
    half = int(math.ceil(r_max + 3 * max(normalize_sigma, smooth_sigma) + 4))
    offsets = torch.arange(-half, half + 1, device=images.device)
    pts = corners.to(images.device)
    origin = pts.detach().nan_to_num(0.0).round().long()  # (B, N, 2) patch centres
    ys = (origin[..., 1, None] + offsets).clamp(0, h - 1)  # (B, N, P), replicate at image borders
    xs = (origin[..., 0, None] + offsets).clamp(0, w - 1)
    bi = torch.arange(b, device=images.device)[:, None, None, None]
    patches = images[bi, 0, ys[..., :, None], xs[..., None, :]]  # (B, N, P, P)
    size = 2 * half + 1
    shift = (origin - half).to(pts.dtype)
    local = (pts - shift).reshape(b * n, 1, 2)
    out, ok = refine_corners(
        patches.reshape(b * n, 1, size, size).float(), local, None, radius.reshape(b * n, 1), method, iterations, r_max,
        smooth_sigma, normalize_sigma, return_ok=True,
    )
    out = (out.reshape(b, n, 2) + shift).to(corners.dtype).to(corners.device)
    ok = ok.reshape(b, n).to(corners.device)
    return (out, ok) if return_ok else out


def refine_from_level(
    images: torch.Tensor,
    corners: torch.Tensor,
    board_size: tuple[int, int],
    factor: float,
    radius_factor: float = 0.2,
    max_radius: int = 12,
    method: str = "saddle",
    iterations: int = 5,
    smooth_sigma: float = 1.0,
    normalize_sigma: float = 6.0,
) -> torch.Tensor:
    r"""Refine at full resolution corners found on a level ``factor`` times smaller, :math:`(B, N, 2)`.

    Coarse to fine: the corners are refined on area-downscaled copies at ``factor / 4``, ``factor / 16``, ... (while
    above 1.5), then at full resolution, each time with :func:`refine_on_patches` and the usual window (at most
    ``max_radius`` px of that copy, widened by the boards' :func:`edge_blur` where the edges are soft). Each step shrinks
    the error of the previous one by about 4, well inside the next window, whatever the factor.

    Args:
        images: :math:`(B, 1, H, W)` full-resolution images.
        corners: :math:`(B, N, 2)` complete boards mapped from the level, grid order.
        board_size: ``(cols, rows)``.
        factor: full-resolution px per level px.
        radius_factor, max_radius, method, iterations, smooth_sigma, normalize_sigma: of the refiner
            (:class:`~ccs_kornia.modules.corner_refine.CornerRefiner`).

    Returns:
        :math:`(B, N, 2)` refined corners.

    Example:
        >>> img = torch.zeros(1, 1, 256, 256); img[..., :128, :128] = 1; img[..., 128:, 128:] = 1
        >>> start = torch.tensor([[[124.0, 131.0], [20.0, 127.5]]])  # 4 px off, as from a level 8x smaller
        >>> refine_from_level(img, start, (2, 1), 8.0)[0, 0].round(decimals=2)
        tensor([127.5000, 127.5000])
    """
    args = (method, iterations, smooth_sigma, normalize_sigma)
    steps = []
    g = factor / 4.0
    while g > 1.5:
        steps.append(g)
        g /= 4.0
    for g in steps:
        small, s = resize_to_level(images, g)
        pts = ((corners.double() + 0.5) / s - 0.5).to(corners.dtype)
        pts = refine_on_patches(small, pts, board_size, radius_factor, max_radius, *args,
                                blur=edge_blur(small, pts, board_size))
        corners = ((pts.double() + 0.5) * s - 0.5).to(corners.dtype)
    blur = edge_blur(images, corners, board_size)
    return refine_on_patches(images, corners, board_size, radius_factor, max_radius, *args, blur=blur)


class ScaleSelector(nn.Module):
    r"""Per image, the area-downscale factor at which the board's squares have ``target_square`` px.

    :func:`estimate_square_size` then :func:`detection_factor`. Squares smaller than the detector can use at the
    coarsest level allowed by ``max_pixels`` are not searched for (they could not be detected anyway), which keeps the
    estimate cheap on large photographs.

    Args:
        target_square: square size in px at which the detector works best (the shipped heatmap network: 6 to 20 px).
        max_pixels: most pixels of a detection level.
        min_level_square: smallest square (px of the level) the detector finds.
        steps_per_octave: scales per octave of the estimate and of the factors.
        min_factor: smallest factor (``< 1`` allows upsampling tiny squares).

    Example:
        >>> import torch.nn.functional as F
        >>> from ccs_kornia.data.synthetic import make_calibration_set
        >>> K = torch.tensor([[800., 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=0, supersample=1)
        >>> big = F.interpolate(views.images, scale_factor=4.0, mode="bilinear")  # squares ~60 px
        >>> square, factor = ScaleSelector()(big)
        >>> square.shape, [round(f, 2) for f in factor.tolist()]  # squares of ~11 px on the level
        (torch.Size([2]), [5.66, 5.66])
    """

    def __init__(
        self,
        target_square: float = 12.0,
        max_pixels: float = 3.2e6,
        min_level_square: float = 6.0,
        steps_per_octave: int = 4,
        min_factor: float = 1.0,
    ) -> None:
        super().__init__()
        if not target_square > 0 or not max_pixels > 0 or not min_level_square > 0:
            raise ValueError("target_square, max_pixels and min_level_square must be positive.")
        self.target_square = float(target_square)
        self.max_pixels = float(max_pixels)
        self.min_level_square = float(min_level_square)
        self.steps_per_octave = int(steps_per_octave)
        self.min_factor = float(min_factor)

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Square size :math:`(B,)` in px and detection factor :math:`(B,)` of grey images :math:`(B, 1, H, W)`."""
        _check_images(images)
        h, w = images.shape[-2:]
        floor = max(self.min_factor, math.sqrt(w * h / self.max_pixels))
        min_square = max(4.0, self.min_level_square * floor)
        max_square = max(min(h, w) / 3.0, 2 * min_square)
        square = estimate_square_size(images, min_square, max_square, self.steps_per_octave)
        factor = detection_factor(square, (w, h), self.target_square, self.max_pixels, self.steps_per_octave,
                                  self.min_factor)
        return square, factor


def detect_at_scale(
    detect: Callable[..., tuple[torch.Tensor, torch.Tensor, list[str] | None]],
    images: torch.Tensor,
    board_size: tuple[int, int],
    factor: torch.Tensor,
    fallback: tuple[float, ...] = (),
    max_pixels: float = 3.2e6,
    refine: Callable[[torch.Tensor, torch.Tensor, float], torch.Tensor] | None = None,
    min_factor: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor, list[str]]:
    r"""Run ``detect`` on each image's detection level; corners at full resolution.

    Images are grouped by factor (one batched call per level). Corners found on a downscaled level are mapped to the
    full-resolution pixel grid (pixel centres: ``x + 0.5`` scales) and refined there by ``refine``. Boards missed are
    looked for again at ``factor * f`` for each ``f`` of ``fallback`` in turn (levels above ``max_pixels`` skipped).

    Args:
        detect: ``detect(level (b, 1, h, w), board_size, full (b, 1, H, W) or None, scale (2,) or None)
            -> corners (b, N, 2), found (b,), reasons`` at the level's resolution; ``full`` (the full-resolution images,
            ``None`` when the level is the image itself) and ``scale`` (``x_full + 0.5 = (x_level + 0.5) * scale``) let
            it verify candidates at full resolution.
        images: :math:`(B, 1, H, W)` full-resolution images.
        board_size: ``(cols, rows)``.
        factor: :math:`(B,)` detection factors (:func:`detection_factor`).
        fallback: relative factors tried, in order, on the boards not found (clamped to the finest level allowed by
            ``max_pixels`` and ``min_factor``; a level already tried is skipped).
        max_pixels: most pixels of a fallback level.
        min_factor: smallest fallback factor (1: no upsampling).
        refine: ``refine(images (b, 1, H, W), corners (b, N, 2), factor) -> corners`` at full resolution, for boards
            found on a resampled level (default: :func:`refine_from_level`).

    Returns:
        corners :math:`(B, N, 2)` (zeros where not found), found :math:`(B,)` bool, and a reason per image.

    Example:
        >>> def detect(x, board, full, scale):  # a stand-in detector: finds nothing
        ...     return torch.zeros(x.shape[0], board[0] * board[1], 2), torch.zeros(x.shape[0], dtype=torch.bool), \
        ...         ["board not found"] * x.shape[0]
        >>> c, f, r = detect_at_scale(detect, torch.rand(3, 1, 96, 128), (4, 3), torch.tensor([1.0, 2.0, 2.0]))
        >>> c.shape, f.tolist()
        (torch.Size([3, 12, 2]), [False, False, False])
    """
    _check_images(images)
    b, _, h, w = images.shape
    factor = torch.as_tensor(factor, dtype=torch.float64).flatten()
    if factor.numel() != b:
        raise ValueError(f"factor must have one value per image ({b}), got {tuple(factor.shape)}.")
    if not bool((factor > 0).all()):
        raise ValueError("factors must be positive.")
    n = int(board_size[0]) * int(board_size[1])
    if refine is None:
        def refine(full, pts, factor):
            return refine_from_level(full, pts, board_size, factor)
    corners = torch.zeros(b, n, 2, dtype=torch.float32, device=images.device)
    found = torch.zeros(b, dtype=torch.bool, device=images.device)
    reasons = ["board not found"] * b
    # fallback levels are clamped to the finest level allowed (memory, no upsampling); each level is tried once
    floor = max(float(min_factor), math.sqrt(w * h / max_pixels))
    attempts = [factor] + [(factor * f).clamp_min(floor) for f in fallback]
    for a, fac in enumerate(attempts):
        todo = ~found.cpu()
        for previous in attempts[:a]:
            todo &= (fac - previous).abs() > 1e-6 * fac
        if not bool(todo.any()):
            continue
        for value in torch.unique(fac[todo]).tolist():
            idx = (todo & (fac == value)).nonzero().flatten()
            full = images[idx.to(images.device)]
            level, scale = resize_to_level(full, value)
            resampled = level.shape[-2:] != images.shape[-2:]
            c, f, r = detect(level, board_size, full if resampled else None, scale if resampled else None)
            c = c.to(images.device)
            if resampled:
                c = ((c.double() + 0.5) * scale - 0.5).float()
            hit = f.to(images.device).nonzero().flatten()
            if resampled and hit.numel():
                c[hit] = refine(full[hit], c[hit], float(scale.max())).to(c.dtype)
            found_now = f.to(found.device)
            sel = idx.to(found.device)[found_now]
            corners[sel.to(images.device)] = c[found_now.to(images.device)]
            found[sel] = True
            for k, i in enumerate(idx.tolist()):
                if bool(found_now[k]) or a == 0:
                    reasons[i] = r[k] if r is not None else ("found" if bool(found_now[k]) else "board not found")
    return corners, found, reasons
