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

from ccs_kornia.modules.detection.learned.learned_detector import (
    LearnedChessboardDetector,
)
from ccs_kornia.modules.detection.learned.scale import detection_factor
from ccs_kornia.modules.detection.refine.patch_refine import resize_to_level
from ccs_kornia.runtime.checks import check_grey_images

__all__ = ["OCTAVES_OFF", "RETRY", "corner_peaks", "shipped_detector"]


@functools.lru_cache(maxsize=1)
def shipped_detector() -> LearnedChessboardDetector:
    """The learned detector with the shipped weights (loaded once)."""
    return LearnedChessboardDetector()


#: a measured square size replaces the scale selector's level where the two are more than this many octaves apart
#: (the network finds corners over about an octave of square sizes around its target)
OCTAVES_OFF = 1.0
#: levels tried in turn (relative to the chosen one) on an image with fewer than ``min_peaks`` peaks
RETRY = (0.5, 2.0)


def _level_peaks(det: LearnedChessboardDetector, x: torch.Tensor, factor: torch.Tensor) -> list[np.ndarray]:
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


@torch.no_grad()
def corner_peaks(images: torch.Tensor, detector: LearnedChessboardDetector | None = None, min_peaks: int = 24,
                 retry: tuple[float, ...] = RETRY, square_size: torch.Tensor | None = None,
                 level_square: float | None = None) -> list[np.ndarray]:
    r"""The corner peaks of each image: a list of :math:`(M_b, 2)` float64 arrays of full-resolution px.

    An image with fewer than ``min_peaks`` peaks on its level (a wrong square-size estimate: small boards of small
    squares) is looked at again on the levels ``retry`` times finer or coarser (at most the detector's upsampling),
    keeping the level with the most peaks.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        detector: whose network, scale selection and peak filters are used (default: :func:`shipped_detector`).
        min_peaks: fewer peaks try the other levels.
        retry: relative factors of those levels.
        square_size: :math:`(B,)` the board's square size in px where another cue measured it (a marker board's
            decoded markers; NaN: not measured): where the scale selector's level is more than
            :data:`OCTAVES_OFF` octaves from that size's (:func:`~ccs_kornia.modules.detection.learned.scale.
            detection_factor`), that size's is used (a scene's larger texture misleads the estimate).
        level_square: with ``square_size``, the squares' size in px on the level (default: the scale selector's
            ``target_square``); a larger one (the corners' features a small part of a square, as the narrow band
            between a ChArUco board's corners and its large markers) always takes the measured size's level.

    Example:
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
    sel = det.scale_selector
    factor = sel(x)[1].cpu().double()
    if square_size is not None:
        known = torch.as_tensor(square_size, dtype=torch.float64).reshape(-1).cpu()
        size = (x.shape[-1], x.shape[-2])
        at_target = detection_factor(known, size, sel.target_square, sel.max_pixels, sel.steps_per_octave,
                                     sel.min_factor)
        finer = level_square is not None and float(level_square) > sel.target_square
        measured = detection_factor(known, size, float(level_square), sel.max_pixels, sel.steps_per_octave,
                                    sel.min_factor) if finer else at_target
        off = (at_target / factor).log2().abs() > OCTAVES_OFF
        factor = torch.where(known.isfinite() & (off | finer), measured, factor)
    out = _level_peaks(det, x, factor)
    floor = det.scale_selector.min_factor
    for rel in retry:
        few = torch.tensor([len(p) < min_peaks for p in out], dtype=torch.bool)
        if not bool(few.any()):
            break
        idx = few.nonzero().flatten()
        again = (factor[idx] * rel).clamp_min(floor)
        fresh = _level_peaks(det, x[idx.to(x.device)], again)
        for k, i in enumerate(idx.tolist()):
            if len(fresh[k]) > len(out[i]):
                out[i] = fresh[k]
    return out
