"""The paper's radial model: image-centred distortion and its correction, radius in units of ``max(W, H)``.

Radii are measured from the image centre ``((W-1)/2, (H-1)/2)`` in units of ``max(W, H)``; distortion
``r_d = r_c (k0 + k1 r_c^2 + k2 r_c^4)`` and correction ``r_c = r_d (k0' + k1' r_d + k2' r_d^2 + k3' r_d^3 + k4' r_d^4)``.
The renderer distorts its training images with it and the distortion network regresses its correction
(:mod:`ccs_kornia.modules.correction`); a calibrated camera of this model is
:class:`~ccs_kornia.geometry.models.centred_radial.CentredRadialModel`.
"""

from __future__ import annotations

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = [
    "radial_centre_scale",
    "radial_distort_points",
    "radial_undistort_points",
    "radial_correct_points",
    "fit_radial_correction",
]


def radial_centre_scale(image_size: tuple[int, int], like: torch.Tensor) -> tuple[torch.Tensor, float]:
    """The frame of the paper's radial model on a ``(W, H)`` image: its centre ``((W-1)/2, (H-1)/2)`` in pixels, a
    :math:`(2,)` tensor on ``like``'s device and dtype, and its unit of radius ``max(W, H)`` (so ``r <= ~0.71``).

    The distortion, its inverse and the network's correction (here and in :mod:`ccs_kornia.modules.correction`) all
    measure radii in this frame.

    Example:
        >>> radial_centre_scale((640, 480), torch.zeros(1))
        (tensor([319.5000, 239.5000]), 640.0)
    """
    w, h = image_size
    centre = torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], device=like.device, dtype=like.dtype)
    return centre, float(max(w, h))


def _apply_radial_factor(points: torch.Tensor, image_size: tuple[int, int], factor_fn) -> torch.Tensor:
    centre, scale = radial_centre_scale(image_size, points)
    q = (points - centre) / scale
    r = q.norm(dim=-1, keepdim=True)
    return q * factor_fn(r) * scale + centre


def radial_distort_points(points: torch.Tensor, coeffs: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
    """Paper distortion ``r_d = r_c (k0 + k1 r_c^2 + k2 r_c^4)`` on pixel points.

    Args:
        points: :math:`(B, N, 2)` ideal pixel coordinates.
        coeffs: :math:`(B, 3)` ``(k0, k1, k2)``.
        image_size: ``(W, H)``.

    Returns:
        :math:`(B, N, 2)` distorted pixel coordinates.

    Example:
        >>> p = torch.tensor([[[319.5, 239.5], [639., 479.]]])
        >>> radial_distort_points(p, torch.tensor([[1.0, 0.0, 0.0]]), (640, 480))
        tensor([[[319.5000, 239.5000],
                 [639.0000, 479.0000]]])
    """
    check_tensor(coeffs, "coeffs", ["*", "3"], what="radial distortion coefficients (k0, k1, k2)")
    k = coeffs.unsqueeze(-2)

    def factor(r):
        r2 = r * r
        return k[..., 0:1] + k[..., 1:2] * r2 + k[..., 2:3] * r2 * r2

    return _apply_radial_factor(points, image_size, factor)


def radial_undistort_points(
    points: torch.Tensor, coeffs: torch.Tensor, image_size: tuple[int, int], num_iters: int = 12
) -> torch.Tensor:
    """Exact inverse of :func:`radial_distort_points` by Newton's method on the radius.

    Args:
        points: :math:`(B, N, 2)` distorted pixel coordinates.
        coeffs: :math:`(B, 3)` distortion ``(k0, k1, k2)``.
        image_size: ``(W, H)``.
        num_iters: Newton steps (converges quadratically; 12 reaches float64 rounding for the paper's ranges).

    Returns:
        :math:`(B, N, 2)` ideal pixel coordinates.
    """
    check_tensor(coeffs, "coeffs", ["*", "3"], what="radial distortion coefficients (k0, k1, k2)")
    centre, scale = radial_centre_scale(image_size, points)
    q = (points - centre) / scale
    rd = q.norm(dim=-1, keepdim=True)
    k = coeffs.unsqueeze(-2)
    k0, k1, k2 = k[..., 0:1], k[..., 1:2], k[..., 2:3]
    rc = rd / k0
    for _ in range(num_iters):
        r2 = rc * rc
        f = rc * (k0 + k1 * r2 + k2 * r2 * r2) - rd
        df = k0 + 3 * k1 * r2 + 5 * k2 * r2 * r2
        rc = rc - f / df.clamp_min(1e-6)
    ratio = torch.where(rd > 0, rc / rd.clamp_min(1e-12), 1.0 / k0)
    return q * ratio * scale + centre


def radial_correct_points(points: torch.Tensor, correction: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
    """Paper correction ``r_c = r_d (k0' + k1' r_d + k2' r_d^2 + k3' r_d^3 + k4' r_d^4)``.

    Args:
        points: :math:`(B, N, 2)` distorted pixel coordinates.
        correction: :math:`(B, 5)` correction coefficients.
        image_size: ``(W, H)``.

    Returns:
        :math:`(B, N, 2)` corrected pixel coordinates.
    """
    check_tensor(correction, "correction", ["*", "5"], what="radial correction coefficients (k0'..k4')")
    c = correction.unsqueeze(-2)

    def factor(r):
        return c[..., 0:1] + r * (c[..., 1:2] + r * (c[..., 2:3] + r * (c[..., 3:4] + r * c[..., 4:5])))

    return _apply_radial_factor(points, image_size, factor)


def fit_radial_correction(coeffs: torch.Tensor, image_size: tuple[int, int], num_samples: int = 64) -> torch.Tensor:
    """Least-squares correction coefficients (B, 5) that best invert distortion ``coeffs`` (B, 3).

    Samples ideal radii up to the image corner, distorts them, and fits
    ``r_c = r_d * poly4(r_d)`` in closed form. Used as the regression target/oracle of the CNN.
    """
    w, h = image_size
    r_max = 0.5 * (w * w + h * h) ** 0.5 / max(w, h) * 1.02
    rc = torch.linspace(0.0, r_max, num_samples, device=coeffs.device, dtype=coeffs.dtype)
    k0, k1, k2 = coeffs[:, 0:1], coeffs[:, 1:2], coeffs[:, 2:3]
    rd = rc * (k0 + k1 * rc**2 + k2 * rc**4)  # (B, S)
    A = torch.stack([rd**p for p in range(1, 6)], -1)  # (B, S, 5): r_d * r_d^p
    sol = torch.linalg.lstsq(A, rc.expand_as(rd).unsqueeze(-1)).solution
    return sol.squeeze(-1)
