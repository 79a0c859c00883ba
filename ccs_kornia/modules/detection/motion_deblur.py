r"""A straight motion blur measured on the image itself, and undone: a marker's bits smeared by a camera or board
that moved during the exposure come back where the blur is a line of known length and direction.

A blur along a line of ``L`` px multiplies the image's spectrum by a sinc whose zeros repeat every ``1 / L`` cycles
per px along the line, so the **cepstrum** (the inverse transform of the log spectrum) has a deep negative peak at
``L`` px in the line's direction, on both sides of its origin (:func:`motion_blur`; Rom, "On the cepstrum of
two-dimensional functions", 1975, and the blind motion deblurring literature since). Where the peak stands out from
the rest of the cepstrum at those distances the blur is taken as found, and a Wiener filter with that line as its
kernel (:func:`deblur_motion`) gives the copy markers are decoded on, and the copy a chessboard is looked for on and
its corners refined on where the image's own saddle fit fails (a milder filter, :data:`REFINE_NOISE`). An image
without such a blur (sharp, or blurred alike in every direction) has no such peak and gets no copy.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["MIN_PEAK", "MOTION_LENGTHS", "REFINE_NOISE", "WIENER_NOISE", "deblur_motion", "line_kernel", "motion_blur"]

#: the blur lengths searched (px): a shorter blur leaves markers readable, and an isotropic blur's cepstrum dips near its
#: origin
MOTION_LENGTHS = (9, 40)
#: a blur is found where its cepstrum peak lies this many standard deviations below the mean of the cepstrum over the
#: searched lengths and directions
MIN_PEAK = 5.0
#: the Wiener filter's noise-to-signal power (of a spectrum in grey levels)
WIENER_NOISE = 0.01
#: the noise-to-signal power of the copy a board's corners are refined on: it rings less than the decoding copy's (on
#: rendered boards smeared 15 px, the corners' mean error 0.006-0.06 px against 0.02-0.09 px with
#: :data:`WIENER_NOISE`; on the real chessboard sets' motion-blurred copies as many boards and corners: docs/detection.md)
REFINE_NOISE = 0.2
#: directions searched over half a turn
_DIRECTIONS = 180
#: the cepstrum is measured on the image reduced to at most this many px on its longer side (speed), the blur's length
#: scaled back
_MAX_SIDE = 1024


def _grey(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"Expected a (H, W) grey image, got shape {image.shape}.")
    return image


def line_kernel(length: int, angle: float) -> np.ndarray:
    """A normalised anti-aliased line of ``length`` px through the kernel's centre at ``angle`` (radians) ``(k, k)``,
    ``k`` the odd size that holds it.

    Example:
        >>> k = line_kernel(5, 0.0)
        >>> k.shape, round(float(k.sum()), 6), round(float(k[2].sum()), 6)
        ((5, 5), 1.0, 1.0)
    """
    size = int(length) | 1
    k = np.zeros((size, size), np.float32)
    c = (size - 1) / 2.0
    d = np.array([math.cos(angle), math.sin(angle)]) * (length - 1) / 2.0
    cv2.line(k, tuple(np.round([c - d[0], c - d[1]]).astype(int).tolist()),
             tuple(np.round([c + d[0], c + d[1]]).astype(int).tolist()), 1.0, 1, cv2.LINE_AA)
    return k / k.sum()


def motion_blur(gray8: np.ndarray) -> tuple[int, float] | None:
    """The straight motion blur of a grey image ``(H, W)``: its length (px) and direction (radians in ``[0, pi)``), or
    ``None`` where the cepstrum shows none (:data:`MIN_PEAK`).

    Example:
        >>> rng = np.random.default_rng(0)
        >>> sharp = rng.integers(0, 256, (256, 256)).astype(np.float32)
        >>> blurred = cv2.filter2D(sharp, -1, line_kernel(15, 0.5), borderType=cv2.BORDER_REFLECT)
        >>> length, angle = motion_blur(blurred.astype(np.uint8))
        >>> length, round(angle, 1)
        (15, 0.5)
        >>> motion_blur(sharp.astype(np.uint8)) is None
        True
    """
    x = _grey(gray8).astype(np.float32)
    scale = min(1.0, _MAX_SIDE / max(x.shape))
    if scale < 1.0:
        x = cv2.resize(x, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    h, w = x.shape
    lo, hi = MOTION_LENGTHS
    lo_s, hi_s = max(2, int(math.ceil(lo * scale))), int(math.ceil(hi * scale))
    if min(h, w) < 4 * hi_s:
        return None
    x = (x - x.mean()) * np.outer(np.hanning(h), np.hanning(w)).astype(np.float32)
    spectrum = np.log(np.abs(np.fft.rfft2(x)) + 1e-3)
    cep = np.fft.fftshift(np.fft.irfft2(spectrum, s=(h, w)))
    lengths = np.arange(lo_s, hi_s + 1, dtype=np.float64)
    angles = np.arange(_DIRECTIONS) * (math.pi / _DIRECTIONS)
    dx = lengths[:, None] * np.cos(angles)[None]
    dy = lengths[:, None] * np.sin(angles)[None]
    cy, cx = h // 2, w // 2
    # the cepstrum is symmetric about its origin: both ends of the line alike
    vals = cep[np.rint(cy + dy).astype(int), np.rint(cx + dx).astype(int)]
    vals = vals + cep[np.rint(cy - dy).astype(int), np.rint(cx - dx).astype(int)]
    i, j = np.unravel_index(np.argmin(vals), vals.shape)
    spread = float(vals.std())
    if not spread > 0 or (float(vals.mean()) - float(vals[i, j])) / spread < MIN_PEAK:
        return None
    return int(round(lengths[i] / scale)), float(angles[j])


def deblur_motion(gray: np.ndarray, length: int, angle: float, noise: float = WIENER_NOISE) -> np.ndarray:
    """A grey image ``(H, W)`` with the straight motion blur of ``length`` px at ``angle`` undone by a Wiener filter
    whose noise-to-signal power is ``noise`` (:data:`WIENER_NOISE`: the sharpest copy, where markers are decoded; a
    larger one rings less), ``(H, W)``: ``uint8`` for a ``uint8`` image (markers are decoded on it), else ``float64``
    on the image's own scale, unrounded (corners are refined on it: the line is symmetric, so a corner's saddle stays
    where it was while the blur across it is gone).

    Example:
        >>> img = np.zeros((64, 64), np.uint8)
        >>> img[:, 32:] = 200
        >>> blurred = cv2.filter2D(img, -1, line_kernel(9, 0.0), borderType=cv2.BORDER_REFLECT)
        >>> sharp = deblur_motion(blurred, 9, 0.0)
        >>> int(abs(int(sharp[32, 28]) - 0)) < 20, int(abs(int(sharp[32, 36]) - 200)) < 20
        (True, True)
        >>> soft = deblur_motion(blurred / 255.0, 9, 0.0)
        >>> soft.dtype, abs(float(soft[32, 36]) - 200 / 255) < 0.08
        (dtype('float64'), True)
    """
    image = _grey(gray)
    x = image.astype(np.float64)
    if int(length) < 1:
        raise ValueError(f"the blur's length must be at least 1 px, got {length}.")
    h, w = x.shape
    k = line_kernel(length, angle).astype(np.float64)
    pad = np.zeros((h, w))
    pad[:k.shape[0], :k.shape[1]] = k
    pad = np.roll(pad, (-(k.shape[0] // 2), -(k.shape[1] // 2)), (0, 1))
    f, kf = np.fft.rfft2(x), np.fft.rfft2(pad)
    # the noise-to-signal ratio is relative to the kernel's unit gain: the same on any grey scale
    out = np.fft.irfft2(f * np.conj(kf) / (np.abs(kf) ** 2 + noise), s=(h, w))
    if image.dtype != np.uint8:
        return out
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
