"""Sub-pixel refinement of chessboard corners on the image itself (batched, no per-corner loops).

Two estimators, both on a window whose size adapts to each corner's grid spacing:

* ``"gradient"``: the gradient-orthogonality fixed point of Förstner/OpenCV ``cornerSubPix``: every edge pixel's
  gradient is orthogonal to the vector from the corner, so the corner minimises ``sum w_i (g_i . (p_i - c))^2``, a
  2x2 linear solve per corner, iterated.
* ``"saddle"``: the corner of a chessboard is a saddle point of the (slightly smoothed) intensity; fit
  ``f = a x^2 + b xy + c y^2 + d x + e y + g`` by weighted least squares on the window and move to its stationary
  point (Lucchese & Mitra), iterated.
* ``"symmetric"`` (the default of :class:`CornerRefiner`): the saddle fit, then the point-symmetry polish of
  :mod:`~ccs_kornia.modules.detection.refine.symmetry_refine` on the same region (the saddle fit finds and verifies the
  corner, the polish is the precise estimate). Its saddle fit runs on two versions of each region, the smoothed
  image divided by its local mean (shading cancels) and the smoothed image alone; a board-wide vote with the
  incoming points picks the plain fit where the division fails across a board (strong motion blur).

All sample the image bilinearly at ``corner + offsets``: the window is centred on the current estimate each time.

The saddle fit smooths and normalises the image only where it looks: around every corner, a region that covers every
window the iterations can reach is blurred (two small matrix products per region, the separable Gaussian as banded
matrices over a patch gathered with the image's border rule), giving the values a whole-image blur would give there
at a fraction of the cost; its normal matrix, fixed by the window, is factorised once per corner.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ccs_kornia.modules._kernels import gaussian_kernel1d
from ccs_kornia.modules.detection.grid.grid_geometry import grid_spacing
from ccs_kornia.modules.detection.refine.symmetry_refine import (
    WIDE_MAX_MOVE,
    WIDE_WINDOW,
    symmetry_polish,
    wide_allowed,
    wide_polish,
    wide_vote,
)
from ccs_kornia.runtime.checks import check_grey_images, check_points

__all__ = [
    "METHODS",
    "POLISH_PLAIN_MARGIN",
    "POLISH_WINDOW",
    "CornerRefiner",
    "refine_corners",
    "saddle_source",
    "sample_bilinear",
    "sample_window",
    "weighted_window",
]

#: refinement methods of :func:`refine_corners`
METHODS = ("saddle", "symmetric", "gradient")
#: the symmetry polish's window radius, in saddle-fit windows (0.3 x the grid spacing with the default 0.2)
POLISH_WINDOW = 1.5
#: Gauss-Newton steps of the polish (the saddle fit leaves it a few hundredths of a px to go)
POLISH_ITERATIONS = 4
#: farthest the polish may move a saddle point (px); beyond it the saddle point is kept
POLISH_MAX_MOVE = 2.0
#: the saddle fit on the plain source replaces the one on the normalised source where the latter moved more than
#: DUAL_VOTE_RATIO times as far from the incoming point, plus DUAL_VOTE_MARGIN px
DUAL_VOTE_RATIO = 3.0
DUAL_VOTE_MARGIN = 0.75
#: ... on a board where at least this fraction of the corners vote so (a source failing across a whole board; single
#: corners disagree where the incoming point itself is a few px off, e.g. at a fisheye's rim)
DUAL_VOTE_BOARD_FRACTION = 0.2
#: the plain source's polish is kept unless its asymmetry exceeds the normalised one's by this factor
POLISH_PLAIN_MARGIN = 1.5


def _central_differences(image: torch.Tensor) -> torch.Tensor:
    """kornia's ``spatial_gradient(mode="diff", normalized=False)`` of (B,1,H,W) -> (B,2,H,W), the same values by two
    subtractions (its one-in two-out 3x3 convolution is several times slower on CPU: ``docs/measurements.md``)."""
    p = F.pad(image, (1, 1, 1, 1), mode="replicate")
    return torch.cat([p[..., 1:-1, 2:] - p[..., 1:-1, :-2], p[..., 2:, 1:-1] - p[..., :-2, 1:-1]], 1)


def sample_bilinear(image: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``image`` :math:`(B, C, H, W)` at pixel points :math:`(B, N, P, 2)` (the project's pixel
    convention) -> :math:`(B, C, N, P)`; outside the image, the nearest border value. Differentiable with respect to
    both (``grid_sample``): the refinements, the X-junction test and the differentiable corners all read the image
    through it.

    Example:
        >>> img = torch.arange(12.0).reshape(1, 1, 3, 4)
        >>> sample_bilinear(img, torch.tensor([[[[1.5, 1.0], [-5.0, 0.0]]]]))
        tensor([[[[5.5000, 0.0000]]]])
    """
    h, w = image.shape[-2:]
    gx = points[..., 0] * (2.0 / max(w - 1, 1)) - 1.0
    gy = points[..., 1] * (2.0 / max(h - 1, 1)) - 1.0
    return F.grid_sample(image, torch.stack([gx, gy], -1), mode="bilinear", padding_mode="border", align_corners=True)


def _border_index(idx: torch.Tensor, size: int, mode: str) -> torch.Tensor:
    """Pixel index of ``idx`` under a border rule: ``"reflect"`` (torch's, no edge repeat) or ``"replicate"``."""
    if mode == "reflect" and size > 1:
        idx = torch.where(idx < 0, -idx, idx)
        idx = torch.where(idx > size - 1, 2 * (size - 1) - idx, idx)
    return idx.clamp(0, size - 1)


def _gather_regions(img: torch.Tensor, bi: torch.Tensor, ys: torch.Tensor, xs: torch.Tensor) -> torch.Tensor:
    """``img[bi, 0, ys[:, :, None], xs[:, None, :]]`` (rows ``ys`` (M, P), columns ``xs`` (M, Q)) as one faster ``take``."""
    h, w = img.shape[-2:]
    lin = (bi[:, None, None] * (h * w) + ys[:, :, None] * w) + xs[:, None, :]
    return img.reshape(-1).take(lin)


def _blurred_regions(img: torch.Tensor, bi: torch.Tensor, top_left: torch.Tensor, q: int, sigma: float,
                     mode: str) -> torch.Tensor:
    """``q x q`` regions (top-left pixel ``top_left`` (M, 2) xy of image ``bi`` (M,)) of the image blurred as
    kornia's ``gaussian_blur2d`` blurs the whole image (kernel ``2 round(3 sigma) + 1``, border rule ``mode``), without
    blurring the whole image: the patch that feeds the region, times banded (Toeplitz) matrices of the kernel on both
    sides. Returns :math:`(M, q, q)`."""
    h, w = img.shape[-2:]
    dev = img.device
    if not sigma > 0:
        ys = _border_index(top_left[:, 1, None] + torch.arange(q, device=dev), h, mode)
        xs = _border_index(top_left[:, 0, None] + torch.arange(q, device=dev), w, mode)
        return _gather_regions(img, bi, ys, xs)
    k = 2 * int(round(3 * sigma)) + 1
    m = k // 2
    span = torch.arange(q + 2 * m, device=dev)
    ys = _border_index(top_left[:, 1, None] - m + span, h, mode)
    xs = _border_index(top_left[:, 0, None] - m + span, w, mode)
    patch = _gather_regions(img, bi, ys, xs)  # (M, q + 2m, q + 2m)
    g = gaussian_kernel1d(k, sigma, dev, img.dtype)
    band = torch.zeros(q + 2 * m, q, device=dev, dtype=img.dtype)
    taps = torch.arange(k, device=dev)[:, None] + torch.arange(q, device=dev)[None, :]  # (k, q) patch rows
    band[taps, torch.arange(q, device=dev).expand(k, q)] = g[:, None].expand(k, q)
    return band.T @ (patch @ band)


def saddle_source(img: torch.Tensor, bi: torch.Tensor, top_left: torch.Tensor, q: int, smooth_sigma: float,
                   normalize_sigma: float, with_plain: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """The saddle fit's input image (smoothed, divided by the local mean) on ``q x q`` regions, :math:`(M, 1, q, q)`
    (with ``with_plain``, also the smoothed regions before the division): region ``m`` of image ``bi[m]`` of ``img``
    :math:`(B, 1, H, W)`, top-left pixel ``top_left[m]`` :math:`(M, 2)` xy. The corner uncertainty reads the same
    source as the refinement.

    Equal, up to float rounding, to ``refine_corners``' whole-image source cropped there: pixels outside the image
    repeat the nearest in-image value, as bilinear sampling with ``padding_mode="border"`` reads it."""
    src = plain = _blurred_regions(img, bi, top_left, q, smooth_sigma, "reflect")
    if normalize_sigma > 0:
        src = plain / _blurred_regions(img, bi, top_left, q, normalize_sigma, "replicate").clamp_min(1e-3)
    h, w = img.shape[-2:]
    # regions over the image's border (the others stay): local index of the clamped (in-image) pixel of every pixel
    edge = ((top_left < 0).any(1) | (top_left[:, 1] + q > h) | (top_left[:, 0] + q > w)).nonzero().flatten()
    tl, span = top_left[edge], torch.arange(q, device=img.device)
    iy = ((tl[:, 1, None] + span).clamp(0, h - 1) - tl[:, 1, None]).clamp(0, q - 1)[:, :, None].expand(-1, -1, q)
    ix = ((tl[:, 0, None] + span).clamp(0, w - 1) - tl[:, 0, None]).clamp(0, q - 1)[:, None, :].expand(-1, q, -1)

    def clamp(x: torch.Tensor) -> torch.Tensor:  # in place: x is this function's own
        if edge.numel():
            x[edge] = x[edge].gather(1, iy).gather(2, ix)
        return x[:, None]

    return (clamp(src), clamp(plain) if normalize_sigma > 0 else None) if with_plain else clamp(src)


def refine_corners(
    image: torch.Tensor,
    corners: torch.Tensor,
    valid: torch.Tensor | None = None,
    radius: torch.Tensor | float = 5.0,
    method: str = "saddle",
    iterations: int = 5,
    max_radius: int = 12,
    smooth_sigma: float = 1.0,
    normalize_sigma: float = 6.0,
    return_ok: bool = False,
    board_size: tuple[int, int] | None = None,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Refine corner positions on the image.

    Args:
        image: :math:`(B, 1, H, W)` grey image in ``[0, 1]``.
        corners: :math:`(B, N, 2)` initial corners (pixels).
        valid: :math:`(B, N)` bool; invalid corners are returned unchanged.
        radius: window half-size in px, a float or a :math:`(B, N)` tensor (e.g. ``0.45 * grid_spacing``),
            clamped to ``[1.5, max_radius]``.
        method: ``"saddle"``, ``"symmetric"`` (the saddle fit, then :func:`symmetry_polish`; its verdict is the
            saddle fit's) or ``"gradient"``.
        iterations: fixed-point iterations (re-centring the window each time).
        max_radius: the largest window half-size (sets the sampling grid size).
        smooth_sigma: Gaussian pre-smoothing (px) for ``"saddle"``.
        normalize_sigma: for ``"saddle"``, divide by the local mean at this scale (px) to cancel smooth
            shading; 0 disables it. Measured on rendered 640x480 boards (window 0.25 x spacing): mean error
            0.006 px clean, 0.033 px under strong shading + specular light, against 0.078 px without it.
        return_ok: also return a :math:`(B, N)` mask of corners whose last iteration found a proper
            saddle (or gradient solution) and that stayed within their radius.
        board_size: ``(cols, rows)`` of whole boards in grid order: with ``"symmetric"``, the wide polish
            (:func:`~ccs_kornia.modules.detection.refine.symmetry_refine.wide_polish`) is then kept where the board's rows and
            columns are straight (:func:`wide_allowed`). ``None`` (e.g. a coarse step aiming at the next window): none.

    Returns:
        :math:`(B, N, 2)` refined corners (one moving beyond its radius keeps its input: the window lost it); with
        ``return_ok``, also the mask above.

    Example:
        >>> img = torch.zeros(1, 1, 32, 32); img[..., :16, :16] = 1; img[..., 16:, 16:] = 1
        >>> refine_corners(img, torch.tensor([[[15.0, 16.2]]]), radius=6.0).round(decimals=2)
        tensor([[[15.5000, 15.5000]]])
    """
    check_grey_images(image, "image", min_side=0)
    check_points(corners, "corners", B=image.shape[0])
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}.")
    b, n = corners.shape[:2]
    if n == 0:
        return (corners, torch.zeros(b, 0, dtype=torch.bool, device=corners.device)) if return_ok else corners
    dev, dt = corners.device, torch.float32
    img = image.to(dt)
    if valid is None:
        valid = torch.ones(b, n, dtype=torch.bool, device=dev)
    r = torch.as_tensor(radius, dtype=dt, device=dev)
    r = r.expand(b, n) if r.dim() == 0 else r
    r = torch.nan_to_num(r, nan=5.0, posinf=float(max_radius)).clamp(1.5, float(max_radius))
    if method in ("saddle", "symmetric"):
        return _refine_saddle(img, corners, valid, r, max_radius, iterations, smooth_sigma, normalize_sigma, return_ok,
                              polish=method == "symmetric", board_size=board_size)
    return _refine_gradient(img, corners, valid, r, iterations, return_ok)


def _refine_gradient(img, corners, valid, r, iterations, return_ok):
    """The gradient branch of :func:`refine_corners` on the images that have valid corners, each image's valid
    corners first (other corners are returned unchanged, so they are not computed)."""
    b, n = corners.shape[:2]
    dev, dt = corners.device, torch.float32
    start = corners.to(dt)
    valid = valid & torch.isfinite(start).all(-1)
    count = valid.sum(1)
    k = int(count.max()) if b else 0
    ok_out = torch.zeros(b, n, dtype=torch.bool, device=dev)
    if k == 0:
        return (corners, ok_out) if return_ok else corners
    rows = (count > 0).nonzero().flatten()
    order = torch.argsort((~valid[rows]).to(torch.int8), dim=1, stable=True)[:, :k]  # valid corners first
    c0 = start[rows].gather(1, order[..., None].expand(-1, -1, 2))
    sub_valid = valid[rows].gather(1, order)
    rr = r[rows].gather(1, order)
    rmax = int(torch.ceil(rr[sub_valid].max()).item())
    off, wgt = weighted_window(rr, rmax)
    src = _central_differences(img[rows])  # (b',2,H,W): gx, gy in px units
    c = c0.clone()
    ok = torch.zeros_like(sub_valid)
    step = torch.zeros_like(rr)
    for _ in range(iterations):
        pts = c[:, :, None, :] + off[None, None]  # (b',K,P,2)
        s = sample_bilinear(src, pts)  # (b',C,K,P)
        gx, gy = s[:, 0], s[:, 1]
        a11 = (wgt * gx * gx).sum(-1)
        a12 = (wgt * gx * gy).sum(-1)
        a22 = (wgt * gy * gy).sum(-1)
        px, py = pts[..., 0], pts[..., 1]
        b1 = (wgt * (gx * gx * px + gx * gy * py)).sum(-1)
        b2 = (wgt * (gx * gy * px + gy * gy * py)).sum(-1)
        det = a11 * a22 - a12 * a12
        ok = det.abs() > 1e-12
        det = torch.where(ok, det, torch.ones_like(det))
        new = torch.stack([(a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det], -1)
        step = (new - c).norm(dim=-1)
        keep = sub_valid & ok & torch.isfinite(new).all(-1) & (step <= rr)
        c = torch.where(keep[..., None], new, c)
    inside = sub_valid & ((c - c0).norm(dim=-1) <= rr)
    c = torch.where(inside[..., None], c, c0)
    out = start.clone()
    out[rows] = out[rows].scatter(1, order[..., None].expand(-1, -1, 2), c)
    ok_out[rows] = ok_out[rows].scatter(1, order, inside & ok & (step <= rr))
    out = out.to(corners.dtype)
    return (out, ok_out) if return_ok else out


def sample_window(src: torch.Tensor, centre: torch.Tensor, rmax: int) -> torch.Tensor:
    """Bilinear samples of regions ``src`` :math:`(M, 1, q, q)` at ``centre`` :math:`(M, 2)` (region pixels) ``+ off``
    for the offsets of the ``(2 rmax + 1)^2`` window (:func:`weighted_window`), :math:`(M, P)`: whole-pixel offsets
    share their centre's fraction, so the window is a blend of shifted crops (``grid_sample``'s values,
    ``align_corners=True``, while inside). The sampler of the symmetry polish
    (:mod:`~ccs_kornia.modules.detection.refine.symmetry_refine`) and of the corner uncertainty.

    Example:
        >>> src = torch.arange(100.0).reshape(1, 1, 10, 10)
        >>> sample_window(src, torch.tensor([[4.5, 4.0]]), 1).reshape(3, 3)
        tensor([[33.5000, 34.5000, 35.5000],
                [43.5000, 44.5000, 45.5000],
                [53.5000, 54.5000, 55.5000]])
    """
    m, q, side = src.shape[0], src.shape[-1], 2 * rmax + 1
    base = torch.floor(centre)
    # top-left pixel of the (side + 1)^2 crop, kept inside the region
    corner = base.long() - rmax
    start = corner.clamp(0, q - side - 1)
    frac = torch.where(corner == start, centre - base, (centre - (start + rmax).to(centre)).clamp(0, 1))
    span = torch.arange(side + 1, device=src.device)
    # the crop's flat indices: its offsets in a row-major region (one small grid) shifted by its top-left pixel's
    idx = (start[:, 1] * q + start[:, 0])[:, None] + (span[:, None] * q + span[None, :]).reshape(1, -1)
    crop = src.reshape(m, q * q).gather(1, idx).reshape(m, side + 1, side + 1)
    fx, fy = frac[:, 0, None, None], frac[:, 1, None, None]
    # each row blended along x once, then pairs of rows along y (the same values as 2x2 blends, a third fewer ops)
    rows = crop[:, :, :-1] + fx * (crop[:, :, 1:] - crop[:, :, :-1])
    return (rows[:, :-1] + fy * (rows[:, 1:] - rows[:, :-1])).reshape(m, side * side)


def weighted_window(r: torch.Tensor, rmax: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Offsets :math:`(P, 2)` of a ``(2 rmax + 1)^2`` window (row-major, xy) and the weights :math:`(..., P)` of radii
    ``r`` :math:`(...)`: a Gaussian of width ``r / 1.5`` cut at ``r`` (far pixels belong to other corners). The
    window of the saddle fit, the symmetry polish and the corner uncertainty.

    Example:
        >>> off, w = weighted_window(torch.tensor([1.0]), 1)
        >>> off.shape, (w > 0).sum().item()
        (torch.Size([9, 2]), 5)
    """
    offs = torch.arange(-rmax, rmax + 1, device=r.device, dtype=r.dtype)
    oy, ox = torch.meshgrid(offs, offs, indexing="ij")
    off = torch.stack([ox.reshape(-1), oy.reshape(-1)], -1)  # (P,2)
    d2 = (off**2).sum(-1)  # (P,)
    return off, torch.exp(-d2 / (2 * (r[..., None] / 1.5) ** 2)) * (d2 <= r[..., None] ** 2)


def _refine_saddle(img, corners, valid, r, max_radius, iterations, smooth_sigma, normalize_sigma, return_ok,
                   polish: bool = False, max_elements: int = 1 << 22, board_size: tuple[int, int] | None = None):
    """The saddle branch of :func:`refine_corners`, on the valid corners only, each on its own region. Corners are
    grouped by radius; a group's window side follows its largest radius (weights are zero beyond a corner's own radius).
    With ``polish`` (method ``"symmetric"``), the saddle fit's point (and its verdict, ``ok``) is then polished by
    :func:`symmetry_polish` on the same region in a window :data:`POLISH_WINDOW` times wider, then (``wide``) by
    :func:`wide_polish` in one :data:`WIDE_WINDOW` times wider (with ``board_size``), kept per board by
    :func:`wide_vote` where the lines are straight (:func:`wide_allowed`)."""
    b, n = corners.shape[:2]
    dev, dt = corners.device, torch.float32
    start = corners.to(dt)
    out = start.clone()
    ok_out = torch.zeros(b, n, dtype=torch.bool, device=dev)
    sel = (valid & torch.isfinite(start).all(-1)).flatten().nonzero().flatten()
    if sel.numel() == 0:
        return (corners, ok_out) if return_ok else corners
    flat_start, flat_r = start.reshape(-1, 2), r.reshape(-1)
    polish_r = (POLISH_WINDOW * flat_r).clamp(2.5, POLISH_WINDOW * max_radius) if polish else None
    wide = polish and board_size is not None
    wide_r = (WIDE_WINDOW * flat_r).clamp(2.5, WIDE_WINDOW * max_radius) if wide else polish_r
    if wide:
        wide_out, agree_out, tried_out = out.clone(), ok_out.clone(), ok_out.clone()
    for group in _radius_groups(sel, flat_r[sel]):
        rmax = int(torch.ceil(flat_r[group].max()).item())
        off, _ = weighted_window(flat_r[:1], rmax)
        # the region covers every window within rmax + 1 px of the starting pixel (a corner that moves further is
        # returned unchanged), and the polishes' windows around the saddle point plus their moves and a border
        half = 2 * rmax + 2
        if polish:
            polish_max, wide_max = (int(torch.ceil(x[group].max()).item()) for x in (polish_r, wide_r))
            moves = POLISH_MAX_MOVE + (WIDE_MAX_MOVE if wide_max > polish_max else 0.0)
            half = max(half, rmax + max(polish_max, wide_max) + int(math.ceil(moves)) + 2)
        q = 2 * half + 1
        pad = 2 * int(round(3 * max(smooth_sigma, normalize_sigma))) + 1
        chunk = max(1, max_elements // ((q + pad) ** 2))
        x, y = off[:, 0], off[:, 1]
        basis = torch.stack([x * x, x * y, y * y, x, y, torch.ones_like(x)], -1)  # (P,6)
        for part in group.split(chunk):
            c, ok, *wide_part = _saddle_group(img, flat_start[part], flat_r[part], part // n, rmax, half, basis,
                                              iterations, smooth_sigma, normalize_sigma,
                                              None if polish_r is None else (polish_r[part], polish_max, wide_r[part],
                                                                             wide_max))
            out.view(-1, 2)[part] = c
            ok_out.view(-1)[part] = ok
            if wide_part:
                wide_out.view(-1, 2)[part], agree_out.view(-1)[part], tried_out.view(-1)[part] = wide_part
    if wide:
        tried_out &= wide_allowed(out, ok_out, board_size)
        out = torch.where(wide_vote(agree_out & tried_out, tried_out)[..., None], wide_out, out)
    out = out.to(corners.dtype)
    return (out, ok_out) if return_ok else out


def _radius_groups(sel: torch.Tensor, radius: torch.Tensor, min_group: int = 128) -> list[torch.Tensor]:
    """``sel`` split into groups of similar radius (half-octaves of ``radius``, smallest first), each of at least
    ``min_group`` corners except the last: a group's window and region follow its own largest radius, so a batch's
    far, small corners do not pay for its near, large ones, while a single board (a few dozen corners) stays one group
    (every group costs a few ms of fixed overhead)."""
    octave = torch.ceil(2 * torch.log2(radius.clamp_min(1.0))).long()
    order = torch.argsort(octave, stable=True)
    keys, counts = torch.unique_consecutive(octave[order], return_counts=True)
    groups, start, size = [], 0, 0
    for count in counts.tolist():
        size += count
        if size >= min_group:
            groups.append(sel[order[start:start + size]])
            start, size = start + size, 0
    if size:
        groups.append(sel[order[start:start + size]])
    return groups


def _saddle_iterations(src, c0, rr, top_left, bw, lu, piv, rmax, iterations):
    """Fixed-point saddle fits of ``M`` corners on their regions ``src`` (M, q, q): ``(corners (M, 2), ok (M,))``."""
    dt = torch.float32
    c = c0.clone()
    ok = torch.zeros(c.shape[0], dtype=torch.bool, device=c.device)
    step = torch.zeros(c.shape[0], dtype=dt, device=c.device)
    for _ in range(iterations):
        f = sample_window(src, c - top_left.to(dt), rmax)  # (M,P)
        atb = torch.einsum("mpi,mp->mi", bw, f)
        coef = torch.linalg.lu_solve(lu, piv, atb.double().unsqueeze(-1)).squeeze(-1).to(dt)
        a, bb, cc, d, e = coef.unbind(-1)[:5]
        # stationary point: [2a b; b 2c] [x y]^T = -[d e]^T ; a saddle has a negative determinant
        det = 4 * a * cc - bb * bb
        ok = det < -1e-12
        det = torch.where(ok, det, -torch.ones_like(det))
        sx = (-2 * cc * d + bb * e) / det
        sy = (-2 * a * e + bb * d) / det
        new = c + torch.stack([sx, sy], -1)
        step = (new - c).norm(dim=-1)
        keep = ok & torch.isfinite(new).all(-1) & (step <= rr)
        c = torch.where(keep[..., None], new, c)
    inside = (c - c0).norm(dim=-1) <= rr
    return torch.where(inside[..., None], c, c0), inside & ok & (step <= rr)


def _saddle_group(img, c0, rr, image_index, rmax, half, basis, iterations, smooth_sigma, normalize_sigma, polish):
    """Saddle fit (and polish, with ``polish = (radii, window half-size, wide radii, wide half-size)``) of one group
    of corners on their regions: ``(corners (M, 2), ok (M,))``, and with a wider wide window the wide polish's
    ``(corners (M, 2), agree (M,), tried (M,))`` (see :func:`wide_polish`)."""
    dev, dt = c0.device, torch.float32
    q = 2 * half + 1
    bw = basis[None] * weighted_window(rr, rmax)[1][..., None]  # (M,P,6)
    ata = torch.einsum("mpi,pj->mij", bw, basis) + 1e-9 * torch.eye(6, device=dev, dtype=dt)
    # the window moves with the corner but its weights do not: one factorisation per corner
    lu, piv = torch.linalg.lu_factor(ata.double())
    top_left = c0.round().long() - half
    src, plain = saddle_source(img, image_index, top_left, q, smooth_sigma, normalize_sigma, with_plain=True)
    m = c0.shape[0]
    dual = polish is not None and plain is not None
    if dual:  # both sources at once: (2M, q, q), the normalised first
        src, c0, rr, bw, top_left = (torch.cat([src, plain]), c0.repeat(2, 1), rr.repeat(2), bw.repeat(2, 1, 1),
                                     top_left.repeat(2, 1))
        lu, piv = lu.repeat(2, 1, 1), piv.repeat(2, 1)
    c, ok = _saddle_iterations(src, c0, rr, top_left, bw, lu, piv, rmax, iterations)
    plain_chosen = torch.zeros(m, dtype=torch.bool, device=dev)
    if dual:
        # three estimates vote: the incoming point, the fit on the normalised source and the fit on the plain one.
        # Where the normalised fit leaves the incoming point while the plain fit stays with it, the division has
        # reshaped the junction (strong motion blur) and the plain fit is kept. The two fits also differ on strongly
        # curved fisheye squares, with both near the incoming point: there the normalised fit stays; and a lone
        # corner can be a few px off at the coarse level, hence the board-wide quorum (docs/measurements.md).
        cn, cp, okn, okp = c[:m], c[m:], ok[:m], ok[m:]
        dn, dp = (cn - c0[:m]).norm(dim=-1), (cp - c0[m:]).norm(dim=-1)
        plain_chosen = okp & (dn > DUAL_VOTE_RATIO * dp + DUAL_VOTE_MARGIN)
        votes = torch.zeros(int(image_index.max()) + 1, device=dev).index_add_(0, image_index, plain_chosen.float())
        total = torch.zeros_like(votes).index_add_(0, image_index, torch.ones_like(votes[image_index]))
        plain_chosen &= (votes / total.clamp_min(1))[image_index] >= DUAL_VOTE_BOARD_FRACTION
        c, ok = torch.where(plain_chosen[:, None], cp, cn), okn | plain_chosen
        both, src, c0, rr, top_left = src, src[:m], c0[:m], rr[:m], top_left[:m]
    if polish is not None:
        pr, polish_max, wr, wide_max = polish
        reach = pr.clamp_max(POLISH_MAX_MOVE)
        # two sources per corner: the normalised one cancels shading (docs/measurements.md), the plain one keeps
        # small squares, board borders and real lenses exact (the local mean sees the next square or the background
        # there)
        w, local = weighted_window(pr, polish_max)[1], c - top_left.to(dt)
        k = 1 if plain is None else 2  # both sources in one call (half the small operations; the same values)
        pb, mb, ab = symmetry_polish(src if k == 1 else both, local.repeat(k, 1), reach.repeat(k), polish_max,
                                     sample_window, w.repeat(k, 1), POLISH_ITERATIONS)
        polished, moved, asym, p2, m2, a2 = pb[:m], mb[:m], ab[:m], pb[m:], mb[m:], ab[m:]
        if plain is not None:
            # the normalised source must be clearly more symmetric to win: where the two are close, the division's
            # own reshaping of the junction outweighs the shading it removes (docs/measurements.md)
            better = m2 & (~moved | (a2 < POLISH_PLAIN_MARGIN * asym) | plain_chosen)
            polished, asym = torch.where(better[:, None], p2, polished), torch.where(better, a2, asym)
            src = torch.where(better[:, None, None, None], plain, src)
            moved = moved | m2
        c = torch.where((ok & moved)[..., None], polished + top_left.to(dt), c)
        if wide_max > polish_max:
            wide, agree = wide_polish(src, polished, moved, asym, wr.clamp_max(WIDE_MAX_MOVE), wide_max, sample_window,
                                      weighted_window(wr, wide_max)[1])
            return c, ok, wide + top_left.to(dt), agree & ok, ok & moved
    return c, ok


class CornerRefiner(torch.nn.Module):
    """Module wrapper of :func:`refine_corners` with the window set from the grid spacing.

    The default window (0.2 x the distance to the nearest grid neighbour) was chosen on the real sets: larger windows
    see the curvature of strongly distorted lines and raise the calibration RMS of a strongly distorted lens; on
    renders 0.2-0.3 are equivalent (``docs/measurements.md``).

    Args:
        method: ``"symmetric"`` (default: saddle fit + point-symmetry polish), ``"saddle"`` or ``"gradient"``.
        radius_factor: window half-size as a fraction of the distance to the nearest grid neighbour.
        iterations: fixed-point iterations.
        max_radius: largest window half-size in px.
        wide: the wide polish of ``"symmetric"`` (off where the corners are refined again at a finer resolution).
    """

    def __init__(
        self,
        method: str = "symmetric",
        radius_factor: float = 0.2,
        iterations: int = 5,
        max_radius: int = 12,
        smooth_sigma: float = 1.0,
        normalize_sigma: float = 6.0,
        wide: bool = True,
    ) -> None:
        super().__init__()
        self.wide = wide
        self.smooth_sigma = smooth_sigma
        self.normalize_sigma = normalize_sigma
        self.method = method
        self.radius_factor = radius_factor
        self.iterations = iterations
        self.max_radius = max_radius

    def forward(
        self,
        image: torch.Tensor,
        corners: torch.Tensor,
        valid: torch.Tensor,
        board_size: tuple[int, int],
        return_ok: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        spacing = grid_spacing(corners, valid, board_size)
        radius = self.radius_factor * spacing
        return refine_corners(
            image, corners, valid, radius, self.method, self.iterations, self.max_radius,
            self.smooth_sigma, self.normalize_sigma, return_ok, board_size if self.wide else None,
        )
