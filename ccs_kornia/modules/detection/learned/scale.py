r"""Scale selection for the learned chessboard detector: detect on the pyramid level where the squares have the size
the heatmap network was trained on, refine at full resolution.

The heatmap network (:class:`~ccs_kornia.modules.detection.learned.heatmap_unet.CornerUNet`) was trained on squares of about 6 to 17 px
(median 10 px) with nearly sharp edges. Squares of 100 px with an 11 px blur look nothing like that; their 8x
area-downscaled copy does (area downscaling shrinks the squares and the blur alike). Three batched steps:

1. :func:`estimate_square_size`: the board's square size in px, from the image itself. A chessboard corner is a saddle
   of the intensity; the :math:`\gamma`-normalised saddle strength :math:`\sigma^\gamma \sqrt{-\det H_\sigma}` (Hessian
   of the image smoothed at scale :math:`\sigma`) grows with :math:`\sigma` on an isolated X-junction and dies once
   the smoothing reaches the neighbouring corners of opposite sign: on a checker of square :math:`s` it peaks near
   :math:`\sigma^* = 0.37 s`, whatever the blur below that scale. L- and T-junctions (clutter, the board's outline)
   are penalised by their gradient, which an X-junction lacks. Per image, the scale whose strongest saddles are
   strongest gives the square size (close to the truth on renders and on the real sets:
   ``docs/measurements.md``). Computed on an incremental Gaussian pyramid of a copy of at most 1 Mpx.
2. :func:`detection_factor`: the area-downscale factor that brings that square size to ``target_square`` px (in
   quarter-octave steps, so images of one camera share a level and stay batched), large enough that the level has
   at most ``max_pixels`` pixels (bounded memory and time on 24 Mpx photographs); tiny squares may be upsampled.
3. :func:`detect_at_scale`: run a detector on each level (images grouped by factor; the detector may verify its
   candidates on the full-resolution images), map the corners back to the full-resolution pixel grid and refine them
   there (each level a :class:`~ccs_kornia.modules.detection.warps.warped_detection.Level` warp through
   :func:`~ccs_kornia.modules.detection.warps.warped_detection.map_back`;
   :func:`~ccs_kornia.modules.detection.refine.patch_refine.refine_from_level`: coarse to fine, on one small patch per
   corner, the saddle window widened to the measured edge blur). Boards missed at the chosen level are looked for at
   other levels (``fallback``).

:class:`ScaleSelector` wraps steps 1-2 as a module.
"""

from __future__ import annotations

import math
from typing import Callable

import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d
from torch import nn

from ccs_kornia.modules._kernels import gaussian_kernel1d
from ccs_kornia.modules._resize import area_resize, halve
from ccs_kornia.modules.detection.base import DetectionResult, image_rows
from ccs_kornia.modules.detection.refine.patch_refine import refine_from_level
from ccs_kornia.modules.detection.warps.warped_detection import Level, map_back
from ccs_kornia.runtime.checks import check_board_size, check_grey_images, check_tensor
from ccs_kornia.runtime.timing import stage

__all__ = ["PEAK_RATIO", "TARGET_SQUARE", "saddle_scale_response", "estimate_square_size", "detection_factor", "ScaleSelector",
           "detect_at_scale"]

#: sigma* / square where the saddle response (gamma = 3, edge penalty 2) peaks, measured on rendered boards under
#: perspective and blur (``docs/measurements.md``)
PEAK_RATIO = 0.365
#: square size (px of the level) the learned detector runs its heatmap network at. The network was trained on squares
#: of 6-17 px; 9 px runs it on fewer pixels than larger targets with the same boards and errors
#: (``docs/measurements.md``, docs/benchmarks.md section 5)
TARGET_SQUARE = 9.0


def _sigmas(min_sigma: float, max_sigma: float, steps_per_octave: int) -> torch.Tensor:
    n = max(1, int(math.floor(steps_per_octave * math.log2(max_sigma / min_sigma))) + 1)
    return min_sigma * 2.0 ** (torch.arange(n, dtype=torch.float64) / steps_per_octave)


def _blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """kornia's ``gaussian_blur2d`` (separable, reflect border) of one-channel images, as weighted sums of shifted
    slices on CPU: the same filter, but without oneDNN's one-channel convolution that kornia uses below 256x256 px
    (slower than the slices there: ``docs/measurements.md``)."""
    k = 2 * int(math.ceil(3 * sigma)) + 1
    k = min(k, 2 * ((min(x.shape[-2:]) - 1) // 2) - 1)
    if k < 3:
        return x
    if x.device.type != "cpu":
        return gaussian_blur2d(x, (k, k), (sigma, sigma), border_type="reflect", separable=True)
    g = gaussian_kernel1d(k, sigma, dtype=x.dtype).tolist()
    m = k // 2
    for dim, pad in ((-1, (m, m, 0, 0)), (-2, (0, 0, m, m))):
        padded = F.pad(x, pad, mode="reflect")
        size = x.shape[dim]
        out = padded.narrow(dim, 0, size) * g[0]
        for tap in range(1, k):
            out.add_(padded.narrow(dim, tap, size), alpha=g[tap])
        x = out
    return x


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
        >>> from ccs_kornia.data.scenes.scenes import make_calibration_set
        >>> K = torch.tensor([[800., 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=0, supersample=1)
        >>> r = saddle_scale_response(views.images, torch.tensor([2.0, 4.0, 8.0, 16.0]))  # squares ~15 px
        >>> r.shape, r.argmax(-1).tolist()  # strongest at sigma ~0.37 x 15 px
        (torch.Size([2, 4]), [1, 1])
    """
    check_grey_images(images)
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
        level = halve(level)
        step *= 2
    blur = 0.0  # blur of ``level`` in its own px (the image's own blur is ignored)
    for k in range(sig.numel()):
        s = float(sig[k]) / step
        while s >= 2 * base_sigma and min(level.shape[-2:]) >= 32:
            level = halve(level)
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
    coarse_first: bool = True,
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
        coarse_first: compute the scales on the image itself (squares below ``2 base_sigma / ratio``, about 8 px) only
            for the images whose strongest coarser scale is one of the two lowest (``False``: always; the coarser
            octaves are then reached through the image's own blur, which moves the estimate by a fraction of a
            step).

    Returns:
        :math:`(B,)` float32 square sizes in px.

    Example:
        >>> from ccs_kornia.data.scenes.scenes import make_calibration_set
        >>> K = torch.tensor([[800., 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=0, supersample=1)
        >>> estimate_square_size(views.images).round()  # true median squares: 14.1 and 15.2 px
        tensor([15., 15.])
    """
    check_grey_images(images)
    ratio = PEAK_RATIO * math.sqrt(gamma / 3.0)
    if max_square is None:
        max_square = min(images.shape[-2:]) / 3.0
    if not 0 < min_square < max_square:
        raise ValueError(f"Need 0 < min_square < max_square, got {min_square} and {max_square}.")
    h, w = images.shape[-2:]
    pre = max(1.0, math.sqrt(h * w / max_pixels))
    if pre > 1.0:
        # large images: estimated on an area-downscaled copy (squares below 4 px of it are not searched for)
        images = area_resize(images.float(), (max(8, round(h / pre)), max(8, round(w / pre))))
        pre = math.sqrt(h * w / (images.shape[-2] * images.shape[-1]))
        min_square, max_square = max(4.0, min_square / pre), max_square / pre
        if min_square >= max_square:
            max_square = 2 * min_square
    sig = _sigmas(ratio * min_square, ratio * max_square, steps_per_octave)
    kw = {"gamma": gamma, "num_peaks": num_peaks, "base_sigma": base_sigma, "edge_penalty": edge_penalty}
    # scales on the image itself cost about two thirds of the whole pyramid; they matter only for squares at the
    # bottom of the range, so the coarser octaves come first and the image's own octave is added only for images
    # whose strongest coarse scale is one of the two lowest (their response is then exactly the full one)
    n_fine = int((sig < 2 * base_sigma).sum())
    if coarse_first and n_fine > 0 and sig.numel() - n_fine >= 3:
        resp = torch.zeros(images.shape[0], sig.numel(), dtype=torch.float32, device=images.device)
        resp[:, n_fine:] = saddle_scale_response(images, sig[n_fine:], **kw)
        low = (resp[:, n_fine:].argmax(-1) <= 1).nonzero().flatten()
        if low.numel():
            resp[low] = saddle_scale_response(images[low], sig, **kw)
    else:
        resp = saddle_scale_response(images, sig, **kw)
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
    target_square: float = TARGET_SQUARE,
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
        >>> detection_factor(torch.tensor([9.0, 36.0, 72.0]), (640, 480))
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
        >>> from ccs_kornia.data.scenes.scenes import make_calibration_set
        >>> K = torch.tensor([[800., 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=0, supersample=1)
        >>> big = F.interpolate(views.images, scale_factor=4.0, mode="bilinear")  # squares ~60 px
        >>> square, factor = ScaleSelector()(big)
        >>> square.shape, [round(f, 2) for f in factor.tolist()]  # squares of ~9 px on the level
        (torch.Size([2]), [6.73, 6.73])
    """

    def __init__(
        self,
        target_square: float = TARGET_SQUARE,
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
        check_grey_images(images)
        h, w = images.shape[-2:]
        floor = max(self.min_factor, math.sqrt(w * h / self.max_pixels))
        min_square = max(4.0, self.min_level_square * floor)
        max_square = max(min(h, w) / 3.0, 2 * min_square)
        square = estimate_square_size(images, min_square, max_square, self.steps_per_octave)
        factor = detection_factor(square, (w, h), self.target_square, self.max_pixels, self.steps_per_octave,
                                  self.min_factor)
        return square, factor


def detect_at_scale(
    detect: Callable[..., DetectionResult],
    images: torch.Tensor,
    board_size: tuple[int, int],
    factor: torch.Tensor,
    fallback: tuple[float, ...] = (),
    max_pixels: float = 3.2e6,
    refine: Callable[[torch.Tensor, torch.Tensor, float], torch.Tensor] | None = None,
    min_factor: float = 1.0,
    finest: bool = True,
    primary: bool = True,
) -> DetectionResult:
    r"""Run ``detect`` on each image's detection level; corners at full resolution.

    Images are grouped by factor (one batched call per level). Corners found on a downscaled level are mapped to the
    full-resolution pixel grid (pixel centres: ``x + 0.5`` scales) and refined there by ``refine`` (a
    :class:`~ccs_kornia.modules.detection.warps.warped_detection.Level` through
    :func:`~ccs_kornia.modules.detection.warps.warped_detection.map_back`); each level's boards are merged with
    :meth:`~ccs_kornia.modules.detection.base.DetectionResult.fill`. Boards missed are
    looked for again at ``factor * f`` for each ``f`` of ``fallback`` in turn (levels above ``max_pixels`` skipped).

    Args:
        detect: ``detect(level (b, 1, h, w), board_size, full (b, 1, H, W) or None, scale (2,) or None)
            -> DetectionResult`` at the level's resolution; ``full`` (the full-resolution images,
            ``None`` when the level is the image itself) and ``scale`` (``x_full + 0.5 = (x_level + 0.5) * scale``) let
            it verify candidates at full resolution.
        images: :math:`(B, 1, H, W)` full-resolution images.
        board_size: ``(cols, rows)``.
        factor: :math:`(B,)` detection factors (:func:`detection_factor`).
        fallback: relative factors tried, in order, on the boards not found (clamped to the finest level allowed by
            ``max_pixels`` and ``min_factor``; a level already tried is skipped); with any fallback and ``finest``,
            the octaves below the finest of them (while above 1.5 times the finest level allowed) and the finest
            level allowed are tried last.
        max_pixels: most pixels of a fallback level.
        min_factor: smallest fallback factor (1: no upsampling).
        refine: ``refine(images (b, 1, H, W), corners (b, N, 2), factor) -> corners`` at full resolution, for boards
            found on a resampled level (default: :func:`refine_from_level`).
        finest: see ``fallback``.
        primary: ``False``: the levels ``factor`` itself skipped (a caller that has tried them already: only the
            fallback levels that differ from them are tried).

    Returns:
        :class:`~ccs_kornia.modules.detection.base.DetectionResult`: corners :math:`(B, N, 2)` (zeros where not
        found), found :math:`(B,)` bool, and a reason per image.

    Example:
        >>> def detect(x, board, full, scale):  # a stand-in detector: finds nothing
        ...     return DetectionResult(torch.zeros(x.shape[0], board[0] * board[1], 2),
        ...                            torch.zeros(x.shape[0], dtype=torch.bool), ["board not found"] * x.shape[0])
        >>> out = detect_at_scale(detect, torch.rand(3, 1, 96, 128), (4, 3), torch.tensor([1.0, 2.0, 2.0]))
        >>> out.corners.shape, out.found.tolist()
        (torch.Size([3, 12, 2]), [False, False, False])
    """
    check_grey_images(images)
    b, _, h, w = images.shape
    factor = torch.as_tensor(factor, dtype=torch.float64).flatten()
    check_tensor(factor, "factor", ["B"], what="(one value per image)", B=b)
    if not bool((factor > 0).all()):
        raise ValueError("factors must be positive.")
    cols, rows = check_board_size(board_size, min_side=1)
    n = cols * rows
    if refine is None:
        def refine(full, pts, factor):
            return refine_from_level(full, pts, board_size, factor)
    out = DetectionResult(torch.zeros(b, n, 2, dtype=torch.float32, device=images.device),
                          torch.zeros(b, dtype=torch.bool, device=images.device), ["board not found"] * b)
    # fallback levels are clamped to the finest level allowed (memory, no upsampling); each level is tried once
    floor = max(float(min_factor), math.sqrt(w * h / max_pixels))
    attempts = [factor] + [(factor * f).clamp_min(floor) for f in fallback]
    if fallback and finest:
        # then octaves down from the finest relative fallback and last, the finest level allowed (the image itself
        # when it fits): a wrong square-size estimate (a scene with strong saddles at 10x the board's scale) must not
        # hide a board the relative fallbacks never reach, and the octave that finds it costs a quarter of the next
        # finer one (docs/measurements.md)
        step = factor * min(fallback) / 2
        while bool((step > 1.5 * floor).any()):
            attempts.append(step.clamp_min(floor))
            step = step / 2
        attempts.append(torch.full_like(factor, floor))
    for a, fac in enumerate(attempts):
        if a == 0 and not primary:
            continue
        todo = ~out.found.cpu()
        for previous in attempts[:a]:
            todo &= (fac - previous).abs() > 1e-6 * fac
        if not bool(todo.any()):
            continue
        for value in torch.unique(fac[todo]).tolist():
            idx = (todo & (fac == value)).nonzero().flatten()
            full = image_rows(images, idx)
            warp = Level(value, (h, w))
            with stage("level resize"):
                level = warp.apply(full)
            if warp.resamples:
                got = detect(level, board_size, full, warp.scale(images.device))
            else:
                got = detect(level, board_size, None, None)
            r = got.reasons or ["found" if bool(k) else "board not found" for k in got.found.tolist()]
            got = DetectionResult(got.corners.to(images.device), got.found.to(images.device), r)
            if warp.resamples:
                got = map_back(warp, got, lambda x, pts, bs: refine(x, pts, warp.coarseness), full, board_size)
            hit = out.fill(idx, got)
            if a == 0:  # the reasons of the first level stand where no level finds the board
                for k, i in enumerate(idx.tolist()):
                    if not bool(hit[k]):
                        out.reasons[i] = r[k]
    return out

