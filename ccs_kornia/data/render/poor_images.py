"""Real photographs made poor: the low light, blur, small size and compression a camera gives a board in bad
conditions, applied to an existing ``uint8`` grey photograph.

The conditions (:data:`POOR_CONDITIONS`):

* ``dark``: grey levels times :data:`DARK` (0.12), then Gaussian noise of :data:`READ_NOISE` (2) grey levels;
* ``dark sensor``: the same light on a sensor: grey levels times :data:`DARK` counted as photo-electrons
  (:data:`GAIN` grey levels per electron: Poisson shot noise), then the read noise;
* ``blur``: Gaussian blur, sigma :data:`BLUR_SIGMA` (2.5) px;
* ``motion``: a straight motion blur :data:`MOTION_PX` (15) px long in a direction drawn per image;
* ``small``: the image scaled by :data:`SMALL` (0.4) with area interpolation (corner ``p`` goes to
  ``(p + 0.5) * 0.4 - 0.5``);
* ``jpeg``: JPEG at quality :data:`JPEG_QUALITY` (30).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["BLUR_SIGMA", "DARK", "GAIN", "JPEG_QUALITY", "MOTION_PX", "POOR_CONDITIONS", "READ_NOISE", "SMALL",
           "make_poor", "motion_kernel", "scale_points"]

#: light left in the dark conditions
DARK = 0.12
#: read noise of the dark conditions (grey levels)
READ_NOISE = 2.0
#: grey levels per photo-electron of the ``dark sensor`` condition (a white of 255 is 1020 electrons before darkening)
GAIN = 0.25
#: Gaussian blur (px)
BLUR_SIGMA = 2.5
#: motion blur length (px)
MOTION_PX = 15
#: scale of the ``small`` condition
SMALL = 0.4
#: JPEG quality
JPEG_QUALITY = 30
#: the conditions, in the order the benchmark reports them
POOR_CONDITIONS: tuple[str, ...] = ("dark", "dark sensor", "blur", "motion", "small", "jpeg")


def motion_kernel(length: int, angle: float) -> np.ndarray:
    """A normalised line of ``length`` px through the kernel's centre at ``angle`` (radians), ``(length, length)``.

    Example:
        >>> k = motion_kernel(5, 0.0)
        >>> k.shape, round(float(k.sum()), 6), round(float(k[2].sum()), 6)
        ((5, 5), 1.0, 1.0)
    """
    k = np.zeros((length, length), np.float32)
    c = (length - 1) / 2.0
    d = np.array([np.cos(angle), np.sin(angle)]) * c
    cv2.line(k, tuple(np.round([c - d[0], c - d[1]]).astype(int).tolist()),
             tuple(np.round([c + d[0], c + d[1]]).astype(int).tolist()), 1.0, 1, cv2.LINE_AA)
    return k / k.sum()


def make_poor(gray8: np.ndarray, condition: str, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A ``uint8`` grey image ``(H, W)`` under one of :data:`POOR_CONDITIONS` (``"clean"``: unchanged), and the scale
    of its pixel grid to the original's (``small``: :data:`SMALL`, else 1).

    Args:
        gray8: ``(H, W)`` ``uint8``.
        condition: ``"clean"`` or one of :data:`POOR_CONDITIONS`.
        rng: the noise and the motion's direction.

    Returns:
        ``(image, scale)``: the poor image ``uint8`` and the scale (:func:`scale_points` moves corners with it).

    Example:
        >>> img = np.full((40, 60), 200, np.uint8)
        >>> dark, s = make_poor(img, "dark", np.random.default_rng(0))
        >>> dark.shape, s, 20 < float(dark.mean()) < 28
        ((40, 60), 1.0, True)
        >>> make_poor(img, "small", np.random.default_rng(0))[0].shape
        (16, 24)
    """
    if gray8.ndim != 2 or gray8.dtype != np.uint8:
        raise ValueError(f"Expected a (H, W) uint8 image, got {gray8.shape} {gray8.dtype}.")
    x = gray8.astype(np.float64)
    if condition == "clean":
        return gray8.copy(), 1.0
    if condition == "dark":
        y = x * DARK + rng.normal(0.0, READ_NOISE, x.shape)
    elif condition == "dark sensor":
        y = rng.poisson(x * DARK / GAIN) * GAIN + rng.normal(0.0, READ_NOISE, x.shape)
    elif condition == "blur":
        y = cv2.GaussianBlur(x, (0, 0), BLUR_SIGMA, borderType=cv2.BORDER_REFLECT)
    elif condition == "motion":
        y = cv2.filter2D(x, -1, motion_kernel(MOTION_PX, float(rng.uniform(0.0, np.pi))),
                         borderType=cv2.BORDER_REFLECT)
    elif condition == "small":
        return cv2.resize(gray8, None, fx=SMALL, fy=SMALL, interpolation=cv2.INTER_AREA), SMALL
    elif condition == "jpeg":
        ok, buf = cv2.imencode(".jpg", gray8, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE), 1.0
    else:
        raise ValueError(f"Unknown condition {condition!r}; expected 'clean' or one of {POOR_CONDITIONS}.")
    return np.clip(np.rint(y), 0, 255).astype(np.uint8), 1.0


def scale_points(points: np.ndarray, scale: float) -> np.ndarray:
    """Pixel coordinates ``(..., 2)`` (pixel centres at integers) on an image resized by ``scale``.

    Example:
        >>> scale_points(np.array([[-0.5, 9.5]]), 0.4).tolist()
        [[-0.5, 3.5]]
    """
    return (np.asarray(points, dtype=np.float64) + 0.5) * scale - 0.5
