r"""Chessboard corners as differentiable functions of the image pixels and of the heatmap network.

The usual detector (:class:`~ccs_kornia.modules.detection.learned.learned_detector.LearnedChessboardDetector`) runs without
autograd: it takes every discrete decision (which peaks, which grid, which board, which corners are valid, the
detection level) and returns corners whose value is final. This module gives those corners a gradient, without
changing their value:

1. **seed** (:func:`network_seeds`): the heatmap network runs with grad on the detection level of the image, and the
   paper's Gaussian fit (:func:`~ccs_kornia.modules.detection.learned.gaussian_fit.gaussian_fit`, a closed-form weighted
   least squares) gives each corner's sub-pixel centre ``mu`` as a function of the heatmap, hence of the network's
   parameters and of the pixels. The window of the fit is picked by rounding the (detached) corner: a discrete
   choice, as the peak that seeded the corner (the peak finder's soft-argmax only picks that window too);
2. **refinement** (:func:`symmetry_refine`): ``steps`` Gauss-Newton steps of the point-symmetry polish (the
   detector's last refinement, :mod:`~ccs_kornia.modules.detection.refine.symmetry_refine`) on the smoothed image, started
   at the seed: every sample is a bilinear ``grid_sample`` and every step a closed-form 2x2 solve, so the refined
   point is a function of the pixels and of the seed;
3. **value** (:func:`differentiable_corners`): the returned corner is
   ``c + (f - f.detach())`` with ``c`` the detector's corner and ``f`` the refinement of step 2: the value is
   exactly the detector's, the gradient is the true local gradient of ``f``. ``f`` is the same estimator (point
   symmetry, same window) run as a fixed number of steps from the network's seed; its value is within a few
   hundredths of a px of ``c`` on renders and real photographs (the difference comes from the detector's
   alternatives ``f`` does not take: the saddle fit on a shading-normalised source, the wide polish, the board-wide
   votes; ``docs/gradients.md`` gives the measured figures).

What the gradient sees: the pixels through the refinement (and through the network, whose heatmap moves the seed);
the network through the seed only, damped by the refinement: a converged refinement forgets its start (its
derivative with respect to the seed is the product of the Gauss-Newton steps' contraction, small after a few
steps). With ``steps=0`` the corner's gradient is the network's own (the Gaussian fit of its heatmap): what a
detector without image refinement (``refine="none"``) returns, and what end-to-end training of the network uses.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d

from ccs_kornia.modules.detection.grid.grid_geometry import grid_spacing
from ccs_kornia.modules.detection.learned.gaussian_fit import gaussian_fit
from ccs_kornia.modules.detection.refine.patch_refine import level_size
from ccs_kornia.modules.detection.refine.saddle_refine import sample_bilinear
from ccs_kornia.runtime.checks import check_grey_images, check_points, check_tensor

__all__ = ["MAX_GAP", "SYMMETRY_STEPS", "symmetry_refine", "network_seeds", "differentiable_corners",
           "DifferentiableCorners"]

#: Gauss-Newton steps of :func:`symmetry_refine` by default (the detector's polish runs 4 after its saddle fit)
SYMMETRY_STEPS = 4
#: farthest (px) the differentiated estimator may land from the detector's corner for the corner to carry its gradient
MAX_GAP = 0.1


def _window(radius: torch.Tensor, rmax: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Offsets ``(P, 2)`` of half of a ``(2 rmax + 1)^2`` window (one of each pair ``+-d``) and weights ``(..., P)``: a
    Gaussian of width ``radius / 1.5`` cut at ``radius``, as the detector's polish."""
    steps = torch.arange(-rmax, rmax + 1, dtype=radius.dtype, device=radius.device)
    oy, ox = torch.meshgrid(steps, steps, indexing="ij")
    off = torch.stack([ox.reshape(-1), oy.reshape(-1)], -1)[: (2 * rmax + 1) ** 2 // 2]
    d2 = (off**2).sum(-1)
    r = radius[..., None]
    return off, torch.exp(-d2 / (2 * (r / 1.5) ** 2)) * (d2 <= r**2)


def symmetry_refine(
    image: torch.Tensor,
    corners: torch.Tensor,
    radius: torch.Tensor | float = 3.0,
    steps: int = SYMMETRY_STEPS,
    max_radius: int = 18,
    smooth_sigma: float = 1.0,
    max_step: float = 1.0,
) -> torch.Tensor:
    r"""Point-symmetry refinement of corners as a differentiable function of the pixels and of the start.

    Each step is the Gauss-Newton step of :math:`\min_c \sum_d w(d) (S(c + d) - S(c - d))^2` (``S``: the image
    smoothed by a Gaussian of ``smooth_sigma``; ``d`` over a window of ``radius``), bounded to ``max_step`` px: the
    polish of :func:`~ccs_kornia.modules.detection.refine.symmetry_refine.symmetry_polish`, written with whole-image
    ``grid_sample`` so that autograd follows it. No decision is taken: every corner takes every step.

    Args:
        image: :math:`(B, 1, H, W)` grey image in ``[0, 1]`` (any float dtype; double for ``gradcheck``).
        corners: :math:`(B, N, 2)` starting points (px), finite.
        radius: window radius (px), a float or :math:`(B, N)`, clamped to ``[1.5, max_radius]``; not differentiated.
        steps: Gauss-Newton steps (0 returns ``corners``).
        max_radius: largest window radius (sets the window's size).
        smooth_sigma: Gaussian smoothing of the image (px), 0 for none.
        max_step: largest move per step (px).

    Returns:
        :math:`(B, N, 2)` refined corners.

    Example:
        >>> img = torch.zeros(1, 1, 32, 32); img[..., :16, :16] = 1; img[..., 16:, 16:] = 1
        >>> symmetry_refine(img, torch.tensor([[[15.2, 16.1]]]), 6.0).round(decimals=2)
        tensor([[[15.5000, 15.5000]]])
    """
    check_grey_images(image, "image", min_side=0)
    check_points(corners, "corners", B=image.shape[0])
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}.")
    if steps == 0 or corners.shape[1] == 0:
        return corners
    dtype = torch.promote_types(image.dtype, corners.dtype)
    img, c = image.to(dtype), corners.to(dtype)
    if smooth_sigma > 0:
        k = 2 * int(round(3 * smooth_sigma)) + 1
        img = gaussian_blur2d(img, (k, k), (smooth_sigma, smooth_sigma), border_type="reflect")
    # the image and its central differences sampled together (the Jacobian of a sample is the sampled gradient)
    p = F.pad(img, (1, 1, 1, 1), mode="replicate")
    gx, gy = 0.5 * (p[..., 1:-1, 2:] - p[..., 1:-1, :-2]), 0.5 * (p[..., 2:, 1:-1] - p[..., :-2, 1:-1])
    src = torch.cat([img, gx, gy], 1)
    r = torch.as_tensor(radius, dtype=dtype, device=c.device).detach()
    r = (r.expand(c.shape[:2]) if r.dim() == 0 else r).nan_to_num(3.0).clamp(1.5, float(max_radius))
    rmax = int(math.ceil(float(r.max())))
    off, w = _window(r, rmax)  # (P, 2), (B, N, P)
    for _ in range(steps):
        plus = sample_bilinear(src, c[:, :, None, :] + off)  # (B, 3, N, P)
        minus = sample_bilinear(src, c[:, :, None, :] - off)
        res = plus[:, 0] - minus[:, 0]  # (B, N, P)
        jx, jy = plus[:, 1] - minus[:, 1], plus[:, 2] - minus[:, 2]  # d/dc of S(c + d) - S(c - d)
        axx, axy, ayy = (w * jx * jx).sum(-1), (w * jx * jy).sum(-1), (w * jy * jy).sum(-1)
        bx, by = (w * jx * res).sum(-1), (w * jy * res).sum(-1)
        det = axx * ayy - axy * axy
        good = det > 1e-12 * (axx + ayy).square().clamp_min(1e-30)
        det = torch.where(good, det, torch.ones_like(det))
        step = -torch.stack([(ayy * bx - axy * by) / det, (axx * by - axy * bx) / det], -1)
        # bounded moves; the bound's own derivative is the scale (a decision-free, piecewise smooth map)
        step = step * (max_step / step.norm(dim=-1, keepdim=True).clamp_min(max_step))
        c = c + torch.where(good[..., None], step, torch.zeros_like(step))
    return c.to(corners.dtype)


def _level(images: torch.Tensor, factor: float) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`~ccs_kornia.modules.detection.refine.patch_refine.resize_to_level` by torch's own differentiable resampling
    (its CPU fast path keeps cached matrices that autograd cannot save; the same values up to float rounding)."""
    h, w = images.shape[-2:]
    size = level_size((w, h), factor)
    if size == (h, w):
        level = images
    elif factor > 1:
        level = F.interpolate(images, size=size, mode="area")
    else:
        level = F.interpolate(images, size=size, mode="bilinear", align_corners=False)
    scale = torch.tensor([w / size[1], h / size[0]], dtype=torch.float64, device=images.device)
    return level, scale


def network_seeds(
    net: torch.nn.Module,
    images: torch.Tensor,
    corners: torch.Tensor,
    valid: torch.Tensor,
    factor: torch.Tensor | float = 1.0,
    fit_window: int = 7,
) -> torch.Tensor:
    r"""The network's sub-pixel estimate of given corners: its heatmap on the detection level of each image (with
    grad) and the Gaussian fit there, in a window centred on each (detached) corner, mapped to full resolution.

    Corners whose fit fails (no peak in the window: e.g. a corner the detector predicted from its neighbours) keep
    their (detached) input.

    Args:
        net: the heatmap network (:class:`~ccs_kornia.modules.detection.learned.heatmap_unet.CornerUNet`).
        images: :math:`(B, 1, H, W)` full-resolution images.
        corners: :math:`(B, N, 2)` corners at full resolution (px; NaN or invalid ones are left as they are).
        valid: :math:`(B, N)` bool.
        factor: full-resolution px per level px, a float or per image :math:`(B,)` (the detector's
            :class:`~ccs_kornia.modules.detection.learned.scale.ScaleSelector`).
        fit_window: odd window of the Gaussian fit.

    Returns:
        :math:`(B, N, 2)` seeds at full resolution, differentiable with respect to ``images`` and ``net``'s parameters.

    Example:
        >>> from ccs_kornia.modules.detection.learned.heatmap_unet import CornerUNet
        >>> net = CornerUNet(base_channels=4).eval()
        >>> img = torch.rand(1, 1, 32, 32)
        >>> network_seeds(net, img, torch.tensor([[[12.0, 15.0]]]), torch.tensor([[True]])).shape
        torch.Size([1, 1, 2])
    """
    for t in (*net.parameters(), *net.buffers()):
        if t.is_inference():  # converted under inference mode (run_heatmap's channels-last layout): a normal copy
            t.data = t.data.clone()
    b = images.shape[0]
    fac = torch.as_tensor(factor, dtype=torch.float64).flatten().cpu()
    fac = fac.expand(b) if fac.numel() == 1 else fac
    base = corners.detach().to(torch.float64)
    ok = valid & base.isfinite().all(-1)
    base = torch.where(ok[..., None], base, torch.zeros_like(base))
    out = base.clone()
    for value in fac.unique().tolist():
        rows = (fac == value).nonzero().flatten().to(images.device)
        level, scale = _level(images[rows], float(value))
        heat = net(level.to(next(net.parameters()).dtype)).to(torch.float64)
        level_pts = (base[rows] + 0.5) / scale - 0.5
        mu, _, fit_ok = gaussian_fit(heat, level_pts, ok[rows], fit_window)
        full = (mu + 0.5) * scale - 0.5
        out = out.index_put((rows,), torch.where(fit_ok[..., None], full, base[rows]))
    return out.to(corners.dtype)


def differentiable_corners(
    corners: torch.Tensor,
    valid: torch.Tensor,
    images: torch.Tensor,
    board_size: tuple[int, int],
    seeds: torch.Tensor | None = None,
    steps: int = SYMMETRY_STEPS,
    radius_factor: float = 0.3,
    max_radius: int = 18,
    max_gap: float = MAX_GAP,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The detector's corners with the gradient of the point-symmetry refinement started at ``seeds``.

    Returns ``c + (f - f.detach())`` with ``f = symmetry_refine(images, seeds, ...)``: the value of ``corners``
    exactly, the gradient of ``f`` (with respect to ``images`` and whatever ``seeds`` depends on). Invalid corners
    (``~valid`` or not finite) come back as they are, without gradient.

    Where ``f`` lands farther than ``max_gap`` px from the corner, ``f`` is not the estimate the detector made (a
    seed from a level the corner was not found on, a corner the detector took from another source or level) and its
    gradient would be another point's: ``f`` is then started at the detached corner instead (the pixels' gradient
    only), and where that too lands farther, the corner comes back without gradient (a decision, like the others:
    ``gap`` reports it). How many corners that concerns on the real sets: ``docs/gradients.md``.

    Args:
        corners: :math:`(B, N, 2)` the detector's corners (the values returned).
        valid: :math:`(B, N)` bool, the corners to differentiate.
        images: :math:`(B, 1, H, W)`.
        board_size: ``(cols, rows)``; the window is ``radius_factor`` times each corner's grid spacing (the detector's
            polish window: 1.5 x 0.2), at most ``max_radius`` px.
        seeds: :math:`(B, N, 2)` the refinement's start (default: ``corners``, detached: gradient to the pixels only),
            e.g. :func:`network_seeds`.
        steps: Gauss-Newton steps of :func:`symmetry_refine` (0: the gradient of ``seeds`` alone).
        max_gap: the farthest (px) the differentiated estimator may land from the corner (see above).

    Returns:
        ``(corners (B, N, 2), f - corners (B, N, 2))``: the differentiable corners and how far the differentiated
        estimator's value is from the detector's (detached; NaN where not valid; beyond ``max_gap`` where the corner
        carries no gradient).

    Example:
        >>> img = torch.zeros(1, 1, 40, 40); img[..., :20, :20] = 1; img[..., 20:, 20:] = 1
        >>> img = img.requires_grad_()
        >>> c = torch.tensor([[[19.5, 19.5]]])
        >>> out, gap = differentiable_corners(c, torch.tensor([[True]]), img, (1, 1), steps=2)
        >>> out.sum().backward(); bool(img.grad.abs().sum() > 0), bool(out.detach().equal(c))
        (True, True)
    """
    check_points(corners, "corners")
    check_tensor(valid, "valid", corners.shape[:2])
    ok = valid & corners.isfinite().all(-1)
    base = torch.where(ok[..., None], corners.detach(), torch.zeros_like(corners))
    start = base if seeds is None else torch.where(ok[..., None], seeds, base.to(seeds.dtype))
    with torch.no_grad():
        radius = torch.full_like(base[..., 0], 3.0)  # a corner without a grid neighbour: a 3 px window
        if board_size[0] * board_size[1] > 1:
            spacing = grid_spacing(base, ok, board_size)
            radius = torch.where(spacing.isfinite(), radius_factor * spacing, radius)
    f = symmetry_refine(images, start, radius, steps, max_radius).to(corners.dtype)
    far = ((f.detach() - base).norm(dim=-1) > max_gap) & ok
    if seeds is not None and bool(far.any()):
        f2 = symmetry_refine(images, base, radius, steps, max_radius).to(corners.dtype)
        f = torch.where(far[..., None], f2, f)
        far = ((f.detach() - base).norm(dim=-1) > max_gap) & ok
    grad = ok & ~far
    out = torch.where(grad[..., None], corners.detach() + (f - f.detach()), corners.detach())
    gap = torch.where(ok[..., None], f.detach() - corners.detach(), torch.full_like(base, float("nan")))
    return out, gap


class DifferentiableCorners(torch.nn.Module):
    r"""Module form: a detector's corners, made differentiable with respect to the images and to the heatmap network.

    ``forward(images, corners, valid, board_size, factor)`` gives :func:`differentiable_corners` started at
    :func:`network_seeds` (where ``net`` is given; otherwise at the detached corners).

    Args:
        net: the heatmap network, or ``None``.
        steps: refinement steps (0: the network's Gaussian-fit corner carries the gradient alone).
        fit_window: odd window of the Gaussian fit.

    Example:
        >>> img = torch.zeros(1, 1, 40, 40); img[..., :20, :20] = 1; img[..., 20:, 20:] = 1
        >>> out, gap = DifferentiableCorners()(img, torch.tensor([[[19.4, 19.6]]]), torch.tensor([[True]]), (1, 1))
        >>> out.shape, float(gap.abs().max()) < 0.2
        (torch.Size([1, 1, 2]), True)
    """

    def __init__(self, net: torch.nn.Module | None = None, steps: int = SYMMETRY_STEPS, fit_window: int = 7) -> None:
        super().__init__()
        self.net, self.steps, self.fit_window = net, int(steps), int(fit_window)

    def forward(self, images: torch.Tensor, corners: torch.Tensor, valid: torch.Tensor, board_size: tuple[int, int],
                factor: torch.Tensor | float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        seeds = None
        if self.net is not None:
            seeds = network_seeds(self.net, images, corners, valid, factor, self.fit_window)
        return differentiable_corners(corners, valid, images, board_size, seeds, self.steps)
