"""Enhanced copies of a grey image: what a detector looks at again where the image itself gave too little.

A dim view's pattern spans a few grey levels (a marker under OpenCV's adaptive threshold constant; a chessboard whose
square-size estimate the noise misleads), a blurred one's edges are soft and a small one's squares or bits a few
pixels. Three copies answer these (:func:`enhanced_copies`): the grey levels stretched from the image's 1st to 99th
percentile, that copy sharpened by an unsharp mask, and that copy enlarged. The marker boards decode their markers on
them (:mod:`~ccs_kornia.modules.detection.markers.marker_board`); the learned chessboard detector looks for a board on
them where the image gave no whole board
(:class:`~ccs_kornia.modules.detection.learned.learned_detector.LearnedChessboardDetector`).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["DEBLUR", "SHARPEN_AMOUNT", "SHARPEN_SIGMA", "UPSCALE", "deblurring_copies", "enhanced_copies"]

#: the sharpened copy: an unsharp mask of this sigma (px) ...
SHARPEN_SIGMA = 2.0
#: ... and this amount (the image plus this times its difference from the blurred image)
SHARPEN_AMOUNT = 1.5
#: the enlarged copy's scale
UPSCALE = 2.0
#: the blurred views' copies (:func:`deblurring_copies`): unsharp masks (sigma px, amount), and each copy's scale
DEBLUR = ((1.5, 4.0, 1.0), (2.5, 3.0, 2.0))


def _unsharp(gray8: np.ndarray, sigma: float, amount: float) -> np.ndarray:
    """An unsharp mask of a ``uint8`` grey image: the image plus ``amount`` times its difference from its Gaussian
    blur of ``sigma`` px, ``uint8``."""
    x = gray8.astype(np.float32)
    return np.clip(np.rint(x + amount * (x - cv2.GaussianBlur(x, (0, 0), sigma))), 0, 255).astype(np.uint8)


def enhanced_copies(gray8: np.ndarray, enlarge: bool = True) -> list[tuple[np.ndarray, float]]:
    """The enhanced copies of a ``uint8`` grey image ``(H, W)``, each with its scale to the image (a point ``p`` of
    the image lies at ``(p + 0.5) * scale - 0.5`` in the copy): the grey levels stretched from the image's 1st and
    99th percentiles to ``0..255``, that copy sharpened by an unsharp mask (:data:`SHARPEN_SIGMA`,
    :data:`SHARPEN_AMOUNT`: blurred edges) and, with ``enlarge``, that copy enlarged :data:`UPSCALE` times (cubic:
    squares or marker bits that span a few pixels).

    Example:
        >>> dim = np.tile(np.arange(20, dtype=np.uint8), (8, 1))
        >>> [(c.shape, s, int(c.max())) for c, s in enhanced_copies(dim)]
        [((8, 20), 1.0, 255), ((8, 20), 1.0, 255), ((16, 40), 2.0, 255)]
    """
    if gray8.dtype != np.uint8 or gray8.ndim != 2:
        raise ValueError(f"expected a uint8 grey image (H, W), got {gray8.dtype} of shape {gray8.shape}.")
    lo, hi = np.percentile(gray8, (1.0, 99.0))
    x = (gray8.astype(np.float32) - float(lo)) * (255.0 / max(float(hi - lo), 1.0))
    stretched = np.clip(np.rint(x), 0, 255).astype(np.uint8)
    sharpened = _unsharp(stretched, SHARPEN_SIGMA, SHARPEN_AMOUNT)
    if not enlarge:
        return [(stretched, 1.0), (sharpened, 1.0)]
    enlarged = cv2.resize(stretched, None, fx=UPSCALE, fy=UPSCALE, interpolation=cv2.INTER_CUBIC)
    return [(stretched, 1.0), (sharpened, 1.0), (enlarged, UPSCALE)]


def deblurring_copies(stretched: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """Copies of a stretched ``uint8`` grey image ``(H, W)`` (the first of :func:`enhanced_copies`) sharpened harder
    for a blurred view (:data:`DEBLUR`: each an unsharp mask's sigma and amount, and the copy's scale), each with its
    scale to the image. A blur of a few px merges a marker's black border with the squares beside it across the
    narrow white margin between them, so OpenCV finds no marker outline; the milder sharpened copy does not undo it.

    Example:
        >>> edge = np.tile(np.repeat(np.array([60, 200], dtype=np.uint8), 10), (8, 1))
        >>> [(c.shape, s) for c, s in deblurring_copies(edge)]
        [((8, 20), 1.0), ((16, 40), 2.0)]
    """
    if stretched.dtype != np.uint8 or stretched.ndim != 2:
        raise ValueError(f"expected a uint8 grey image (H, W), got {stretched.dtype} of shape {stretched.shape}.")
    out = []
    for sigma, amount, scale in DEBLUR:
        sharp = _unsharp(stretched, sigma, amount)
        if scale != 1.0:
            sharp = cv2.resize(sharp, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        out.append((sharp, float(scale)))
    return out
