r"""A Gaussian (defocus-like) blur measured on the image itself, and undone: a marker's bits and outline merged by
a blur of a few px come back where the blur's width is known.

The width is measured at the image's strongest edges by **re-blurring** (Zhuo and Sim, "Defocus map estimation from
a single image", 2011): a step edge blurred by a Gaussian of :math:`\sigma` has a gradient peak
:math:`\propto 1/\sigma`; blurred again by :math:`\sigma_0` it becomes :math:`\propto 1/\sqrt{\sigma^2+\sigma_0^2}`,
so the ratio :math:`R` of the two peaks gives :math:`\sigma = \sigma_0/\sqrt{R^2-1}` (:func:`gaussian_blur_sigma`:
the median over the strongest edge pixels, where a board's edges are the image's sharpest steps). A Wiener filter
with that Gaussian as its kernel (:func:`deblur_gaussian`) gives the copy markers are decoded on. The kernel is
symmetric, so undoing it moves no corner.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["ACROSS", "GAUSSIAN_WIENER_NOISE", "MIN_SIGMA", "REBLUR_SIGMA", "deblur_gaussian", "gaussian_blur_sigma"]

#: the second blur of the re-blur measure (px)
REBLUR_SIGMA = 2.0
#: a blur narrower than this (px) is left to the sharpened copies: a sharp webcam frame measures 0.5 to 1.6 px
MIN_SIGMA = 2.0
#: the Wiener filter's noise-to-signal power (relative to the kernel's unit gain at zero frequency)
GAUSSIAN_WIENER_NOISE = 3e-4
#: the edges whose gradient lies within this angle (radians) of a direction asked for
ACROSS = math.pi / 8
#: the edges measured: Canny's hysteresis thresholds (grey levels of a stretched image) ...
_CANNY = (40, 100)
#: ... and the strongest of them, above this percentile of their gradient
_STRONGEST = 90.0


def _grey8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"Expected a (H, W) uint8 grey image, got {image.shape} {image.dtype}.")
    return image


def _gradient(x: np.ndarray, where: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The gradient's magnitude and direction (radians) of ``x`` at the pixels ``where`` (rows, columns)."""
    gx, gy = cv2.Sobel(x, cv2.CV_32F, 1, 0, ksize=3)[where], cv2.Sobel(x, cv2.CV_32F, 0, 1, ksize=3)[where]
    return np.hypot(gx, gy), np.arctan2(gy, gx)


def gaussian_blur_sigma(gray8: np.ndarray, direction: float | None = None) -> float:
    """The Gaussian blur (sigma, px) of a ``uint8`` grey image ``(H, W)`` measured at its strongest edges by
    re-blurring (module doc); NaN where it has no edge. A contrast-stretched image measures best (the edges are found
    at fixed grey-level thresholds). ``direction`` (radians): only the edges whose gradient lies within
    :data:`ACROSS` of it (either way), the blur across a motion blur's line of that direction.

    Example:
        >>> img = np.zeros((100, 100), np.float32)
        >>> img[:, 50:] = 200
        >>> img[30:70, 20:80] = 100
        >>> sharp = gaussian_blur_sigma(img.astype(np.uint8))
        >>> blurred = gaussian_blur_sigma(cv2.GaussianBlur(img, (0, 0), 2.5).astype(np.uint8))
        >>> sharp < 1.0, 2.3 < blurred < 2.9
        (True, True)
    """
    gray8 = _grey8(gray8)
    edges = cv2.Canny(gray8, *_CANNY) > 0
    if not edges.any():
        return float("nan")
    x = gray8.astype(np.float32)
    where = np.nonzero(edges)
    (g, angle), (g_again, _) = _gradient(x, where), _gradient(cv2.GaussianBlur(x, (0, 0), REBLUR_SIGMA), where)
    if direction is not None:
        off = np.abs((angle - direction + 0.5 * math.pi) % math.pi - 0.5 * math.pi)
        g, g_again = g[off <= ACROSS], g_again[off <= ACROSS]
        if not g.size:
            return float("nan")
    strong = g >= np.percentile(g, _STRONGEST)
    ratio = g[strong] / np.maximum(g_again[strong], 1e-6)
    ratio = ratio[ratio > 1.0 + 1e-4]
    if not ratio.size:
        return float("nan")
    return float(np.median(REBLUR_SIGMA / np.sqrt(ratio**2 - 1.0)))


def deblur_gaussian(gray8: np.ndarray, sigma: float, noise: float = GAUSSIAN_WIENER_NOISE) -> np.ndarray:
    """A ``uint8`` grey image ``(H, W)`` with a Gaussian blur of ``sigma`` px undone by a Wiener filter (``noise``:
    the noise-to-signal power), ``(H, W)`` ``uint8``.

    Example:
        >>> img = np.zeros((64, 64), np.float32)
        >>> img[:, 28:36] = 200
        >>> blurred = cv2.GaussianBlur(img, (0, 0), 2.5).astype(np.uint8)
        >>> sharp = deblur_gaussian(blurred, 2.5)
        >>> int(blurred[32, 32]) < 180, int(sharp[32, 32]) > 200, int(sharp[32, 24]) < 10
        (True, True, True)
    """
    x = _grey8(gray8).astype(np.float64)
    if not sigma > 0:
        raise ValueError(f"the blur's sigma must be positive, got {sigma}.")
    h, w = x.shape
    # mirrored at the borders, as the blur was: no ringing from the frame's wrap-around
    padded = np.pad(x, ((h // 4, h // 4), (w // 4, w // 4)), mode="reflect")
    ph, pw = padded.shape
    fy, fx = np.fft.fftfreq(ph)[:, None], np.fft.rfftfreq(pw)[None]
    kf = np.exp(-2.0 * math.pi**2 * sigma**2 * (fx**2 + fy**2))
    out = np.fft.irfft2(np.fft.rfft2(padded) * kf / (kf**2 + noise), s=(ph, pw))[h // 4:h // 4 + h, w // 4:w // 4 + w]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
