"""The figure of ``imu-noise --plot``, drawn with OpenCV only (the plotting primitives of
:mod:`ccs_kornia.outputs.report.drawing`): the Allan deviation of the gyroscope's and the accelerometer's axes on
log-log axes with the fitted curves, the two values read off them (the white noise at 1 s, the random walk at 3 s)
marked, and the -1/2 and +1/2 slope lines they are read on.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ccs_kornia.outputs.report.drawing import (
    BLACK,
    BLUE,
    GREEN,
    RED,
    draw_legend,
    draw_plot_frame,
    draw_text,
)

__all__ = ["allan_figure"]

_AXES = (("x", RED), ("y", GREEN), ("z", BLUE))


def _panel(img: np.ndarray, box: tuple[int, int, int, int], taus: np.ndarray, adev: np.ndarray, fit: np.ndarray,
           white: np.ndarray, walk: np.ndarray, title: str, unit: str) -> None:
    """One sensor's panel: three axes' curves (thick), their fits (thin black), the values read off them (rings at 1
    and 3 s) and the two lines of the axes' mean (dashed)."""
    lx = np.log10(taus)
    values = np.concatenate([a[np.isfinite(a) & (a > 0)] for a in (adev, fit, white, walk)])
    xr = (math.floor(lx.min()), math.ceil(max(lx.max(), math.log10(3.0))))
    yr = (math.floor(math.log10(values.min())), math.ceil(math.log10(values.max()))) if values.size else (-6, 0)
    yr = (yr[0], yr[1] + 1) if yr[1] == yr[0] else yr
    draw_plot_frame(img, box, xr, yr, "log10 averaging time (s)", "", xticks=list(range(xr[0], xr[1] + 1)))
    x0, y0, w, h = box

    def px(lt: float, lv: float) -> tuple[int, int]:
        return round(x0 + (lt - xr[0]) / (xr[1] - xr[0]) * w), round(y0 + h - (lv - yr[0]) / (yr[1] - yr[0]) * h)

    for c, (_, colour) in enumerate(_AXES):
        ok = np.isfinite(adev[:, c]) & (adev[:, c] > 0)
        pts = np.array([px(a, math.log10(b)) for a, b in zip(lx[ok], adev[ok, c])], np.int32)
        if len(pts) > 1:
            cv2.polylines(img, [pts], False, colour, 2, cv2.LINE_AA)
        fitted = np.array([px(a, math.log10(b)) for a, b in zip(lx, fit[:, c]) if b > 0], np.int32)
        if len(fitted) > 1:  # the fitted curve, thin over the measured one
            cv2.polylines(img, [fitted], False, BLACK, 1, cv2.LINE_AA)
        for tau, value in ((1.0, white[c]), (3.0, walk[c] if walk[c] > 0 else None)):
            if value is not None and value > 0:
                cv2.circle(img, px(math.log10(tau), math.log10(value)), 6, colour, 2, cv2.LINE_AA)
    # the two lines the values are read on, for the mean of the axes: -1/2 through N at 1 s, +1/2 through K at 3 s
    ends = np.array([lx.min(), lx.max()])
    n, k = float(np.mean(white)), float(np.mean(walk))
    lines = [(ends, math.log10(n) - 0.5 * ends)] if n > 0 else []
    lines += [(ends, math.log10(k) + 0.5 * (ends - math.log10(3.0)))] if k > 0 else []
    for xs, ys in lines:
        a, b = np.array(px(xs[0], ys[0]), np.float64), np.array(px(xs[1], ys[1]), np.float64)
        steps = max(2, int(np.linalg.norm(b - a) / 6))
        for i in range(0, steps - 1, 2):
            p, q = a + (b - a) * i / steps, a + (b - a) * (i + 1) / steps
            if y0 <= p[1] <= y0 + h and y0 <= q[1] <= y0 + h:
                cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), BLACK, 1, cv2.LINE_AA)
    draw_text(img, f"{title}: log10 Allan deviation ({unit})", (x0, y0 - 10), 0.5, BLACK)


def allan_figure(taus: np.ndarray, gyro: np.ndarray, accel: np.ndarray, gyro_fit: np.ndarray, accel_fit: np.ndarray,
                 noise: dict[str, np.ndarray]) -> np.ndarray:
    """The Allan deviation figure: the gyroscope's panel above the accelerometer's.

    Args:
        taus: :math:`(T,)` averaging times (s).
        gyro: :math:`(T, 3)` the gyroscope's Allan deviation (rad/s).
        accel: :math:`(T, 3)` the accelerometer's (m/s^2).
        gyro_fit: :math:`(T, 3)` the fitted curves (rad/s).
        accel_fit: :math:`(T, 3)` the fitted curves (m/s^2).
        noise: ``gyro_white``, ``gyro_walk``, ``accel_white``, ``accel_walk``: :math:`(3,)` each, the values read off
            the fit (the white noise density is the -1/2 line at 1 s, the random walk the +1/2 line at 3 s).

    Returns:
        the figure (H, W, 3) uint8, BGR.

    Example:
        >>> taus = np.logspace(-2, 3, 40)
        >>> dev = np.sqrt(1e-6 / taus + 1e-8 * taus / 3)[:, None].repeat(3, 1)
        >>> n = {k: np.full(3, v) for k, v in (("gyro_white", 1e-3), ("gyro_walk", 1e-4), ("accel_white", 1e-3),
        ...                                    ("accel_walk", 1e-4))}
        >>> allan_figure(taus, dev, dev, dev, dev, n).shape
        (900, 900, 3)
    """
    img = np.full((900, 900, 3), 255, np.uint8)
    panels = ((gyro, gyro_fit, "gyro", "gyroscope", "rad/s"), (accel, accel_fit, "accel", "accelerometer", "m/s^2"))
    for k, (dev, fit, key, title, unit) in enumerate(panels):
        box = (90, 50 + 440 * k, 780, 340)
        _panel(img, box, np.asarray(taus, np.float64), np.asarray(dev, np.float64), np.asarray(fit, np.float64),
               np.asarray(noise[f"{key}_white"], np.float64), np.asarray(noise[f"{key}_walk"], np.float64), title, unit)
        draw_legend(img, [("line", colour, f"{title} {axis}") for axis, colour in _AXES] + [("line", BLACK, "fit")]
                    + [("dash", BLACK, "-1/2 and +1/2 lines (mean)"), ("ring", BLACK, "N at 1 s, K at 3 s")], (box[0] + box[2] - 6, box[1] + 6))
    return img
