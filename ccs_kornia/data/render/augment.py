"""Batched photometric degradations and procedural backgrounds for synthetic chessboard images.

Every function works on float images ``(B, 1, H, W)`` in ``[0, 1]``, draws its per-image parameters
from a ``torch.Generator`` (so a seed fixes the result) and returns images in ``[0, 1]``.
Random numbers are drawn on the generator's device and moved to the images' device, so a CPU
generator gives the same images on CPU and CUDA.

The named conditions used by the benchmarks and the training data are :data:`CONDITIONS`:

* ``clean``: unchanged;
* ``blur_noise``: 3x3 Gaussian blur with sigma 1.5, then read + shot noise;
* ``bad_lighting``: Phong specular highlight and strong diffuse shading, then vignetting;
* ``combined``: bad lighting, blur, noise and JPEG compression, in the order a camera applies them.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d

__all__ = [
    "CONDITIONS",
    "gaussian_blur",
    "add_noise",
    "phong_lighting",
    "vignetting",
    "gamma",
    "jpeg",
    "textured_background",
    "apply_condition",
    "ApplyCondition",
]

#: named image conditions, in the order the benchmarks report them
CONDITIONS: tuple[str, ...] = ("clean", "blur_noise", "bad_lighting", "combined")

def _check_images(images: torch.Tensor) -> None:
    if not isinstance(images, torch.Tensor) or images.dim() != 4 or images.shape[1] != 1:
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"Expected grey images of shape (B, 1, H, W), got {shape}.")


def _rand(generator: torch.Generator, shape: tuple[int, ...], device, dtype=torch.float32) -> torch.Tensor:
    """Uniform [0, 1) numbers drawn on the generator's device, moved to ``device``."""
    return torch.rand(shape, generator=generator, device=generator.device, dtype=dtype).to(device)


def _randn(generator: torch.Generator, shape: tuple[int, ...], device, dtype=torch.float32) -> torch.Tensor:
    return torch.randn(shape, generator=generator, device=generator.device, dtype=dtype).to(device)


def _uniform(generator: torch.Generator, shape: tuple[int, ...], value, device, dtype=torch.float32) -> torch.Tensor:
    """Per-item values from ``value`` (a number, or a ``(lo, hi)`` range sampled uniformly)."""
    if isinstance(value, (int, float)):
        return torch.full(shape, float(value), device=device, dtype=dtype)
    lo, hi = float(value[0]), float(value[1])
    if hi < lo:
        raise ValueError(f"Invalid range {value}: high < low.")
    return lo + (hi - lo) * _rand(generator, shape, device, dtype)


def _default_generator(generator: torch.Generator | None) -> torch.Generator:
    return generator if generator is not None else torch.default_generator


def gaussian_blur(
    images: torch.Tensor,
    generator: torch.Generator | None = None,
    sigma: float | tuple[float, float] = (0.5, 1.5),
    kernel_size: int | None = None,
) -> torch.Tensor:
    """Gaussian blur with a per-image sigma (kornia ``gaussian_blur2d``).

    Args:
        images: :math:`(B, 1, H, W)` in ``[0, 1]``.
        generator: source of the per-image sigma.
        sigma: fixed sigma or ``(lo, hi)`` range in pixels.
        kernel_size: odd kernel side; ``None`` picks ``2 * ceil(3 * max_sigma) + 1``.

    Returns:
        :math:`(B, 1, H, W)` blurred images.

    Example:
        >>> x = torch.zeros(2, 1, 16, 16); x[..., 8:] = 1
        >>> gaussian_blur(x, torch.Generator().manual_seed(0), sigma=1.5, kernel_size=3).shape
        torch.Size([2, 1, 16, 16])
    """
    _check_images(images)
    generator = _default_generator(generator)
    b = images.shape[0]
    s = _uniform(generator, (b,), sigma, images.device, images.dtype).clamp_min(1e-3)
    if kernel_size is None:
        kernel_size = 2 * math.ceil(3.0 * float(s.max())) + 1
    if kernel_size % 2 == 0 or kernel_size < 1:
        raise ValueError(f"kernel_size must be odd and positive, got {kernel_size}.")
    return gaussian_blur2d(images, (kernel_size, kernel_size), torch.stack([s, s], -1), border_type="reflect").clamp(
        0.0, 1.0
    )


def add_noise(
    images: torch.Tensor,
    generator: torch.Generator | None = None,
    sigma: float | tuple[float, float] = (0.01, 0.04),
    shot: float | tuple[float, float] = (0.0, 0.003),
) -> torch.Tensor:
    """Sensor noise: Gaussian read noise plus signal-dependent (Poisson-like) shot noise.

    The per-pixel variance is ``sigma**2 + shot * I`` (shot noise of a sensor whose full well maps
    to 1/shot photo-electrons).

    Args:
        images: :math:`(B, 1, H, W)` in ``[0, 1]``.
        generator: random source.
        sigma: read-noise standard deviation (number or range).
        shot: shot-noise gain (number or range).

    Returns:
        :math:`(B, 1, H, W)` noisy images clamped to ``[0, 1]``.
    """
    _check_images(images)
    generator = _default_generator(generator)
    b = images.shape[0]
    read = _uniform(generator, (b, 1, 1, 1), sigma, images.device, images.dtype)
    gain = _uniform(generator, (b, 1, 1, 1), shot, images.device, images.dtype)
    std = (read * read + gain * images.clamp_min(0.0)).sqrt()
    return (images + std * _randn(generator, tuple(images.shape), images.device, images.dtype)).clamp(0.0, 1.0)


def phong_lighting(
    images: torch.Tensor,
    generator: torch.Generator | None = None,
    specular: float | tuple[float, float] = (0.3, 0.9),
    shininess: float | tuple[float, float] = (4.0, 80.0),
    shading: float | tuple[float, float] = (0.4, 0.85),
    brightness: float | tuple[float, float] = (0.75, 1.1),
) -> torch.Tensor:
    """Phong lighting of the image plane: diffuse shading gradient plus a specular highlight.

    The image is treated as a planar surface (coordinates in units of ``max(W, H)``, centred) with a
    slightly tilted normal, lit by a point light at a random position and viewed from a random point
    above it. ``I' = I * brightness * shade / max(shade) + ks * max(R.V, 0)^alpha`` where
    ``shade = ambient + diffuse * max(N.L, 0) / d^2``. The highlight's centre follows the light, its
    size the shininess ``alpha``; the shading strength is the diffuse share of ``shade``.

    Args:
        images: :math:`(B, 1, H, W)` in ``[0, 1]``.
        generator: random source.
        specular: highlight strength ``ks`` (number or range).
        shininess: Phong exponent ``alpha`` (large = small highlight), sampled log-uniformly.
        shading: diffuse share of the shading (0 = flat, 1 = fully light-dependent).
        brightness: overall gain at the brightest point.

    Returns:
        :math:`(B, 1, H, W)` lit images clamped to ``[0, 1]``.
    """
    _check_images(images)
    generator = _default_generator(generator)
    b, _, h, w = images.shape
    dev, dt = images.device, images.dtype
    scale = float(max(w, h))
    ys = (torch.arange(h, device=dev, dtype=dt) - (h - 1) / 2) / scale
    xs = (torch.arange(w, device=dev, dtype=dt) - (w - 1) / 2) / scale
    px, py = xs.view(1, 1, 1, w), ys.view(1, 1, h, 1)

    def u(lo, hi):
        return _uniform(generator, (b, 1, 1, 1), (lo, hi), dev, dt)

    light = (u(-0.6, 0.6), u(-0.6, 0.6), u(0.25, 1.2))
    view = (u(-0.2, 0.2), u(-0.2, 0.2), u(0.8, 2.0))
    tilt, azim = u(0.0, 0.35), u(0.0, 2 * math.pi)
    normal = (tilt.sin() * azim.cos(), tilt.sin() * azim.sin(), tilt.cos())

    lx, ly, lz = light[0] - px, light[1] - py, light[2].expand(b, 1, h, w)
    dist2 = lx * lx + ly * ly + lz * lz
    inv_d = dist2.rsqrt()
    lx, ly, lz = lx * inv_d, ly * inv_d, lz * inv_d
    vx, vy, vz = view[0] - px, view[1] - py, view[2].expand(b, 1, h, w)
    inv_v = (vx * vx + vy * vy + vz * vz).rsqrt()
    vx, vy, vz = vx * inv_v, vy * inv_v, vz * inv_v
    n_dot_l = normal[0] * lx + normal[1] * ly + normal[2] * lz
    # reflection of the light direction about the normal
    rx, ry, rz = 2 * n_dot_l * normal[0] - lx, 2 * n_dot_l * normal[1] - ly, 2 * n_dot_l * normal[2] - lz
    r_dot_v = (rx * vx + ry * vy + rz * vz).clamp_min(0.0)

    k_diffuse = _uniform(generator, (b, 1, 1, 1), shading, dev, dt)
    diffuse = n_dot_l.clamp_min(0.0) / dist2
    diffuse = diffuse / diffuse.amax(dim=(2, 3), keepdim=True).clamp_min(1e-6)
    shade = (1.0 - k_diffuse) + k_diffuse * diffuse
    gain = _uniform(generator, (b, 1, 1, 1), brightness, dev, dt)
    alpha = _log_uniform(generator, (b, 1, 1, 1), shininess, dev, dt)
    ks = _uniform(generator, (b, 1, 1, 1), specular, dev, dt)
    highlight = ks * r_dot_v.pow(alpha)
    return (images * gain * shade + highlight).clamp(0.0, 1.0)


def _log_uniform(generator, shape, value, device, dtype) -> torch.Tensor:
    if isinstance(value, (int, float)):
        return torch.full(shape, float(value), device=device, dtype=dtype)
    lo, hi = math.log(float(value[0])), math.log(float(value[1]))
    return (lo + (hi - lo) * _rand(generator, shape, device, dtype)).exp()


def vignetting(
    images: torch.Tensor,
    generator: torch.Generator | None = None,
    strength: float | tuple[float, float] = (0.2, 0.6),
    power: float | tuple[float, float] = (2.0, 4.0),
    centre_jitter: float = 0.1,
) -> torch.Tensor:
    """Radial fall-off ``1 - strength * (r / r_max)^power`` about a jittered image centre.

    Args:
        images: :math:`(B, 1, H, W)` in ``[0, 1]``.
        generator: random source.
        strength: darkening at the farthest corner (number or range).
        power: fall-off exponent (number or range).
        centre_jitter: centre offset as a fraction of the image size.

    Returns:
        :math:`(B, 1, H, W)` images.
    """
    _check_images(images)
    generator = _default_generator(generator)
    b, _, h, w = images.shape
    dev, dt = images.device, images.dtype
    cx = (w - 1) / 2 + centre_jitter * w * (2 * _rand(generator, (b, 1, 1, 1), dev, dt) - 1)
    cy = (h - 1) / 2 + centre_jitter * h * (2 * _rand(generator, (b, 1, 1, 1), dev, dt) - 1)
    xs = torch.arange(w, device=dev, dtype=dt).view(1, 1, 1, w)
    ys = torch.arange(h, device=dev, dtype=dt).view(1, 1, h, 1)
    r = ((xs - cx) ** 2 + (ys - cy) ** 2).sqrt()
    r = r / r.amax(dim=(2, 3), keepdim=True).clamp_min(1.0)
    s = _uniform(generator, (b, 1, 1, 1), strength, dev, dt)
    p = _uniform(generator, (b, 1, 1, 1), power, dev, dt)
    return (images * (1.0 - s * r.pow(p))).clamp(0.0, 1.0)


def gamma(
    images: torch.Tensor, generator: torch.Generator | None = None, value: float | tuple[float, float] = (0.6, 1.6)
) -> torch.Tensor:
    """Tone curve ``I ** gamma`` with a per-image gamma (log-uniform in the range).

    Returns:
        :math:`(B, 1, H, W)` images in ``[0, 1]``.
    """
    _check_images(images)
    generator = _default_generator(generator)
    g = _log_uniform(generator, (images.shape[0], 1, 1, 1), value, images.device, images.dtype)
    return images.clamp(0.0, 1.0).pow(g)


def jpeg(
    images: torch.Tensor, generator: torch.Generator | None = None, quality: int | tuple[int, int] = (30, 90)
) -> torch.Tensor:
    """JPEG compression artefacts (OpenCV encode/decode per image, 8-bit).

    Args:
        images: :math:`(B, 1, H, W)` in ``[0, 1]``.
        generator: source of the per-image quality.
        quality: JPEG quality (integer or inclusive range).

    Returns:
        :math:`(B, 1, H, W)` decoded images on the input device.
    """
    _check_images(images)
    generator = _default_generator(generator)
    b = images.shape[0]
    if isinstance(quality, int):
        q = torch.full((b,), quality, dtype=torch.long)
    else:
        q = torch.randint(int(quality[0]), int(quality[1]) + 1, (b,), generator=generator, device=generator.device)
    arr = (images.detach().clamp(0, 1) * 255.0).round().to(torch.uint8).cpu().numpy()
    out = np.empty_like(arr)
    for i in range(b):
        ok, buf = cv2.imencode(".jpg", arr[i, 0], [int(cv2.IMWRITE_JPEG_QUALITY), int(q[i])])
        if not ok:
            raise RuntimeError("cv2.imencode failed to encode a JPEG.")
        out[i, 0] = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return torch.from_numpy(out).to(device=images.device, dtype=images.dtype) / 255.0


def _bands(batch: int, h: int, w: int, pixels: int = 1 << 22):
    """``(batch slice, y0, y1)`` pieces of about ``pixels`` pixels: bounds the full-size temporaries."""
    step = max(1, pixels // max(1, h * w))
    rows = max(1, min(h, pixels // max(1, w)))
    for i in range(0, batch, step):
        sl = slice(i, min(batch, i + step))
        for y0 in range(0, h, rows if step == 1 else h):
            yield sl, y0, min(h, y0 + (rows if step == 1 else h))


def _upsample_rows(grid: torch.Tensor, h: int, w: int, y0: int, y1: int) -> torch.Tensor:
    """Rows ``y0 .. y1 - 1`` of ``F.interpolate(grid, (h, w), bilinear, align_corners=True)``."""
    gh = grid.shape[-2]
    sy = torch.arange(y0, y1, device=grid.device, dtype=grid.dtype) * ((gh - 1) / max(h - 1, 1))
    i0 = sy.floor().clamp(0, gh - 2).long()
    f = (sy - i0.to(sy.dtype)).view(1, 1, -1, 1)
    rows = grid[:, :, i0] * (1 - f) + grid[:, :, i0 + 1] * f
    return F.interpolate(rows, size=(y1 - y0, w), mode="bilinear", align_corners=True)


def textured_background(
    batch_size: int,
    image_size: tuple[int, int],
    generator: torch.Generator | None = None,
    device: torch.device | str = "cpu",
    dtype: torch.dtype = torch.float32,
    num_rects: int = 5,
    num_lines: int = 5,
    num_blobs: int = 3,
    num_stripes: int = 1,
) -> torch.Tensor:
    """Procedural clutter: multi-scale value noise, rotated rectangles, line segments, blobs, stripes.

    Each shape slot is filled with probability about 0.6 (an absent shape gets zero size), so the
    amount of clutter varies per image; rectangles, lines and stripe patches give straight edges
    (hard negatives for a corner detector). Edges are anti-aliased with a one-pixel ramp on the
    signed distance. All parameters are drawn first, so the result does not depend on how the
    batch is sliced to bound memory.

    Args:
        batch_size: number of images ``B``.
        image_size: ``(W, H)``.
        generator: random source.
        device, dtype: of the output.
        num_rects, num_lines, num_blobs, num_stripes: shape slots per image.

    Returns:
        :math:`(B, 1, H, W)` backgrounds in ``[0, 1]``.

    Example:
        >>> textured_background(2, (64, 48), torch.Generator().manual_seed(0)).shape
        torch.Size([2, 1, 48, 64])
    """
    generator = _default_generator(generator)
    w, h = int(image_size[0]), int(image_size[1])
    b = int(batch_size)
    if b < 1 or w < 2 or h < 2:
        raise ValueError(f"Invalid background request: batch {b}, image size {image_size}.")
    dim = float(max(w, h))

    def u(lo, hi):
        return _uniform(generator, (b, 1, 1, 1), (lo, hi), device, dtype)

    def present():
        return (_rand(generator, (b, 1, 1, 1), device, dtype) < 0.6).to(dtype)

    def frame():
        return {"cx": u(-0.1, 1.1) * w, "cy": u(-0.1, 1.1) * h, "ang": u(0.0, math.pi)}

    # multi-scale value noise: random grids at several cell sizes, bilinearly upsampled
    amp = u(0.03, 0.3)
    weights = [0.55**k for k in range(4)]
    grids = []
    for weight, cell in zip(weights, (64, 24, 8, 3)):
        gh, gw = max(2, math.ceil(h / cell) + 1), max(2, math.ceil(w / cell) + 1)
        grids.append((2 * _rand(generator, (b, 1, gh, gw), device, dtype) - 1) * (amp * weight / sum(weights)))
    base = u(0.15, 0.85)
    shapes = []
    for _ in range(num_rects):
        on = present()
        shapes.append(("rect", {**frame(), "hw": u(0.02, 0.3) * dim * on, "hh": u(0.02, 0.3) * dim * on, "val": u(0, 1)}))
    for _ in range(num_blobs):
        shapes.append(("blob", {**frame(), "a": u(0.01, 0.12) * dim, "b": u(0.01, 0.12) * dim, "on": present(), "val": u(0, 1)}))
    for _ in range(num_stripes):
        on = present() * (_rand(generator, (b, 1, 1, 1), device, dtype) < 0.5).to(dtype)
        shapes.append(("stripes", {**frame(), "hw": u(0.05, 0.2) * dim * on, "hh": u(0.05, 0.2) * dim * on,
                                   "period": u(6.0, 30.0), "lo": u(0.0, 0.4), "amp": u(0.4, 0.6)}))
    for _ in range(num_lines):
        shapes.append(("line", {**frame(), "len": u(0.05, 0.7) * dim, "thick": u(0.5, 3.0) * present(), "val": u(0, 1)}))

    xs = torch.arange(w, device=device, dtype=dtype).view(1, 1, 1, w)
    out = torch.empty(b, 1, h, w, device=device, dtype=dtype)
    for sl, y0, y1 in _bands(b, h, w):
        hb = y1 - y0
        ys = torch.arange(y0, y1, device=device, dtype=dtype).view(1, 1, hb, 1)
        canvas = base[sl].expand(-1, 1, hb, w).clone()
        for grid in grids:
            canvas += _upsample_rows(grid[sl], h, w, y0, y1)
        # shapes are composited in place: large temporaries are the main cost on CPU
        for kind, p in shapes:
            p = {k: v[sl] for k, v in p.items()}
            c, s = p["ang"].cos(), p["ang"].sin()
            dx, dy = xs - p["cx"], ys - p["cy"]
            xr, yr = torch.addcmul(dx * c, dy, s), torch.addcmul(dy * c, dx, -s)
            if kind == "rect":
                sd = torch.maximum(xr.abs_().sub_(p["hw"]), yr.abs_().sub_(p["hh"]), out=xr)
                canvas.lerp_(p["val"].expand_as(canvas), sd.neg_().add_(0.5).clamp_(0.0, 1.0))
            elif kind == "blob":
                rho = xr.div_(p["a"]).square_().add_(yr.div_(p["b"]).square_()).sqrt_()
                alpha = rho.neg_().add_(1.0).mul_(torch.minimum(p["a"], p["b"])).add_(0.5).clamp_(0.0, 1.0).mul_(p["on"])
                canvas.lerp_(p["val"].expand_as(canvas), alpha)
            elif kind == "stripes":
                period = p["period"]
                phase = torch.remainder(xr / period, 1.0).mul_(period)
                # anti-aliased square wave: one-pixel ramps at both stripe edges
                wave = phase.clamp(0, 1).sub_(phase.sub_(0.5 * period).clamp_(0, 1)).clamp_(0, 1)
                inside = torch.maximum(xr.abs_().sub_(p["hw"]), yr.abs_().sub_(p["hh"]), out=xr)
                canvas.lerp_(wave.mul_(p["amp"]).add_(p["lo"]), inside.neg_().add_(0.5).clamp_(0.0, 1.0))
            else:
                sd = torch.maximum(yr.abs_().sub_(p["thick"]), xr.abs_().sub_(p["len"]), out=yr)
                canvas.lerp_(p["val"].expand_as(canvas), sd.neg_().add_(0.5).clamp_(0.0, 1.0))
        out[sl, :, y0:y1] = canvas.clamp_(0.0, 1.0)
    return out


def apply_condition(images: torch.Tensor, condition: str, generator: torch.Generator | None = None) -> torch.Tensor:
    """Apply one named condition from :data:`CONDITIONS` to every image of the batch.

    Args:
        images: :math:`(B, 1, H, W)` in ``[0, 1]``.
        condition: ``clean``, ``blur_noise``, ``bad_lighting`` or ``combined``.
        generator: random source.

    Returns:
        :math:`(B, 1, H, W)` images in ``[0, 1]``.

    Example:
        >>> x = torch.rand(2, 1, 32, 32)
        >>> apply_condition(x, "blur_noise", torch.Generator().manual_seed(0)).shape
        torch.Size([2, 1, 32, 32])
    """
    _check_images(images)
    if condition not in CONDITIONS:
        raise ValueError(f"Unknown condition {condition!r}; expected one of {CONDITIONS}.")
    generator = _default_generator(generator)
    if condition == "clean":
        return images.clamp(0.0, 1.0)
    if condition == "blur_noise":
        out = gaussian_blur(images, generator, sigma=1.5, kernel_size=3)
        return add_noise(out, generator)
    if condition == "bad_lighting":
        out = phong_lighting(images, generator)
        return vignetting(out, generator)
    # combined: scene lighting, lens fall-off and blur, sensor noise, then compression
    out = phong_lighting(images, generator)
    out = vignetting(out, generator)
    out = gaussian_blur(out, generator, sigma=1.5, kernel_size=3)
    out = add_noise(out, generator)
    return jpeg(out, generator)


class ApplyCondition(torch.nn.Module):
    """Module form of :func:`apply_condition` with a fixed condition."""

    def __init__(self, condition: str = "clean") -> None:
        super().__init__()
        if condition not in CONDITIONS:
            raise ValueError(f"Unknown condition {condition!r}; expected one of {CONDITIONS}.")
        self.condition = condition

    def forward(self, images: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return apply_condition(images, self.condition, generator)
