"""The heatmap network's corner peaks at full resolution, with no board organisation: for callers that organise the
corners themselves (a marker board's free lattice, :mod:`~ccs_kornia.modules.detection.markers.lattice_path`).

Each image is looked at on its own detection level (:class:`~ccs_kornia.modules.detection.learned.scale.ScaleSelector`:
squares of about 9 px), its peaks filtered as the detector filters them (sigma, X-junction on the full-resolution
image) and mapped back to the full-resolution pixel grid.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from ccs_kornia.modules._checks import check_grey_images
from ccs_kornia.modules.detection.learned.learned_detector import LearnedChessboardDetector
from ccs_kornia.modules.detection.refine.patch_refine import resize_to_level

__all__ = ["corner_peaks", "shipped_detector"]


@functools.lru_cache(maxsize=1)
def shipped_detector() -> LearnedChessboardDetector:
    """The learned detector with the shipped weights (loaded once)."""
    return LearnedChessboardDetector()


@torch.no_grad()
def corner_peaks(images: torch.Tensor, detector: LearnedChessboardDetector | None = None) -> list[np.ndarray]:
    r"""The corner peaks of each image: a list of :math:`(M_b, 2)` float64 arrays of full-resolution px.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        detector: whose network, scale selection and peak filters are used (default: :func:`shipped_detector`).

    Example:
        >>> from ccs_kornia.geometry.camera import board_object_points
        >>> img = torch.zeros(1, 1, 120, 160)
        >>> for i in range(8):
        ...     for j in range(6):
        ...         if (i + j) % 2 == 0:
        ...             img[..., 12 + 12 * j:24 + 12 * j, 20 + 12 * i:32 + 12 * i] = 1.0
        >>> peaks = corner_peaks(img)
        >>> len(peaks), peaks[0].shape[0] >= 30
        (1, True)
    """
    check_grey_images(images)
    det = shipped_detector() if detector is None else detector
    x = images.float()
    _, factor = det.scale_selector(x)
    out: list[np.ndarray] = [np.zeros((0, 2))] * x.shape[0]
    for value in torch.unique(factor).tolist():
        idx = (factor == value).nonzero().flatten()
        full = x[idx.to(x.device)]
        level, scale = resize_to_level(full, float(value))
        resampled = tuple(level.shape[-2:]) != tuple(full.shape[-2:])
        _, mu, keep = det.candidates(level, full if resampled else None, scale if resampled else None)
        pts = (mu.double() + 0.5) * scale.to(mu.device) - 0.5 if resampled else mu.double()
        for k, i in enumerate(idx.tolist()):
            out[i] = pts[k][keep[k]].cpu().numpy()
    return out
