"""Differentiable removal of the paper's radial distortion from images and points (paper Sec. III-A).

The distortion CNN predicts a *correction* ``r_c = r_d (k0' + k1' r_d + k2' r_d^2 + k3' r_d^3 + k4' r_d^4)``
(:func:`ccs_kornia.geometry.radial.radial_correct_points`), radii measured from the image centre ``((W-1)/2, (H-1)/2)``
in units of ``max(W, H)``. It maps *distorted* pixels to *corrected* ones, which is exactly what points need.
An image warp needs the opposite direction: for every pixel of the corrected output, the distorted source
position to sample. That inverse has no closed form, so it is solved per pixel by Newton's method on the radius
(:func:`distort_points_from_correction`), batched over images and pixels. Newton iterations run without
autograd; one final Newton step is taken with autograd, which at a converged root gives exactly the
implicit-function gradient ``d r_d / d theta = -(d g / d theta) / g'(r_d)`` at the cost of one step.

Where the correction has no preimage (the correction polynomial folds over, or the corrected radius is beyond
what it reaches), the output pixel is marked invalid and filled with zeros.

``zoom`` scales the corrected frame about the image centre (``zoom < 1`` shows more of a barrel-corrected image,
whose content otherwise grows beyond the frame); points maps use the same convention, so
``correct_points`` gives coordinates in the output image of :func:`radial_undistort_image`.
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap
from torch import nn

from ccs_kornia.geometry.radial import radial_centre_scale, radial_correct_points
from ccs_kornia.runtime.checks import check_correction, check_points, check_tensor

__all__ = [
    "correct_points",
    "corrected_radius",
    "corrected_radius_and_slope",
    "correction_zoom",
    "distort_points_from_correction",
    "invert_correction_radius",
    "radial_undistort_image",
    "RadialUndistort",
]


def corrected_radius_and_slope(r: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The correction's radial map ``g(r) = r * poly4(r)`` and its slope ``g'(r)`` (Horner): what Newton's method
    inverts (:func:`invert_correction_radius`) and what pooling samples along the radius
    (:mod:`~ccs_kornia.modules.correction.pooling`).

    Args:
        r: radii (units of ``max(W, H)``), any shape :math:`(...)`.
        c: correction coefficients :math:`(..., 5)`, broadcasting against ``r[..., None]``.

    Returns:
        ``g`` and ``g'``, both of the broadcast shape of ``r``.

    Example:
        >>> corrected_radius_and_slope(torch.tensor([0.5]), torch.tensor([1.0, 0.0, 0.2, 0.0, 0.0]))
        (tensor([0.5250]), tensor([1.1500]))
    """
    c0, c1, c2, c3, c4 = c.unbind(-1)
    g = r * (c0 + r * (c1 + r * (c2 + r * (c3 + r * c4))))
    dg = c0 + r * (2 * c1 + r * (3 * c2 + r * (4 * c3 + r * 5 * c4)))
    return g, dg


def invert_correction_radius(
    r_corrected: torch.Tensor, correction: torch.Tensor, num_iters: int = 10, tol: float = 1e-4
) -> tuple[torch.Tensor, torch.Tensor]:
    """Distorted radius ``r_d`` with ``r_d * poly4(r_d) = r_c``, by Newton's method (batched, differentiable).

    Starting at ``r_c / k0'`` Newton converges monotonically for a correction that is convex (barrel) or
    concave (pincushion) in ``r_d``; the iterate is clamped to ``[0, 4]`` so a folding polynomial cannot
    produce non-finite values.

    Args:
        r_corrected: :math:`(B, N)` corrected radii (units of ``max(W, H)``).
        correction: :math:`(B, 5)` correction coefficients.
        num_iters: Newton iterations without autograd before the final differentiable step.
        tol: a root counts as found when ``|g(r_d) - r_c| < tol`` (radius units) and ``g'(r_d) > 0``.

    Returns:
        ``r_d`` :math:`(B, N)` and ``valid`` :math:`(B, N)` bool.
    """
    c = correction.unsqueeze(-2)  # (B, 1, 5)
    with torch.no_grad():
        rc0 = r_corrected.detach()
        cd = c.detach()
        r = rc0 / cd[..., 0].clamp_min(1e-3)
        for _ in range(num_iters):
            g, dg = corrected_radius_and_slope(r, cd)
            r = (r - (g - rc0) / dg.clamp_min(1e-3)).clamp(0.0, 4.0)
        g, dg = corrected_radius_and_slope(r, cd)
        valid = ((g - rc0).abs() < tol) & (dg > 1e-3) & torch.isfinite(r)
    # one differentiable Newton step from the (detached) root: the implicit-function gradient
    g, dg = corrected_radius_and_slope(r, c)
    dg_safe = torch.where(valid, dg, torch.ones_like(dg))
    r_out = r - torch.where(valid, g - r_corrected, torch.zeros_like(g)) / dg_safe
    return r_out, valid


def correct_points(
    points: torch.Tensor, correction: torch.Tensor, image_size: tuple[int, int], zoom: float = 1.0
) -> torch.Tensor:
    """Distorted pixels to corrected pixels (:func:`ccs_kornia.geometry.radial.radial_correct_points`, then ``zoom``).

    Args:
        points: :math:`(B, N, 2)` distorted pixel coordinates.
        correction: :math:`(B, 5)` correction coefficients.
        image_size: ``(W, H)``.
        zoom: scale of the corrected frame about the image centre (1 = the paper's model).

    Returns:
        :math:`(B, N, 2)` pixel coordinates in the corrected image.

    Example:
        >>> p = torch.tensor([[[10.0, 20.0]]])
        >>> correct_points(p, torch.tensor([[1.0, 0, 0, 0, 0]]), (64, 48))
        tensor([[[10., 20.]]])
    """
    check_points(points)
    check_correction(correction, points.shape[0])
    out = radial_correct_points(points, correction, image_size)
    if zoom != 1.0:
        centre, _ = radial_centre_scale(image_size, out)
        out = (out - centre) * zoom + centre
    return out


def distort_points_from_correction(
    points: torch.Tensor,
    correction: torch.Tensor,
    image_size: tuple[int, int],
    zoom: float = 1.0,
    num_iters: int = 10,
    return_valid: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Corrected pixels back to distorted pixels: the inverse of :func:`correct_points` (Newton on the radius).

    Args:
        points: :math:`(B, N, 2)` pixel coordinates in the corrected image.
        correction: :math:`(B, 5)` correction coefficients.
        image_size: ``(W, H)``.
        zoom: as in :func:`correct_points`.
        num_iters: Newton iterations.
        return_valid: also return the :math:`(B, N)` mask of points that have a preimage.

    Returns:
        :math:`(B, N, 2)` distorted pixel coordinates (points without a preimage keep a finite placeholder),
        and the mask if asked.

    Example:
        >>> c = torch.tensor([[1.0, 0.0, 0.3, 0.0, 0.0]])
        >>> p = torch.tensor([[[5.0, 7.0], [60.0, 40.0]]])
        >>> q = distort_points_from_correction(correct_points(p, c, (64, 48)), c, (64, 48))
        >>> bool(torch.allclose(q, p, atol=1e-4))
        True
    """
    check_points(points)
    check_correction(correction, points.shape[0])
    if zoom <= 0:
        raise ValueError(f"zoom must be positive, got {zoom}.")
    centre, scale = radial_centre_scale(image_size, points)
    q = (points - centre) / (scale * zoom)
    rc = q.norm(dim=-1)
    rd, valid = invert_correction_radius(rc, correction.to(points.dtype), num_iters=num_iters)
    out = _from_radius(q, rc, rd, correction, scale, centre)
    return (out, valid) if return_valid else out


def _from_radius(q: torch.Tensor, rc: torch.Tensor, rd: torch.Tensor, correction: torch.Tensor, scale: float,
                 centre: torch.Tensor) -> torch.Tensor:
    """Distorted pixels :math:`(B, N, 2)` of the normalised corrected points ``q`` (broadcasting to ``rd``), radii
    ``rc`` and their distorted radii ``rd`` :math:`(B, N)`."""
    rc = rc.expand_as(rd)
    k0 = correction[:, 0:1].to(rd.dtype)
    ratio = torch.where(rc > 0, rd / rc.clamp_min(1e-12), 1.0 / k0.clamp_min(1e-3).expand_as(rc))
    return q * ratio.unsqueeze(-1) * scale + centre


def _pixel_sources(h: int, w: int, correction: torch.Tensor, zoom: float, num_iters: int, dtype: torch.dtype,
                   device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`distort_points_from_correction` of every pixel of an ``h x w`` image, :math:`(B, h w, 2)` and the
    valid mask :math:`(B, h w)`, with Newton on a quarter of them: the four pixels mirrored about the centre have the
    same radius to the bit (their offsets from the centre differ in sign only), so the top-left quadrant's inverse
    radii serve all four (the same values, in less than half the time: ``docs/measurements.md``)."""
    pts = create_meshgrid(h, w, normalized_coordinates=False, device=device, dtype=dtype).reshape(1, h * w, 2)
    centre, scale = radial_centre_scale((w, h), pts)
    q = (pts - centre) / (scale * zoom)
    rc = q.norm(dim=-1)  # (1, h w)
    hq, wq = (h + 1) // 2, (w + 1) // 2
    quadrant = rc.reshape(1, h, w)[:, :hq, :wq].reshape(1, hq * wq).expand(correction.shape[0], -1)
    rd, valid = invert_correction_radius(quadrant, correction.to(dtype), num_iters=num_iters)
    rows, cols = torch.arange(h, device=device), torch.arange(w, device=device)
    index = (torch.minimum(rows, h - 1 - rows)[:, None] * wq + torch.minimum(cols, w - 1 - cols)[None, :]).reshape(-1)
    rd, valid = rd[:, index], valid[:, index]
    return _from_radius(q, rc, rd, correction, scale, centre), valid


def radial_undistort_image(
    images: torch.Tensor,
    correction: torch.Tensor,
    zoom: float = 1.0,
    mode: str = "bilinear",
    padding_mode: str = "zeros",
    num_iters: int = 10,
    return_mask: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Warp distorted images to corrected images (differentiable in the images and the coefficients).

    Output pixel ``p`` takes the value of the input at ``distort_points_from_correction(p)``, sampled with
    :func:`kornia.geometry.transform.remap` (pixel centres at integers, ``align_corners=True``).

    Args:
        images: :math:`(B, C, H, W)`.
        correction: :math:`(B, 5)` (or :math:`(1, 5)`, shared) correction coefficients for images of this size.
        zoom: scale of the corrected frame about the image centre.
        mode: ``bilinear`` or ``nearest``.
        padding_mode: ``zeros``, ``border`` or ``reflection`` (for samples outside the input).
        num_iters: Newton iterations of the radius inversion.
        return_mask: also return the :math:`(B, 1, H, W)` mask of output pixels whose source lies inside the
            input and has a preimage under the correction.

    Returns:
        :math:`(B, C, H, W)` corrected images (zeros where there is no preimage), and the mask if asked.

    Example:
        >>> img = torch.rand(2, 1, 48, 64)
        >>> out = radial_undistort_image(img, torch.tensor([[1.0, 0, 0, 0, 0]]).repeat(2, 1))
        >>> bool(torch.allclose(out, img, atol=1e-5))
        True
    """
    check_tensor(images, "images", ["B", "C", "H", "W"])
    b, _, h, w = images.shape
    check_correction(correction, b)
    dtype = images.dtype if images.is_floating_point() else torch.float32
    if zoom <= 0:
        raise ValueError(f"zoom must be positive, got {zoom}.")
    src, valid = _pixel_sources(h, w, correction.to(dtype), zoom, num_iters, dtype, images.device)
    src = src.reshape(-1, h, w, 2).expand(b, -1, -1, -1)
    valid = valid.reshape(-1, 1, h, w).expand(b, -1, -1, -1)
    out = remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode=padding_mode, align_corners=True)
    out = out * valid.to(dtype)
    if not return_mask:
        return out
    inside = (src[..., 0] >= -0.5) & (src[..., 0] <= w - 0.5) & (src[..., 1] >= -0.5) & (src[..., 1] <= h - 0.5)
    return out, valid & inside.unsqueeze(1)


class RadialUndistort(nn.Module):
    """Module form of :func:`radial_undistort_image`.

    Args:
        zoom: scale of the corrected frame about the image centre.
        mode: interpolation mode.
        padding_mode: how samples outside the input are filled.
        num_iters: Newton iterations.

    Example:
        >>> warp = RadialUndistort()
        >>> warp(torch.rand(1, 1, 24, 32), torch.tensor([[1.0, 0.0, 0.2, 0.0, 0.0]])).shape
        torch.Size([1, 1, 24, 32])
    """

    def __init__(self, zoom: float = 1.0, mode: str = "bilinear", padding_mode: str = "zeros", num_iters: int = 10):
        super().__init__()
        if zoom <= 0:
            raise ValueError(f"zoom must be positive, got {zoom}.")
        self.zoom, self.mode, self.padding_mode, self.num_iters = float(zoom), mode, padding_mode, int(num_iters)

    def forward(self, images: torch.Tensor, correction: torch.Tensor) -> torch.Tensor:
        return radial_undistort_image(images, correction, self.zoom, self.mode, self.padding_mode, self.num_iters)

    def correct_points(
        self, points: torch.Tensor, correction: torch.Tensor, image_size: tuple[int, int]
    ) -> torch.Tensor:
        """Distorted input pixels to pixels of this module's output image."""
        return correct_points(points, correction, image_size, self.zoom)

    def distort_points(
        self, points: torch.Tensor, correction: torch.Tensor, image_size: tuple[int, int]
    ) -> torch.Tensor:
        """Pixels of this module's output image back to distorted input pixels."""
        return distort_points_from_correction(points, correction, image_size, self.zoom, self.num_iters)

    def extra_repr(self) -> str:
        return f"zoom={self.zoom}, mode={self.mode}, padding_mode={self.padding_mode}, num_iters={self.num_iters}"


def corrected_radius(radius: torch.Tensor, correction: torch.Tensor) -> torch.Tensor:
    """Corrected radius ``r_d * poly4(r_d)`` of distorted radii (units of ``max(W, H)``).

    Args:
        radius: :math:`(B, S)` distorted radii (or anything broadcasting against ``correction[:, :1]``).
        correction: :math:`(B, 5)`.

    Example:
        >>> corrected_radius(torch.tensor([[0.5]]), torch.tensor([[1.0, 0.0, 0.2, 0.0, 0.0]]))
        tensor([[0.5250]])
    """
    return corrected_radius_and_slope(radius, correction.unsqueeze(-2))[0]


def correction_zoom(correction: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Zoom that keeps the farthest original image corner in the frame after correction (in [0.5, 1]).

    Args:
        correction: :math:`(B, 5)` corrections; the smallest zoom over them is returned.
        size: ``(W, H)``.

    Example:
        >>> float(correction_zoom(torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]]), (64, 48)))
        1.0
    """
    w, h = size
    scale = float(max(w, h))
    r = 0.5 * math.hypot(w - 1, h - 1) / scale
    g = corrected_radius(torch.full_like(correction[:, :1], r, dtype=torch.float64), correction.double())[:, 0]
    return (r / g.clamp_min(1e-6)).clamp(0.5, 1.0).min()
