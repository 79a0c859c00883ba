r"""Sampling-grid loss of the distortion CNN (paper Eq. 1, after Zhao et al.).

The network sees a distorted image and predicts a *correction* with 5 coefficients, while the image was made
with a 3-coefficient *distortion*; the two parameter sets are not comparable directly, so the loss compares
what they do to points. A regular ``grid_size x grid_size`` grid of sampling points spans the distorted image;
the predicted correction moves each point to :math:`p_{cor}` (:func:`ccs_kornia.geometry.radial.radial_correct_points`)
and the exact inverse of the true distortion moves it to :math:`p_{dst}`
(:func:`ccs_kornia.geometry.radial.radial_undistort_points`). The loss is

.. math::
    L_{grid} = \frac{1}{N} \sum_i^N \lVert p_{dst}^i - p_{cor}^i \rVert_1

in pixels of the given image size. Grid points that have no undistorted position (beyond the fold of a strong
distortion, where the rendered image is black) are left out.
"""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.geometry.radial import (
    radial_correct_points,
    radial_distort_points,
    radial_undistort_points,
)
from ccs_kornia.runtime.checks import check_correction, check_tensor

__all__ = ["sampling_grid", "normalize_distortion_scale", "grid_targets", "grid_loss", "GridLoss"]

_REDUCTIONS = ("mean", "sum", "none")


def sampling_grid(
    image_size: tuple[int, int], grid_size: int = 16, device: torch.device | str | None = None, dtype=torch.float32
) -> torch.Tensor:
    """Regular ``grid_size x grid_size`` pixel grid spanning ``[0, W-1] x [0, H-1]``, row-major.

    Returns:
        :math:`(1, G^2, 2)` pixel coordinates ``(x, y)``.

    Example:
        >>> sampling_grid((5, 3), 2)
        tensor([[[0., 0.],
                 [4., 0.],
                 [0., 2.],
                 [4., 2.]]])
    """
    if grid_size < 2:
        raise ValueError(f"grid_size must be >= 2, got {grid_size}.")
    w, h = int(image_size[0]), int(image_size[1])
    xs = torch.linspace(0.0, w - 1.0, grid_size, device=device, dtype=dtype)
    ys = torch.linspace(0.0, h - 1.0, grid_size, device=device, dtype=dtype)
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([gx, gy], -1).reshape(1, -1, 2)


def normalize_distortion_scale(distortion: torch.Tensor) -> torch.Tensor:
    """The same distortion with ``k0 = 1``: ``(k0, k1, k2) -> (1, k1 / k0^3, k2 / k0^5)``.

    ``k0`` alone scales the image about its centre, which a single image cannot tell apart from a different
    focal length or board distance. Writing ``r_c' = k0 r_c`` turns
    ``r_d = r_c (k0 + k1 r_c^2 + k2 r_c^4)`` into ``r_d = r_c' (1 + k1/k0^3 r_c'^2 + k2/k0^5 r_c'^4)``: the same
    distorted image, with the undistorted image zoomed by ``k0``. Its correction keeps the scale at the image
    centre (``k0' = 1``), which is the part of the correction that can be learned from images.

    Example:
        >>> normalize_distortion_scale(torch.tensor([[2.0, 8.0, 32.0]]))
        tensor([[1., 1., 1.]])
    """
    check_tensor(distortion, "distortion", ["B", "3"], what="coefficients (k0, k1, k2)")
    k0 = distortion[:, 0:1]
    return torch.cat([torch.ones_like(k0), distortion[:, 1:2] / k0**3, distortion[:, 2:3] / k0**5], -1)


def grid_targets(
    distortion: torch.Tensor, image_size: tuple[int, int], grid_size: int = 16
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Distorted sampling points, their true undistorted positions and which of them exist.

    Args:
        distortion: :math:`(B, 3)` paper distortion ``(k0, k1, k2)``.
        image_size: ``(W, H)``.
        grid_size: points per side.

    Returns:
        ``points`` :math:`(B, G^2, 2)` distorted pixels, ``targets`` :math:`(B, G^2, 2)` undistorted pixels
        (computed in float64, returned in ``distortion``'s dtype) and ``valid`` :math:`(B, G^2)`: the inverse
        converged on the increasing branch of the distortion (points past its fold have no preimage).
    """
    check_tensor(distortion, "distortion", ["B", "3"], what="coefficients (k0, k1, k2)")
    b = distortion.shape[0]
    k = distortion.detach().to(torch.float64)
    pts = sampling_grid(image_size, grid_size, distortion.device, torch.float64).expand(b, -1, -1)
    tgt = radial_undistort_points(pts, k, image_size, num_iters=20)
    back = radial_distort_points(tgt, k, image_size)
    w, h = int(image_size[0]), int(image_size[1])
    centre = torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], device=pts.device, dtype=torch.float64)
    rc = ((tgt - centre) / float(max(w, h))).norm(dim=-1)
    slope = k[:, 0:1] + 3 * k[:, 1:2] * rc**2 + 5 * k[:, 2:3] * rc**4
    valid = torch.isfinite(tgt).all(-1) & ((back - pts).norm(dim=-1) < 1e-3) & (slope > 0)
    tgt = torch.where(valid.unsqueeze(-1), tgt, pts)
    dt = distortion.dtype
    return pts.to(dt), tgt.to(dt), valid


def grid_loss(
    correction: torch.Tensor,
    distortion: torch.Tensor,
    image_size: tuple[int, int],
    grid_size: int = 16,
    reduction: str = "mean",
) -> torch.Tensor:
    """Paper Eq. 1: mean L1 distance (px) between corrected and true undistorted sampling-grid points.

    Args:
        correction: :math:`(B, 5)` predicted correction ``(k0', ..., k4')`` (differentiable).
        distortion: :math:`(B, 3)` true distortion ``(k0, k1, k2)`` of the images.
        image_size: ``(W, H)`` of the images the coefficients refer to (sets the pixel unit of the loss).
        grid_size: sampling points per side.
        reduction: ``mean`` (over valid points of the batch), ``sum``, or ``none`` (:math:`(B, G^2)`, zero at
            points without a true undistorted position).

    Returns:
        scalar loss, or :math:`(B, G^2)` for ``reduction="none"``.

    Example:
        >>> k = torch.tensor([[1.0, -0.2, 0.0]])
        >>> identity = torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]])
        >>> bool(grid_loss(identity, k, (64, 48)) > 0.5)
        True
        >>> from ccs_kornia.geometry.radial import fit_radial_correction
        >>> bool(grid_loss(fit_radial_correction(k, (64, 48)), k, (64, 48)) < 0.01)
        True
    """
    check_correction(correction)
    check_tensor(distortion, "distortion", ["B", "3"], what="coefficients (k0, k1, k2)", B=correction.shape[0])
    if reduction not in _REDUCTIONS:
        raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}.")
    pts, tgt, valid = grid_targets(distortion, image_size, grid_size)
    pts, tgt = pts.to(correction.dtype), tgt.to(correction.dtype)
    cor = radial_correct_points(pts, correction, image_size)
    err = (cor - tgt).abs().sum(-1) * valid.to(correction.dtype)
    if reduction == "none":
        return err
    if reduction == "sum":
        return err.sum()
    return err.sum() / valid.sum().clamp_min(1).to(correction.dtype)


class GridLoss(nn.Module):
    """Module form of :func:`grid_loss`.

    Args:
        grid_size: sampling points per side (the paper's :math:`N = G^2`).
        reduction: ``mean``, ``sum`` or ``none``.

    Example:
        >>> loss = GridLoss(grid_size=8)
        >>> round(float(loss(torch.tensor([[1.0, 0, 0, 0, 0]]), torch.tensor([[1.0, 0, 0]]), (64, 48))), 4)
        0.0
    """

    def __init__(self, grid_size: int = 16, reduction: str = "mean") -> None:
        super().__init__()
        if grid_size < 2:
            raise ValueError(f"grid_size must be >= 2, got {grid_size}.")
        if reduction not in _REDUCTIONS:
            raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}.")
        self.grid_size, self.reduction = int(grid_size), reduction

    def forward(self, correction: torch.Tensor, distortion: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor:
        return grid_loss(correction, distortion, image_size, self.grid_size, self.reduction)

    def extra_repr(self) -> str:
        return f"grid_size={self.grid_size}, reduction={self.reduction}"
