"""Differentiable removal of the paper's radial distortion from images and points (paper Sec. III-A).

The distortion CNN predicts a *correction* ``r_c = r_d (k0' + k1' r_d + k2' r_d^2 + k3' r_d^3 + k4' r_d^4)``
(:func:`ccs_kornia.camera.radial_correct_points`), radii measured from the image centre ``((W-1)/2, (H-1)/2)``
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

import torch
from kornia.geometry.grid import create_meshgrid
from kornia.geometry.transform import remap
from torch import nn

from ccs_kornia import camera

__all__ = [
    "aggregate_corrections",
    "correct_points",
    "correction_displacement",
    "corrected_radius",
    "fit_correction_to_points",
    "opencv_undistort_image",
    "opencv_undistorted_frame",
    "opencv_distorted_frame",
    "distort_points_from_correction",
    "invert_correction_radius",
    "radial_undistort_image",
    "RadialUndistort",
    "straightness_rms",
]


def _check_correction(correction: torch.Tensor, batch: int | None = None) -> None:
    if correction.dim() != 2 or correction.shape[-1] != 5:
        raise ValueError(f"correction must be (B, 5) coefficients (k0'..k4'), got {tuple(correction.shape)}.")
    if batch is not None and correction.shape[0] not in (1, batch):
        raise ValueError(f"correction batch {correction.shape[0]} does not match {batch}.")


def _check_points(points: torch.Tensor) -> None:
    if points.dim() != 3 or points.shape[-1] != 2:
        raise ValueError(f"points must be (B, N, 2), got {tuple(points.shape)}.")


def _centre_scale(image_size: tuple[int, int], like: torch.Tensor) -> tuple[torch.Tensor, float]:
    w, h = int(image_size[0]), int(image_size[1])
    centre = torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], device=like.device, dtype=like.dtype)
    return centre, float(max(w, h))


def _radial_map(r: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``g(r) = r * poly4(r)`` and ``g'(r)`` (Horner), ``c`` broadcasting as ``(..., 5)`` against ``r[..., None]``."""
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
            g, dg = _radial_map(r, cd)
            r = (r - (g - rc0) / dg.clamp_min(1e-3)).clamp(0.0, 4.0)
        g, dg = _radial_map(r, cd)
        valid = ((g - rc0).abs() < tol) & (dg > 1e-3) & torch.isfinite(r)
    # one differentiable Newton step from the (detached) root: the implicit-function gradient
    g, dg = _radial_map(r, c)
    dg_safe = torch.where(valid, dg, torch.ones_like(dg))
    r_out = r - torch.where(valid, g - r_corrected, torch.zeros_like(g)) / dg_safe
    return r_out, valid


def correct_points(
    points: torch.Tensor, correction: torch.Tensor, image_size: tuple[int, int], zoom: float = 1.0
) -> torch.Tensor:
    """Distorted pixels to corrected pixels (:func:`ccs_kornia.camera.radial_correct_points`, then ``zoom``).

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
    _check_points(points)
    _check_correction(correction, points.shape[0])
    out = camera.radial_correct_points(points, correction, image_size)
    if zoom != 1.0:
        centre, _ = _centre_scale(image_size, out)
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
    _check_points(points)
    _check_correction(correction, points.shape[0])
    if zoom <= 0:
        raise ValueError(f"zoom must be positive, got {zoom}.")
    centre, scale = _centre_scale(image_size, points)
    q = (points - centre) / (scale * zoom)
    rc = q.norm(dim=-1)
    rd, valid = invert_correction_radius(rc, correction.to(points.dtype), num_iters=num_iters)
    k0 = correction[:, 0:1].to(points.dtype)
    ratio = torch.where(rc > 0, rd / rc.clamp_min(1e-12), 1.0 / k0.clamp_min(1e-3).expand_as(rc))
    out = q * ratio.unsqueeze(-1) * scale + centre
    return (out, valid) if return_valid else out


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
    if images.dim() != 4:
        raise ValueError(f"images must be (B, C, H, W), got {tuple(images.shape)}.")
    b, _, h, w = images.shape
    _check_correction(correction, b)
    dtype = images.dtype if images.is_floating_point() else torch.float32
    grid = create_meshgrid(h, w, normalized_coordinates=False, device=images.device, dtype=dtype)  # (1,H,W,2)
    pts = grid.reshape(1, h * w, 2).expand(correction.shape[0], -1, -1)
    src, valid = distort_points_from_correction(
        pts, correction.to(dtype), (w, h), zoom=zoom, num_iters=num_iters, return_valid=True
    )
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
    return _radial_map(radius, correction.unsqueeze(-2))[0]


def correction_displacement(correction: torch.Tensor, image_size: tuple[int, int], samples: int = 64) -> torch.Tensor:
    """Largest distance (px) a correction moves any pixel of the image, :math:`(B,)`.

    Measured along the radius from the centre to the farthest image corner; a ``k0'`` other than 1 counts as the
    zoom it is.

    Example:
        >>> correction_displacement(torch.tensor([[1.0, 0, 0, 0, 0]]), (64, 48))
        tensor([0.])
    """
    _check_correction(correction)
    w, h = int(image_size[0]), int(image_size[1])
    scale = float(max(w, h))
    r_corner = 0.5 * ((w - 1) ** 2 + (h - 1) ** 2) ** 0.5 / scale
    r = torch.linspace(0.0, r_corner, samples, device=correction.device, dtype=correction.dtype)
    g, _ = _radial_map(r.unsqueeze(0), correction.unsqueeze(1))
    return ((g - r) * scale).abs().amax(-1)


def aggregate_corrections(
    corrections: torch.Tensor, image_size: tuple[int, int], mask: torch.Tensor | None = None, samples: int = 64
) -> torch.Tensor:
    """One correction per camera from the per-view predictions of its views.

    All views of one camera share its lens, so the per-view estimates are pooled: at ``samples`` radii up to the
    image corner the corrected radius is the median over the camera's views (robust to a view whose board says
    little about the lens), and a 5-coefficient correction is fitted to those medians by least squares.

    Args:
        corrections: :math:`(C, V, 5)` per-view correction coefficients.
        image_size: ``(W, H)``.
        mask: optional :math:`(C, V)` bool, views to pool (a camera without any keeps the identity).
        samples: radii sampled.

    Returns:
        :math:`(C, 5)`.

    Example:
        >>> c = torch.tensor([[[1.0, 0, 0.2, 0, 0], [1.0, 0, 0.2, 0, 0], [1.0, 0, 0.3, 0, 0]]])
        >>> bool(torch.allclose(aggregate_corrections(c, (64, 48)), c[:, 0], atol=1e-5))
        True
    """
    if corrections.dim() != 3 or corrections.shape[-1] != 5:
        raise ValueError(f"corrections must be (C, V, 5), got {tuple(corrections.shape)}.")
    c, v = corrections.shape[:2]
    if mask is None:
        mask = torch.ones(c, v, dtype=torch.bool, device=corrections.device)
    if mask.shape != (c, v):
        raise ValueError(f"mask must be {(c, v)}, got {tuple(mask.shape)}.")
    dt = torch.float64
    w, h = int(image_size[0]), int(image_size[1])
    r_corner = 0.5 * ((w - 1) ** 2 + (h - 1) ** 2) ** 0.5 / float(max(w, h))
    r = torch.linspace(0.0, r_corner, samples, device=corrections.device, dtype=dt)
    g, _ = _radial_map(r.view(1, 1, -1), corrections.to(dt).unsqueeze(2))  # (C, V, S)
    g = torch.where(mask.unsqueeze(-1), g, torch.full_like(g, float("nan")))
    med = g.nanmedian(1).values  # (C, S)
    A = torch.stack([r ** p for p in range(1, 6)], -1)  # (S, 5): g(r) = sum_p c_p r^p
    sol = torch.linalg.lstsq(A.expand(c, -1, -1), med.nan_to_num(0.0).unsqueeze(-1)).solution.squeeze(-1)
    ident = torch.zeros_like(sol)
    ident[:, 0] = 1.0
    return torch.where(mask.any(1, keepdim=True), sol, ident).to(corrections.dtype)


def fit_correction_to_points(
    distorted: torch.Tensor,
    ideal: torch.Tensor,
    image_size: tuple[int, int],
    mask: torch.Tensor | None = None,
    fix_k0: bool = True,
) -> torch.Tensor:
    """Least-squares correction coefficients mapping ``distorted`` pixels onto ``ideal`` ones.

    ``correct_points`` is linear in the coefficients (``p_c - c = (p_d - c) sum_j k_j' r_d^j``), so this is one
    batched solve. With ``fix_k0`` the scale at the centre stays 1: a zoom about the centre cannot be told from
    the focal length, so leaving it free would let a calibration loop drift.

    Args:
        distorted, ideal: :math:`(B, N, 2)` pixels.
        image_size: ``(W, H)``.
        mask: optional :math:`(B, N)` bool of points to use.
        fix_k0: keep ``k0' = 1``.

    Returns:
        :math:`(B, 5)` correction coefficients.

    Example:
        >>> c = torch.tensor([[1.0, 0.0, 0.3, 0.0, 0.1]], dtype=torch.float64)
        >>> p = torch.rand(1, 50, 2, dtype=torch.float64) * torch.tensor([64.0, 48.0])
        >>> bool(torch.allclose(fit_correction_to_points(p, correct_points(p, c, (64, 48)), (64, 48)), c))
        True
    """
    _check_points(distorted)
    if ideal.shape != distorted.shape:
        raise ValueError(f"ideal must match distorted {tuple(distorted.shape)}, got {tuple(ideal.shape)}.")
    centre, scale = _centre_scale(image_size, distorted)
    d = distorted - centre
    r = d.norm(dim=-1) / scale  # (B, N)
    powers = torch.stack([r**j for j in range(5)], -1)  # (B, N, 5)
    A = (d.unsqueeze(-1) * powers.unsqueeze(-2)).reshape(d.shape[0], -1, 5)  # (B, 2N, 5)
    b = (ideal - centre).reshape(d.shape[0], -1)
    w = torch.ones_like(r) if mask is None else (mask.to(r.dtype) * torch.isfinite(ideal).all(-1).to(r.dtype))
    w = w.repeat_interleave(2, -1)
    A, b = A * w.unsqueeze(-1), b.nan_to_num(0.0) * w
    if fix_k0:
        sol = torch.linalg.lstsq(A[..., 1:], (b - A[..., 0]).unsqueeze(-1)).solution.squeeze(-1)
        return torch.cat([torch.ones_like(sol[:, :1]), sol], -1)
    return torch.linalg.lstsq(A, b.unsqueeze(-1)).solution.squeeze(-1)


def _zoomed_camera(K: torch.Tensor, zoom: float) -> torch.Tensor:
    """``K`` scaled by ``zoom`` about its principal point (same principal point)."""
    Kz = K.clone()
    Kz[..., 0, 0] = K[..., 0, 0] * zoom
    Kz[..., 1, 1] = K[..., 1, 1] * zoom
    Kz[..., 0, 1] = K[..., 0, 1] * zoom
    return Kz


def opencv_undistorted_frame(points: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, zoom: float = 1.0) -> torch.Tensor:
    """Distorted pixels to pixels of :func:`opencv_undistort_image`'s output, :math:`(B, N, 2)`.

    Args:
        points: :math:`(B, N, 2)`; K: :math:`(B, 3, 3)`; dist: :math:`(B, D)` OpenCV coefficients.
        zoom: focal scale of the undistorted image (its camera is ``K`` with ``fx, fy`` times ``zoom``).
    """
    ideal = camera.undistort_pixels(points, K, dist)
    pp = K[..., None, :2, 2]
    return (ideal - pp) * zoom + pp


def opencv_distorted_frame(points: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, zoom: float = 1.0) -> torch.Tensor:
    """Pixels of :func:`opencv_undistort_image`'s output back to distorted pixels (inverse of
    :func:`opencv_undistorted_frame`)."""
    pp = K[..., None, :2, 2]
    return camera.distort_pixels((points - pp) / zoom + pp, K, dist)


def opencv_undistort_image(
    images: torch.Tensor, K: torch.Tensor, dist: torch.Tensor, zoom: float = 1.0, mode: str = "bilinear"
) -> torch.Tensor:
    """Remove OpenCV-model distortion from images (as ``cv2.undistort`` with ``newCameraMatrix = K`` zoomed).

    ``zoom < 1`` keeps more of a barrel-distorted image's periphery in the frame.

    Args:
        images: :math:`(B, C, H, W)`.
        K: :math:`(B, 3, 3)`; dist: :math:`(B, D)`.
        zoom: focal scale of the output camera.
        mode: interpolation.

    Returns:
        :math:`(B, C, H, W)`, zeros where the source lies outside the input.

    Example:
        >>> K = torch.tensor([[[50.0, 0, 31.5], [0, 50, 23.5], [0, 0, 1]]])
        >>> img = torch.rand(1, 1, 48, 64)
        >>> bool(torch.allclose(opencv_undistort_image(img, K, torch.zeros(1, 5)), img, atol=1e-5))
        True
    """
    if images.dim() != 4:
        raise ValueError(f"images must be (B, C, H, W), got {tuple(images.shape)}.")
    b, _, h, w = images.shape
    dtype = images.dtype if images.is_floating_point() else torch.float32
    grid = create_meshgrid(h, w, normalized_coordinates=False, device=images.device, dtype=torch.float64)
    pts = grid.reshape(1, h * w, 2).expand(b, -1, -1)
    src = opencv_distorted_frame(pts, K.to(torch.float64), dist.to(torch.float64), zoom).reshape(b, h, w, 2).to(dtype)
    return remap(images.to(dtype), src[..., 0], src[..., 1], mode=mode, padding_mode="zeros", align_corners=True)


def straightness_rms(
    corners: torch.Tensor, valid: torch.Tensor, board_size: torch.Tensor | tuple[int, int], min_points: int = 3
) -> tuple[torch.Tensor, torch.Tensor]:
    """RMS distance (px) of board corners from total-least-squares lines fitted to each row and column.

    Under a pinhole camera every row and column of board corners is straight, so this measures residual lens
    distortion (and detection noise) without knowing the camera. Each corner counts once for its row and once
    for its column; lines with fewer than ``min_points`` valid corners are skipped.

    Args:
        corners: :math:`(B, N, 2)` corners in grid order ``n = j * cols + i`` (padded).
        valid: :math:`(B, N)` bool.
        board_size: ``(cols, rows)`` or a :math:`(B, 2)` long tensor.
        min_points: smallest line that counts.

    Returns:
        per-image RMS :math:`(B,)` (0 where no line counts) and the number of point-on-line terms :math:`(B,)`.

    Example:
        >>> xy = torch.stack(torch.meshgrid(torch.arange(3.), torch.arange(4.), indexing="xy"), -1).reshape(1, 12, 2)
        >>> rms, n = straightness_rms(xy, torch.ones(1, 12, dtype=torch.bool), (3, 4))
        >>> float(rms), int(n)
        (0.0, 24)
    """
    _check_points(corners)
    b, n = corners.shape[:2]
    if valid.shape != (b, n):
        raise ValueError(f"valid must be {(b, n)}, got {tuple(valid.shape)}.")
    bs = torch.as_tensor(board_size, device=corners.device, dtype=torch.long)
    if bs.shape == (2,):
        bs = bs.expand(b, 2)
    if tuple(bs.shape) != (b, 2):
        raise ValueError(f"board_size must be (cols, rows) or (B, 2), got {tuple(bs.shape)}.")
    cols, rows = bs[:, 0:1], bs[:, 1:2]
    idx = torch.arange(n, device=corners.device).unsqueeze(0)
    exists = idx < cols * rows
    i = torch.remainder(idx, cols)
    j = torch.div(idx, cols, rounding_mode="floor")
    w = (valid.bool() & exists & torch.isfinite(corners).all(-1)).to(torch.float64)
    r_max, c_max = int(bs[:, 1].max()), int(bs[:, 0].max())
    member = torch.cat(
        [
            nn.functional.one_hot(j.clamp(0, r_max - 1), r_max),
            nn.functional.one_hot(i.clamp(0, c_max - 1), c_max),
        ],
        -1,
    ).to(torch.float64) * w.unsqueeze(-1)  # (B, N, L)
    p = torch.where(torch.isfinite(corners), corners, torch.zeros_like(corners)).to(torch.float64)
    count = member.sum(1)  # (B, L)
    mean = torch.einsum("bnl,bnd->bld", member, p) / count.clamp_min(1.0).unsqueeze(-1)
    d = p.unsqueeze(2) - mean.unsqueeze(1)  # (B, N, L, 2), centred before the products (float64, no cancellation)
    sxx = (member * d[..., 0] ** 2).sum(1)
    syy = (member * d[..., 1] ** 2).sum(1)
    sxy = (member * d[..., 0] * d[..., 1]).sum(1)
    # smallest eigenvalue of the 2x2 scatter matrix = sum of squared perpendicular distances to the TLS line
    sse = (0.5 * (sxx + syy) - torch.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)).clamp_min(0.0)
    use = count >= min_points
    total = torch.where(use, sse, torch.zeros_like(sse)).sum(-1)
    terms = torch.where(use, count, torch.zeros_like(count)).sum(-1)
    rms = torch.sqrt(total / terms.clamp_min(1.0))
    return rms.to(corners.dtype), terms.to(torch.long)
