r"""Full-resolution refinement of boards found on a resampled detection level (see
:mod:`ccs_kornia.modules.detection.learned.scale`).

* :func:`resize_to_level`: the area-downscaled (or bilinearly upsampled) detection level of an image and the px scale
  back to full resolution.
* :func:`edge_blur`: the blur of a found board's square edges, measured across them.
* :func:`refine_on_patches`: the saddle refiner at full resolution on one small patch per corner (bounded memory on
  24 Mpx photographs), its window widened to the edge blur where the edges are soft; :func:`refine_boards`: the same
  with a :class:`~ccs_kornia.modules.detection.refine.saddle_refine.CornerRefiner`'s options (the pipeline's
  refinement of boards found on a copy of the images).
* :func:`refine_from_level`: coarse to fine from the detection level to full resolution.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ccs_kornia.modules._resize import area_resize
from ccs_kornia.modules.detection.grid.grid_geometry import grid_spacing
from ccs_kornia.modules.detection.grid.missing_corners import predict_missing_corners
from ccs_kornia.modules.detection.refine.saddle_refine import (
    CornerRefiner,
    refine_corners,
)
from ccs_kornia.runtime.checks import check_board_size, check_grey_images, check_points
from ccs_kornia.runtime.timing import stage

#: the smallest window half-size (px) a corner near the image's border is refined with (its window ends a px short of
#: the border)
MIN_BORDER_RADIUS = 1.5

__all__ = ["MIN_BORDER_RADIUS", "edge_blur", "level_size", "refine_boards", "refine_from_level", "refine_from_neighbours",
           "refine_on_patches", "resize_to_level"]


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
    check_grey_images(images)
    h, w = images.shape[-2:]
    size = level_size((w, h), factor)
    if size == (h, w):
        level = images.float()
    elif factor > 1:
        level = area_resize(images.float(), size)
    else:
        level = F.interpolate(images.float(), size=size, mode="bilinear", align_corners=False)
    scale = torch.tensor([w / size[1], h / size[0]], dtype=torch.float64, device=images.device)
    return level, scale


def edge_blur(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int], samples: int | None = None,
              return_contrast: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
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
        return_contrast: also return the median step between the two plateaus of the edges measured (the board's
            contrast, in the images' units).

    Returns:
        :math:`(B,)` float32 blur in px (includes the optics and the pixel footprint; about 0.5-0.7 px for sharp
        images), and with ``return_contrast`` the :math:`(B,)` contrast.

    Example:
        >>> img = torch.zeros(1, 1, 64, 64); img[..., :32, :32] = 1; img[..., 32:, 32:] = 1
        >>> from kornia.filters import gaussian_blur2d
        >>> img = gaussian_blur2d(img, (25, 25), (3.0, 3.0))
        >>> pts = torch.tensor([[[31.5, 31.5], [63.5, 31.5]]])  # a 2x1 "board": one edge between two corners
        >>> round(float(edge_blur(img, pts, (2, 1))), 1)
        3.0
    """
    check_grey_images(images)
    cols, rows = check_board_size(board_size, min_side=1)
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
    # the profile itself, normalised from one plateau (mean of its first tenth) to the other, is the cdf of the
    # edge's derivative: summing clamped sample differences instead would add the noise of every sample (on a
    # 300 px square, 200 samples of 1 % noise outweigh the edge itself and read as 30 px of blur)
    end = max(2, samples // 10)
    lo, hi = prof[..., :end].mean(-1, keepdim=True), prof[..., -end:].mean(-1, keepdim=True)
    step = (hi - lo).sign()
    total = ((hi - lo) * step).clamp_min(1e-6)
    q = (0.5 * (prof[..., 1:] + prof[..., :-1]) - lo) * step / total  # (B, E, S-1), at the derivative samples
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
    if return_contrast:
        return sigma.nanmedian(-1).values, torch.where(ok, contrast, torch.nan).nanmedian(-1).values
    return sigma.nanmedian(-1).values


def _to_border(points: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Distance (px) of points :math:`(..., 2)` to the nearest border of an image ``h`` x ``w`` (negative outside)."""
    x, y = points[..., 0], points[..., 1]
    return torch.minimum(torch.minimum(x, y), torch.minimum(w - 1 - x, h - 1 - y))


def refine_on_patches(
    images: torch.Tensor,
    corners: torch.Tensor,
    board_size: tuple[int, int],
    radius_factor: float = 0.2,
    max_radius: int = 12,
    method: str = "symmetric",
    iterations: int = 5,
    smooth_sigma: float = 1.0,
    normalize_sigma: float = 6.0,
    return_ok: bool = False,
    blur: torch.Tensor | None = None,
    blur_factor: float = 2.0,
    max_fraction: float = 0.3,
    wide: bool = True,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Refine whole boards at full resolution, each corner on its own small patch.

    The refiner (:func:`~ccs_kornia.modules.detection.refine.saddle_refine.refine_corners`) must not smooth and normalise a
    whole 24 Mpx photo (seconds and hundreds of MB): its saddle fit works on one small region per corner; the gradient
    fit gets a patch of window plus margin per corner, all patches refined in one batch. The window half-size is
    ``radius_factor`` times the distance to the nearest grid neighbour (clamped to ``[1.5, max_radius]``), as in
    :class:`~ccs_kornia.modules.detection.refine.saddle_refine.CornerRefiner`; with ``blur`` (e.g. from :func:`edge_blur`) it
    is widened to ``blur_factor`` blur widths where the edges are soft (a saddle fit needs a window about as wide as
    the blur; large squares are often blurred in proportion), but never beyond ``max_fraction`` of the spacing.

    Args:
        images: :math:`(B, 1, H, W)` full-resolution images.
        corners: :math:`(B, N, 2)` corners of complete boards in grid order, ``N = cols * rows``.
        board_size: ``(cols, rows)``.
        radius_factor, max_radius, method, iterations, smooth_sigma, normalize_sigma: of the refiner.
        return_ok: also return the refiner's :math:`(B, N)` mask of corners that found a proper saddle.
        blur: optional :math:`(B,)` edge blur (Gaussian sigma, px) per board.
        blur_factor, max_fraction: see above.
        wide: the refiner's wide polish (off on the coarse steps of :func:`refine_from_level`).

    Returns:
        :math:`(B, N, 2)` refined corners (and the mask with ``return_ok``).

    Example:
        >>> img = torch.zeros(1, 1, 64, 64); img[..., :32, :32] = 1; img[..., 32:, 32:] = 1
        >>> refine_on_patches(img, torch.tensor([[[31.0, 32.2], [10.0, 31.5]]]), (2, 1))[0, 0].round(decimals=2)
        tensor([31.5000, 31.5000])
    """
    check_grey_images(images)
    check_points(corners, "corners", B=images.shape[0])
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
    # a window that crosses the image's border sees the border's pixels repeated, a false junction the fit is pulled
    # to (px off on a corner a few px inside the border): the window ends a px short of the border
    edge = _to_border(corners.to(radius.device).float(), h, w)
    radius = torch.minimum(radius, (edge - 1.0).nan_to_num(float(max_radius)).clamp_min(MIN_BORDER_RADIUS))
    r_max = int(math.ceil(float(radius.max())))
    if method in ("saddle", "symmetric"):
        # the saddle refiner works on one small region per corner of the image itself (bounded memory whatever the
        # image size): no patch copy needed
        out, ok = refine_corners(images.float(), corners.to(images.device).float(), None, radius, method, iterations,
                                 r_max, smooth_sigma, normalize_sigma, return_ok=True,
                                 board_size=board_size if wide else None)
        out, ok = out.to(corners.dtype).to(corners.device), ok.to(corners.device)
        return (out, ok) if return_ok else out
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


def refine_boards(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int],
                  refiner: CornerRefiner) -> torch.Tensor:
    """Saddle refinement of whole boards :math:`(S, N, 2)` on ``images`` :math:`(S, 1, H, W)`, one small patch per
    corner (:func:`refine_on_patches` with ``refiner``'s window, method, iterations and smoothing), in the corners'
    dtype.

    Example:
        >>> img = torch.zeros(1, 1, 64, 64)
        >>> img[..., :32, :32] = 1.0
        >>> img[..., 32:, 32:] = 1.0
        >>> refine_boards(img, torch.tensor([[[31.0, 32.2], [10.0, 31.5]]]), (2, 1), CornerRefiner()).shape
        torch.Size([1, 2, 2])
    """
    r = refiner
    with stage("saddle refinement"):
        return refine_on_patches(images.float(), corners.float(), board_size, r.radius_factor, r.max_radius, r.method,
                                 r.iterations, r.smooth_sigma, r.normalize_sigma).to(corners.dtype)


def refine_from_level(
    images: torch.Tensor,
    corners: torch.Tensor,
    board_size: tuple[int, int],
    factor: float,
    radius_factor: float = 0.2,
    max_radius: int = 12,
    method: str = "symmetric",
    iterations: int = 5,
    smooth_sigma: float = 1.0,
    normalize_sigma: float = 6.0,
    return_ok: bool = False,
    neighbours: bool = True,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Refine at full resolution corners found on a level ``factor`` times smaller, :math:`(B, N, 2)`.

    Coarse to fine: the corners are refined on area-downscaled copies at ``factor / 4``, ``factor / 16``, ... (while
    above 1.5), then at full resolution, each time with :func:`refine_on_patches` and the usual window (at most
    ``max_radius`` px of that copy, widened by the boards' :func:`edge_blur` where the edges are soft). Each step shrinks
    the error of the previous one by about 4, well inside the next window, whatever the factor.

    Args:
        images: :math:`(B, 1, H, W)` full-resolution images.
        corners: :math:`(B, N, 2)` complete boards mapped from the level, grid order; NaN at the hidden corners of a
            partial board (:mod:`~ccs_kornia.modules.detection.checks.hidden_corners`), which stay NaN.
        board_size: ``(cols, rows)``.
        factor: full-resolution px per level px.
        radius_factor, max_radius, method, iterations, smooth_sigma, normalize_sigma: of the refiner
            (:class:`~ccs_kornia.modules.detection.refine.saddle_refine.CornerRefiner`).
        return_ok: also return the full-resolution step's :math:`(B, N)` mask of corners that found a proper saddle
            within their window (False at hidden corners); the others keep the position they came with.
        neighbours: a corner that finds none from where the level put it is tried again from where its refined
            neighbours put it (:func:`refine_from_neighbours`).

    Returns:
        :math:`(B, N, 2)` refined corners (and the mask with ``return_ok``).

    Example:
        >>> img = torch.zeros(1, 1, 256, 256); img[..., :128, :128] = 1; img[..., 128:, 128:] = 1
        >>> start = torch.tensor([[[124.0, 131.0], [20.0, 127.5]]])  # 4 px off, as from a level 8x smaller
        >>> refine_from_level(img, start, (2, 1), 8.0)[0, 0].round(decimals=2)
        tensor([127.5000, 127.5000])
    """
    hidden = ~corners.isfinite().all(-1)
    if bool(hidden.any()):
        # hidden corners ride along at the place their neighbours predict (the windows and the edge blur are measured
        # on whole boards) and come back NaN
        filled, _ = predict_missing_corners(corners.masked_fill(hidden[..., None], 0.0), ~hidden, board_size,
                                            passes=max(board_size))
        out, ok = refine_from_level(images, filled, board_size, factor, radius_factor, max_radius, method, iterations,
                                    smooth_sigma, normalize_sigma, return_ok=True, neighbours=neighbours)
        out = out.masked_fill(hidden[..., None], float("nan"))
        return (out, ok & ~hidden) if return_ok else out
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
                                blur=edge_blur(small, pts, board_size), wide=False)
        corners = ((pts.double() + 0.5) * s - 0.5).to(corners.dtype)
    # squares that needed upsampling are small: their window (0.2 square) is the usual one, blur or not
    blur = edge_blur(images, corners, board_size) if factor > 1 else None
    out, ok = refine_on_patches(images, corners, board_size, radius_factor, max_radius, *args, return_ok=True, blur=blur)
    if neighbours:
        out, ok = refine_from_neighbours(images, corners, out, ok, board_size, radius_factor, max_radius, *args,
                                         blur=blur)
    return (out, ok) if return_ok else out


def refine_from_neighbours(
    images: torch.Tensor,
    corners: torch.Tensor,
    refined: torch.Tensor,
    ok: torch.Tensor,
    board_size: tuple[int, int],
    radius_factor: float = 0.2,
    max_radius: int = 12,
    method: str = "symmetric",
    iterations: int = 5,
    smooth_sigma: float = 1.0,
    normalize_sigma: float = 6.0,
    blur: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The corners whose saddle fit failed, :math:`(B, N)` ``~ok``, from a start within ``max_radius`` px of the
    image's border (or beyond it), tried again from where their refined neighbours put them
    (:func:`~ccs_kornia.modules.detection.grid.missing_corners.predict_missing_corners`): at the border the level's
    heatmap peak is cut off and can place a corner farther off than its window; from the neighbours' prediction it
    finds its saddle. Elsewhere a failed fit is a corner the image does not show as a junction (at a glare's rim the
    fit is pulled by px) and stays failed; the others keep their fit.

    Args:
        images: :math:`(B, 1, H, W)` full-resolution images.
        corners: :math:`(B, N, 2)` the corners the fit started from (NaN: hidden, left alone).
        refined, ok: :func:`refine_on_patches`'s corners and mask from them.
        board_size: ``(cols, rows)``, at least 2x2 (a 1-wide board has no lattice to predict from: returned as is).
        radius_factor, max_radius, method, iterations, smooth_sigma, normalize_sigma, blur: of
            :func:`refine_on_patches`.

    Returns:
        :math:`(B, N, 2)` corners and :math:`(B, N)` mask, the corners found again added.

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> truth = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> start = truth.clone(); start[0, 0] += torch.tensor([9.0, -27.0])  # beyond its window, at the border
        >>> out, ok = refine_on_patches(img, start, (3, 2), return_ok=True)
        >>> bool(ok[0, 0])
        False
        >>> out, ok = refine_from_neighbours(img, start, out, ok, (3, 2))
        >>> bool(ok.all()), round(float((out - truth).norm(dim=-1).max()), 2)
        (True, 0.0)
    """
    edge = _to_border(corners.to(refined.device).float(), *images.shape[-2:])
    # only where the level's estimate is the suspect, at the border: elsewhere a fit that fails is a corner the image
    # does not show as a junction (a glare's rim pulls its saddle by px), left out
    failed = ~ok.to(refined.device) & corners.isfinite().all(-1) & (edge < max_radius)
    rows = failed.any(-1).nonzero().flatten()
    if not rows.numel() or min(board_size) < 2:
        return refined, ok
    good = ok[rows].to(refined.device) & refined[rows].isfinite().all(-1)
    start, filled = predict_missing_corners(refined[rows].masked_fill(~good[..., None], 0.0), good, board_size,
                                            passes=max(board_size))
    again, ok_again = refine_on_patches(images[rows], start, board_size, radius_factor, max_radius, method, iterations,
                                        smooth_sigma, normalize_sigma, return_ok=True,
                                        blur=None if blur is None else blur[rows])
    take = failed[rows] & filled & ok_again.to(refined.device)
    refined, ok = refined.clone(), ok.clone()
    refined[rows] = torch.where(take[..., None], again.to(refined), refined[rows])
    ok[rows] = ok[rows] | take.to(ok.device)
    return refined, ok
