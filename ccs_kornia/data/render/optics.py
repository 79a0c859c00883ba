"""Camera optics and lighting for the renderer: blur scaled to the square size, a realistic point spread and
gamma, glare and shadows, all on ``(B, 1, H, W)`` images in linear light, memory-bounded on big images.

A camera sees in this order (:func:`apply_optics`): light on the board (soft shadows, a specular glare whose
core saturates), the lens' defocus or the camera's motion (box, Gaussian or motion blur whose width is a
fraction of the square size in pixels, so the blur looks the same on 8 px and 300 px squares), the optical
point spread (a 0.3-1 px Gaussian), sensor noise, saturation at 1, the tone curve (``I ** (1 / gamma)``) and
JPEG. Per-image parameters are drawn from a ``torch.Generator`` (CPU draws, so a seed gives the same images on
every device).

Blur widths ``w`` (px), all three with the same spread (standard deviation ``w / sqrt(12)`` along the blur):
*box*: a ``w x w`` box with anti-aliased (fractional) edges; *gaussian*: sigma ``w / sqrt(12)``; *motion*: a
segment of length ``w`` at a random angle. Kernels up to 15 px wide are applied with
``conv2d`` in bands of rows; wider ones with FFTs on overlapping tiles, so memory stays bounded.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "BLUR_KINDS",
    "square_size_px",
    "blur_kernel",
    "gaussian_kernel",
    "convolve",
    "scaled_blur",
    "psf_and_gamma",
    "glare",
    "shadows",
    "apply_optics",
]

#: blur kinds of :func:`scaled_blur`
BLUR_KINDS: tuple[str, ...] = ("none", "box", "gaussian", "motion")
_TILE = 1024
_DIRECT_MAX = 15


def _u(g: torch.Generator, n: int, rng, dtype=torch.float64) -> Tensor:
    if isinstance(rng, (int, float)):
        return torch.full((n,), float(rng), dtype=dtype)
    lo, hi = float(rng[0]), float(rng[1])
    return lo + (hi - lo) * torch.rand(n, generator=g, dtype=dtype)


def square_size_px(corners: Tensor, valid: Tensor, board_size: Tensor) -> Tensor:
    """Median distance (px) between neighbouring valid corners along rows and columns, per view ``(B,)``.

    Args:
        corners: :math:`(B, N, 2)` grid order; valid: :math:`(B, N)`; board_size: :math:`(B, 2)` ``(cols, rows)``.
    """
    b, n = valid.shape
    idx = torch.arange(n, device=corners.device).unsqueeze(0)
    cols = board_size[:, 0:1].to(corners.device)
    rows = board_size[:, 1:2].to(corners.device)
    parts = []
    for step, has in ((1, torch.remainder(idx, cols) < cols - 1), (cols, idx + cols < cols * rows)):
        nb = (idx + step).clamp_max(n - 1).expand(b, -1)
        both = has & valid & valid.gather(1, nb)
        d = (corners.gather(1, nb.unsqueeze(-1).expand(-1, -1, 2)) - corners).norm(dim=-1).double()
        parts.append(torch.where(both, d, torch.full_like(d, math.nan)))
    return torch.cat(parts, -1).nanmedian(-1).values.nan_to_num(0.0).cpu()


def blur_kernel(kind: str, width: float, angle: float = 0.0) -> Tensor:
    """Normalised 2-D blur kernel ``(k, k)`` float32, ``k`` odd (``(1, 1)`` for no blur).

    Args:
        kind: one of :data:`BLUR_KINDS`.
        width: box side, motion length, or ``sqrt(12)`` x the Gaussian sigma (the same spread), in px.
        angle: motion direction (radians).

    Example:
        >>> blur_kernel("box", 3.0).shape, round(float(blur_kernel("motion", 10.0, 0.3).sum()), 6)
        (torch.Size([3, 3]), 1.0)
    """
    if kind not in BLUR_KINDS:
        raise ValueError(f"Unknown blur {kind!r}; expected one of {BLUR_KINDS}.")
    w = float(width)
    if kind == "none" or w <= 1e-3:
        return torch.ones(1, 1)
    if kind == "box":
        half = max(0, math.ceil(w / 2 - 0.5 - 1e-9))
        t = torch.arange(-half, half + 1, dtype=torch.float64)
        # overlap of each pixel [t - 1/2, t + 1/2] with the box [-w/2, w/2]
        k1 = (torch.minimum(t + 0.5, torch.tensor(w / 2)) - torch.maximum(t - 0.5, torch.tensor(-w / 2))).clamp_min(0)
        k = k1[:, None] * k1[None, :]
    elif kind == "gaussian":
        sigma = w / math.sqrt(12.0)
        half = max(1, math.ceil(3.5 * sigma))
        t = torch.arange(-half, half + 1, dtype=torch.float64)
        k1 = torch.exp(-0.5 * (t / sigma) ** 2)
        k = k1[:, None] * k1[None, :]
    else:
        half = math.ceil(w / 2) + 1
        size = 2 * half + 1
        s = torch.linspace(-w / 2, w / 2, max(2, int(math.ceil(w * 8)) + 1), dtype=torch.float64)
        x, y = s * math.cos(angle) + half, s * math.sin(angle) + half
        k = torch.zeros(size, size, dtype=torch.float64)
        x0, y0 = x.floor(), y.floor()
        for dx in (0, 1):
            for dy in (0, 1):
                wgt = (1 - (x - x0 - dx).abs()) * (1 - (y - y0 - dy).abs())
                k.index_put_(((y0 + dy).long(), (x0 + dx).long()), wgt, accumulate=True)
    return (k / k.sum()).float()


def gaussian_kernel(sigma: float) -> Tensor:
    """Normalised Gaussian kernel of standard deviation ``sigma`` px (``(1, 1)`` below 0.05 px)."""
    return blur_kernel("gaussian", math.sqrt(12.0) * sigma) if sigma > 0.05 else torch.ones(1, 1)


def _conv_one(img: Tensor, kernel: Tensor, tile: int = _TILE) -> Tensor:
    """``img`` ``(H, W)`` convolved with ``kernel`` ``(kh, kw)`` (reflect padding), in tiles."""
    kh, kw = kernel.shape
    if kh == 1 and kw == 1:
        return img.clone()
    h, w = img.shape
    ph, pw = kh // 2, kw // 2
    mode = "reflect" if ph < h and pw < w else "replicate"
    padded = F.pad(img[None, None], (pw, pw, ph, ph), mode=mode)[0, 0]
    out = torch.empty_like(img)
    kern = kernel.to(img)
    ky, kx = kern.sum(1), kern.sum(0)
    if max(kh, kw) <= 4 * _DIRECT_MAX and torch.allclose(ky[:, None] * kx[None, :], kern, atol=1e-7):
        # separable (box, Gaussian): two 1-D passes in bands of rows
        # (shifted multiply-adds: faster than a one-channel conv2d on the CPU, docs/measurements.md)
        rows = max(1, (1 << 21) // max(1, w + 2 * pw))
        for y in range(0, h, rows):
            y1 = min(h, y + rows)
            src = padded[y:y1 + 2 * ph]
            tmp = src[kh - 1:kh - 1 + (y1 - y)] * float(ky[kh - 1])
            for i in range(kh - 1):
                tmp.add_(src[i:i + (y1 - y)], alpha=float(ky[kh - 1 - i]))
            acc = tmp[:, kw - 1:kw - 1 + w] * float(kx[kw - 1])
            for i in range(kw - 1):
                acc.add_(tmp[:, i:i + w], alpha=float(kx[kw - 1 - i]))
            out[y:y1] = acc
        return out
    direct = max(kh, kw) <= _DIRECT_MAX
    th = max(1, (1 << 20) // max(1, w)) if direct else tile
    tw = w if direct else tile
    for y in range(0, h, th):
        for x in range(0, w, tw):
            y1, x1 = min(h, y + th), min(w, x + tw)
            src = padded[y:y1 + 2 * ph, x:x1 + 2 * pw]
            if direct:
                res = F.conv2d(src[None, None], kern.flip(0, 1)[None, None])[0, 0]
            else:
                fh, fw = src.shape
                spec = torch.fft.rfft2(src, s=(fh, fw)) * torch.fft.rfft2(kern, s=(fh, fw))
                full = torch.fft.irfft2(spec, s=(fh, fw))
                res = full[kh - 1:kh - 1 + (y1 - y), kw - 1:kw - 1 + (x1 - x)]
            out[y:y1, x:x1] = res
    return out


def convolve(images: Tensor, kernels: list[Tensor]) -> Tensor:
    """Convolve each image of ``(B, 1, H, W)`` with its own kernel (reflect padding, memory-bounded)."""
    return torch.stack([_conv_one(images[i, 0], kernels[i])[None] for i in range(images.shape[0])])


def scaled_blur(
    images: Tensor, square_px: Tensor, kind: str | list[str], fraction, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Box / Gaussian / motion blur of width ``fraction x square_px`` per image.

    Args:
        images: :math:`(B, 1, H, W)`.
        square_px: :math:`(B,)` square size in px (e.g. :func:`square_size_px`).
        kind: a blur kind for all images or one per image.
        fraction: a number or ``(lo, hi)`` range of the blur width relative to the square.
        generator: random source of the fractions and motion angles.

    Returns:
        blurred images and the blur widths ``(B,)`` in px.
    """
    b = images.shape[0]
    kinds = [kind] * b if isinstance(kind, str) else list(kind)
    frac = _u(generator, b, fraction)
    angle = _u(generator, b, (0.0, math.pi))
    width = frac * square_px.double().cpu()
    kernels = [blur_kernel(kinds[i], float(width[i]), float(angle[i])) for i in range(b)]
    return convolve(images, kernels), width


def psf_and_gamma(images: Tensor, generator: torch.Generator, sigma=(0.3, 1.0), gamma=(1.8, 2.4)) -> Tensor:
    """The realistic last mile of every render: a Gaussian optical point spread of ``sigma`` px, then the
    camera's tone curve ``I ** (1 / gamma)`` (``gamma = 1`` leaves the tones linear)."""
    b = images.shape[0]
    s = _u(generator, b, sigma)
    g = _u(generator, b, gamma)
    kernels = [gaussian_kernel(float(si)) for si in s]
    out = convolve(images, kernels).clamp(0.0, 1.0)
    return out.pow((1.0 / g).to(out).view(b, 1, 1, 1))


def _grid(h: int, w: int, y0: int, y1: int, device) -> tuple[Tensor, Tensor]:
    ys = torch.arange(y0, y1, device=device, dtype=torch.float32).view(-1, 1)
    xs = torch.arange(w, device=device, dtype=torch.float32).view(1, -1)
    return xs, ys


def glare(images: Tensor, generator: torch.Generator, centres: Tensor, size: Tensor, strength=(0.6, 1.6)) -> Tensor:
    """Specular highlight: an elliptical bright lobe ``strength * exp(-(d / r)^2)`` added in linear light at a
    random point near ``centres`` ``(B, 2)`` with radius ``0.2-0.6 x size`` ``(B,)`` px; its core exceeds 1 and
    saturates when the sensor clips (values are left above 1 here)."""
    b, _, h, w = images.shape
    g = generator
    off = torch.randn(b, 2, generator=g, dtype=torch.float64) * 0.3 * size.double().cpu()[:, None]
    c = centres.double().cpu() + off
    r = size.double().cpu() * _u(g, b, (0.2, 0.6))
    ratio, ang, amp = _u(g, b, (0.3, 1.0)), _u(g, b, (0.0, math.pi)), _u(g, b, strength)
    out = images.clone()
    rows = max(1, (1 << 21) // max(1, w))
    for i in range(b):
        ca, sa = math.cos(float(ang[i])), math.sin(float(ang[i]))
        for y0 in range(0, h, rows):
            xs, ys = _grid(h, w, y0, min(h, y0 + rows), images.device)
            dx, dy = xs - float(c[i, 0]), ys - float(c[i, 1])
            p, q = (dx * ca + dy * sa) / float(r[i]), (-dx * sa + dy * ca) / (float(r[i]) * float(ratio[i]))
            out[i, 0, y0:y0 + rows] += float(amp[i]) * torch.exp(-(p * p + q * q))
    return out


def shadows(images: Tensor, generator: torch.Generator, centres: Tensor, size: Tensor, darkness=(0.3, 0.7)) -> Tensor:
    """Soft-edged shadow crossing the board: a half-plane or a bar through a point near ``centres`` ``(B, 2)``,
    edges softened over ``2-15 %`` of ``size`` px, multiplying the light by ``1 - darkness``."""
    b, _, h, w = images.shape
    g = generator
    off = (torch.rand(b, 2, generator=g, dtype=torch.float64) - 0.5) * 0.6 * size.double().cpu()[:, None]
    c = centres.double().cpu() + off
    ang = _u(g, b, (0.0, 2 * math.pi))
    soft = size.double().cpu() * _u(g, b, (0.02, 0.15))
    bar = torch.rand(b, generator=g) < 0.5
    bar_w = size.double().cpu() * _u(g, b, (0.1, 0.4))
    dark = _u(g, b, darkness)
    out = images.clone()
    rows = max(1, (1 << 21) // max(1, w))
    for i in range(b):
        ca, sa = math.cos(float(ang[i])), math.sin(float(ang[i]))
        for y0 in range(0, h, rows):
            xs, ys = _grid(h, w, y0, min(h, y0 + rows), images.device)
            d = (xs - float(c[i, 0])) * ca + (ys - float(c[i, 1])) * sa
            if bool(bar[i]):
                d = float(bar_w[i]) / 2 - d.abs()
            inside = torch.clamp(0.5 + d / (2 * float(soft[i]) + 1e-6), 0.0, 1.0)
            inside = inside * inside * (3 - 2 * inside)  # smoothstep edge
            out[i, 0, y0:y0 + rows] *= 1.0 - float(dark[i]) * inside
    return out


def apply_optics(
    images: Tensor,
    generator: torch.Generator,
    square_px: Tensor,
    board_centre: Tensor,
    board_size_px: Tensor,
    blur: str | tuple[str, ...] = "none",
    blur_fraction=(0.0, 0.3),
    psf_sigma=(0.3, 1.0),
    gamma=(1.8, 2.4),
    glare_prob: float = 0.0,
    shadow_prob: float = 0.0,
    noise_sigma=0.0,
    jpeg_quality=None,
) -> Tensor:
    """The camera's chain on linear renders (see the module docstring); returns images in ``[0, 1]``.

    Args:
        images: :math:`(B, 1, H, W)` linear renders.
        generator: random source.
        square_px: :math:`(B,)` square size in px (blur widths are fractions of it).
        board_centre: :math:`(B, 2)` px, where glare and shadows fall; board_size_px: :math:`(B,)` their scale.
        blur: a kind of :data:`BLUR_KINDS` or a tuple drawn from per image.
        blur_fraction: blur width relative to the square (number or range).
        psf_sigma, gamma: of :func:`psf_and_gamma` (``0`` / ``1`` switch them off).
        glare_prob, shadow_prob: probability of a glare / a shadow per image.
        noise_sigma: read-noise sigma (number or range; shot noise ``0-0.003`` is added with it).
        jpeg_quality: ``None`` or a JPEG quality (number or inclusive range).
    """
    from ccs_kornia.data.render import augment

    g = generator
    b = images.shape[0]
    out = images
    if shadow_prob > 0:
        pick = (torch.rand(b, generator=g) < shadow_prob).nonzero().squeeze(1)
        if pick.numel():
            out = out.clone()
            out[pick] = shadows(out[pick], g, board_centre[pick], board_size_px[pick])
    if glare_prob > 0:
        pick = (torch.rand(b, generator=g) < glare_prob).nonzero().squeeze(1)
        if pick.numel():
            out = out.clone()
            out[pick] = glare(out[pick], g, board_centre[pick], board_size_px[pick])
    kinds = (blur,) if isinstance(blur, str) else tuple(blur)
    which = torch.randint(0, len(kinds), (b,), generator=g)
    if any(k != "none" for k in kinds):
        out, _ = scaled_blur(out, square_px, [kinds[int(i)] for i in which], blur_fraction, g)
    sig = psf_sigma if isinstance(psf_sigma, (tuple, list)) else (psf_sigma, psf_sigma)
    if max(sig) > 0:
        s = _u(g, b, sig)
        out = convolve(out, [gaussian_kernel(float(v)) for v in s])
    if noise_sigma is not None and (max(noise_sigma) if isinstance(noise_sigma, (tuple, list)) else noise_sigma) > 0:
        out = augment.add_noise(out.clamp_min(0.0), g, sigma=noise_sigma)
    out = out.clamp(0.0, 1.0)
    gm = _u(g, b, gamma)
    out = out.pow((1.0 / gm).to(out).view(b, 1, 1, 1))
    if jpeg_quality is not None:
        out = augment.jpeg(out, g, quality=jpeg_quality)
    return out
