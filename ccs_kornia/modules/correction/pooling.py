"""One radial correction per camera: pooling the per-view predictions, and how far a correction moves pixels.

The views of a camera share its lens, so the network's per-view corrections are pooled into one
(:func:`aggregate_corrections`); :func:`correction_displacement` measures how far it moves the image, which decides
whether the correction is applied (:func:`correction_is_large`; :func:`pool_corrections` does both, as
:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` pools each camera's views).
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.modules.correction.radial_warp import corrected_radius_and_slope
from ccs_kornia.runtime.checks import check_correction, check_tensor

__all__ = ["aggregate_corrections", "correction_displacement", "correction_is_large", "pool_corrections"]


def correction_displacement(correction: torch.Tensor, image_size: tuple[int, int], samples: int = 64) -> torch.Tensor:
    """Largest distance (px) a correction moves any pixel of the image, :math:`(B,)`.

    Measured along the radius from the centre to the farthest image corner; a ``k0'`` other than 1 counts as the
    zoom it is.

    Example:
        >>> correction_displacement(torch.tensor([[1.0, 0, 0, 0, 0]]), (64, 48))
        tensor([0.])
    """
    check_correction(correction)
    w, h = int(image_size[0]), int(image_size[1])
    scale = float(max(w, h))
    r_corner = 0.5 * ((w - 1) ** 2 + (h - 1) ** 2) ** 0.5 / scale
    r = torch.linspace(0.0, r_corner, samples, device=correction.device, dtype=correction.dtype)
    g, _ = corrected_radius_and_slope(r.unsqueeze(0), correction.unsqueeze(1))
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
    check_tensor(corrections, "corrections", ["C", "V", "5"])
    c, v = corrections.shape[:2]
    if mask is None:
        mask = torch.ones(c, v, dtype=torch.bool, device=corrections.device)
    check_tensor(mask, "mask", [c, v])
    dt = torch.float64
    w, h = int(image_size[0]), int(image_size[1])
    r_corner = 0.5 * ((w - 1) ** 2 + (h - 1) ** 2) ** 0.5 / float(max(w, h))
    r = torch.linspace(0.0, r_corner, samples, device=corrections.device, dtype=dt)
    g, _ = corrected_radius_and_slope(r.view(1, 1, -1), corrections.to(dt).unsqueeze(2))  # (C, V, S)
    g = torch.where(mask.unsqueeze(-1), g, torch.full_like(g, float("nan")))
    med = g.nanmedian(1).values  # (C, S)
    A = torch.stack([r ** p for p in range(1, 6)], -1)  # (S, 5): g(r) = sum_p c_p r^p
    sol = torch.linalg.lstsq(A.expand(c, -1, -1), med.nan_to_num(0.0).unsqueeze(-1)).solution.squeeze(-1)
    ident = torch.zeros_like(sol)
    ident[:, 0] = 1.0
    return torch.where(mask.any(1, keepdim=True), sol, ident).to(corrections.dtype)


def correction_is_large(correction: torch.Tensor, image_size: tuple[int, int], min_correction: float) -> torch.Tensor:
    """:math:`(C,)` bool: the corrections :math:`(C, 5)` move some pixel of an image of ``image_size`` ``(W, H)`` by
    more than ``min_correction`` of the half image diagonal (:func:`correction_displacement`).

    Example:
        >>> correction_is_large(torch.tensor([[1.0, 0, 0, 0, 0], [1.0, 0, 0.3, 0, 0]]), (640, 480), 0.02).tolist()
        [False, True]
    """
    half_diagonal = 0.5 * math.hypot(image_size[0], image_size[1])
    return correction_displacement(correction, image_size) > min_correction * half_diagonal


def pool_corrections(per_view: torch.Tensor, image_size: tuple[int, int], min_correction: float,
                     mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """One correction per camera :math:`(C, 5)` float64 from :math:`(C, V, 5)` per-view ones (NaN: no prediction;
    ``mask`` :math:`(C, V)`: the views to pool, :func:`aggregate_corrections`), and whether it is large :math:`(C,)`
    (:func:`correction_is_large`).

    Example:
        >>> per_view = torch.tensor([[[1.0, 0, 0.3, 0, 0], [1.0, 0, 0.3, 0, 0]]])
        >>> correction, large = pool_corrections(per_view, (640, 480), 0.02)
        >>> correction.shape, large.tolist()
        (torch.Size([1, 5]), [True])
    """
    correction = aggregate_corrections(per_view.double().nan_to_num(0.0), image_size, mask)
    return correction, correction_is_large(correction, image_size, min_correction)
