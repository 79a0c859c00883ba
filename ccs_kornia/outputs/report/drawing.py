"""The plotting primitives every report draws with (OpenCV only), and how a report writes a picture.

Colours (BGR), text, a boxed legend, a colour bar, axes with "nice" ticks (1, 2 or 5 times a power of ten), a white
figure with an image-shaped plot area, and :func:`write_png` with the report's manifest. The figures themselves are
the reports': :mod:`~ccs_kornia.outputs.report.figures` (calibration), :mod:`~ccs_kornia.outputs.report.quality`,
:mod:`~ccs_kornia.outputs.report.rig`, :mod:`~ccs_kornia.outputs.report.hand_eye`.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from ccs_kornia.io.files import text_path

__all__ = [
    "BLACK", "BLUE", "GREEN", "GREY", "MAGENTA", "ORANGE", "RED", "WHITE", "YELLOW",
    "axis_max", "bend_unit", "board_bend_line", "draw_colour_bar", "draw_legend", "draw_plot_frame", "draw_text", "format_number", "image_canvas",
    "int_point", "nice_number", "nice_ticks", "write_png",
]

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_AA = cv2.LINE_AA
#: the reports' colours (BGR)
GREEN, RED, YELLOW, BLUE = (0, 170, 0), (0, 0, 230), (0, 215, 255), (230, 90, 0)
MAGENTA = (200, 0, 200)
ORANGE, BLACK, GREY, WHITE = (0, 140, 255), (0, 0, 0), (150, 150, 150), (255, 255, 255)


def write_png(path: str, image: np.ndarray, written: list[str]) -> bool:
    """Encode ``image`` (H, W[, 3] uint8) as PNG into ``path`` (any characters in the path, through
    :func:`numpy.ndarray.tofile`) and add the path to ``written`` (the report's manifest); False if it cannot be
    encoded."""
    ok, buf = cv2.imencode(".png", image)
    if ok:
        buf.tofile(path)
        written.append(path)
    return bool(ok)


def write_page(path: str, text: str) -> str:
    """Write a report's page (HTML or markdown) as UTF-8, file names that are not UTF-8 escaped
    (:func:`~ccs_kornia.io.files.text_path`); returns ``path``."""
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text_path(text))
    return path


def format_number(value: float | None, digits: int = 4) -> str:
    """``value`` with ``digits`` decimals for a report's tables and legends; ``-`` where there is none (None, NaN).

    Example:
        >>> format_number(0.123456), format_number(2.0, 1), format_number(None), format_number(float("nan"))
        ('0.1235', '2.0', '-', '-')
    """
    return "-" if value is None or value != value else f"{value:.{digits}f}"


#: how each fit's held-out figure of the board's sag reads (the ``board_flatness`` block's key)
_HELDOUT_LABELS = {"heldout_median_px": "held-out median", "heldout_epipolar_px": "held-out epipolar RMS",
                   "heldout_rms_px": "held-out poses' RMS"}


def board_bend_line(flatness: dict | None, square: float | None = None) -> str | None:
    """A report's line on the board's bend (the ``board_flatness`` block of a camera's, rig's or hand-eye JSON), or
    None where it was not judged (HTML: ``&plusmn;``). The sag is in thousandths of the board's unit: mm where the
    square was given in metres, thousandths of a square where no size was given (``square`` 1, the commands' default).

    Example:
        >>> board_bend_line({"kept": True, "warp_m": [-1e-3, 5e-4], "std_m": [1e-5, 1e-5],
        ...                  "heldout_median_px": {"flat": 0.92, "warp": 0.55}}).split(": ")[-1]
        'kept (held-out median 0.9200 px flat, 0.5500 px bent)'
    """
    if not flatness or flatness.get("warp_m") is None:
        return None
    warp = [1000 * float(v) for v in flatness["warp_m"]]
    std = [1000 * float(v) for v in flatness.get("std_m") or (float("nan"), float("nan"))]
    key = next((k for k in _HELDOUT_LABELS if k in flatness), None)
    held = flatness.get(key) or {}
    judged = (f" ({_HELDOUT_LABELS[key]} {format_number(held.get('flat'))} px flat, {format_number(held.get('warp'))} "
              "px bent)") if any(v is not None for v in held.values()) else ""
    return (f"board bend (mrcal's sag c_x, c_y): {warp[0]:+.3f} &plusmn; {std[0]:.3f}, {warp[1]:+.3f} &plusmn; "
            f"{std[1]:.3f} {bend_unit(square)}: {'kept' if flatness.get('kept') else 'not kept, the board taken as flat'}"
            f"{judged}")


def bend_unit(square: float | None) -> str:
    """The unit of a board's sag times 1000: ``mm`` where the board's square was given (in metres), ``1e-3 squares``
    where it was not (``square`` 1, the commands' default: the board's unit is then its square).

    Example:
        >>> bend_unit(0.025), bend_unit(1.0)
        ('mm', '1e-3 squares')
    """
    return "1e-3 squares" if square is not None and float(square) == 1.0 else "mm"


def nice_number(x: float) -> float:
    """The number of the form 1, 2 or 5 times a power of ten nearest below ``x`` (1 where ``x`` is not a positive
    number): tick steps, magnification gains and scale arrows read as round numbers.

    Example:
        >>> nice_number(0.37), nice_number(7.0), nice_number(1500.0)
        (0.2, 5.0, 1000.0)
    """
    if not x > 0 or not math.isfinite(x):
        return 1.0
    e = math.floor(math.log10(x))
    for m in (5.0, 2.0, 1.0):
        if m * 10**e <= x:
            return m * 10**e
    return 10.0**e


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """Ticks in ``[lo, hi]`` about ``count`` steps apart, on multiples of a :func:`nice_number` step.

    Example:
        >>> nice_ticks(0.0, 1.0, 4)
        [0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
    """
    step = nice_number((hi - lo) / max(count, 1)) if hi > lo else 1.0
    first = math.ceil(lo / step - 1e-9) * step
    return [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]


def _tick_label(value: float, step: float) -> str:
    digits = max(0, -math.floor(math.log10(step))) if step > 0 else 0
    return f"{value:.{digits}f}"


def draw_text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.5, color=BLACK, thick: int = 1,
              anchor: str = "left") -> None:
    """Draw ``text`` on ``img`` (H, W, 3) in place, its baseline at ``org``, anchored ``"left"``, ``"centre"`` or
    ``"right"`` of it. File names that are not UTF-8 are drawn escaped (:func:`~ccs_kornia.io.files.text_path`: OpenCV
    cannot take a lone surrogate)."""
    text = text_path(text)
    (tw, th), _ = cv2.getTextSize(text, _FONT, scale, thick)
    x, y = org
    if anchor == "centre":
        x -= tw // 2
    elif anchor == "right":
        x -= tw
    cv2.putText(img, text, (int(x), int(y)), _FONT, scale, color, thick, _AA)


def _vertical_text(img: np.ndarray, text: str, centre: tuple[int, int], scale: float = 0.5) -> None:
    text = text_path(text)
    (tw, th), base = cv2.getTextSize(text, _FONT, scale, 1)
    patch = np.full((th + base + 4, tw + 4, 3), 255, np.uint8)
    cv2.putText(patch, text, (2, th + 2), _FONT, scale, BLACK, 1, _AA)
    patch = cv2.rotate(patch, cv2.ROTATE_90_COUNTERCLOCKWISE)
    x0, y0 = centre[0] - patch.shape[1] // 2, centre[1] - patch.shape[0] // 2
    y0, x0 = max(0, y0), max(0, x0)
    h, w = min(patch.shape[0], img.shape[0] - y0), min(patch.shape[1], img.shape[1] - x0)
    img[y0 : y0 + h, x0 : x0 + w] = np.minimum(img[y0 : y0 + h, x0 : x0 + w], patch[:h, :w])


def draw_legend(img: np.ndarray, items: list[tuple[str, Any, str]], top_right: tuple[int, int]) -> None:
    """Draw a boxed legend on ``img`` in place, its top-right corner at ``top_right``; ``items`` are
    ``(kind, colour, label)`` with kind circle|ring|cross|x|line|dash|arrow|bar."""
    scale, pad, row = 0.45, 8, 20
    width = max(cv2.getTextSize(label, _FONT, scale, 1)[0][0] for _, _, label in items) + 3 * pad + 24
    height = row * len(items) + pad
    x1, y0 = top_right
    x0 = x1 - width
    sub = img[y0 : y0 + height, x0:x1]
    sub[:] = (0.25 * sub + 0.75 * 255).astype(np.uint8)  # translucent white box
    cv2.rectangle(img, (x0, y0), (x1, y0 + height), GREY, 1)
    for k, (kind, colour, label) in enumerate(items):
        cy = y0 + pad + row * k + 6
        cx = x0 + pad + 10
        if kind == "circle":
            cv2.circle(img, (cx, cy), 5, colour, 1, _AA)
        elif kind == "ring":
            cv2.circle(img, (cx, cy), 7, colour, 2, _AA)
        elif kind == "cross":
            cv2.drawMarker(img, (cx, cy), colour, cv2.MARKER_CROSS, 10, 1)
        elif kind == "x":
            cv2.drawMarker(img, (cx, cy), colour, cv2.MARKER_TILTED_CROSS, 10, 2)
        elif kind == "line":
            cv2.line(img, (cx - 10, cy), (cx + 10, cy), colour, 2, _AA)
        elif kind == "dash":
            for x in range(cx - 10, cx + 10, 6):
                cv2.line(img, (x, cy), (x + 3, cy), colour, 2)
        elif kind == "arrow":
            cv2.arrowedLine(img, (cx - 10, cy), (cx + 10, cy), colour, 2, _AA, tipLength=0.35)
        else:  # bar
            cv2.rectangle(img, (cx - 8, cy - 6), (cx + 8, cy + 6), colour, -1)
            cv2.rectangle(img, (cx - 8, cy - 6), (cx + 8, cy + 6), GREY, 1)
        draw_text(img, label, (cx + 18, cy + 5), scale)


def draw_colour_bar(img: np.ndarray, box: tuple[int, int, int, int], vmax: float, label: str,
                    colormap: int = cv2.COLORMAP_VIRIDIS) -> None:
    """Draw a vertical colour bar on ``img`` in place, in ``box = (x, y, w, h)``, for values ``0..vmax`` with ticks and
    a label."""
    x, y, w, h = box
    ramp = np.linspace(255, 0, h).astype(np.uint8)[:, None].repeat(w, 1)
    img[y : y + h, x : x + w] = cv2.applyColorMap(ramp, colormap)
    cv2.rectangle(img, (x, y), (x + w, y + h), BLACK, 1)
    ticks = nice_ticks(0.0, vmax, 4)
    step = ticks[1] - ticks[0] if len(ticks) > 1 else vmax
    for t in ticks:
        ty = int(round(y + h - h * t / vmax)) if vmax > 0 else y + h
        cv2.line(img, (x + w, ty), (x + w + 4, ty), BLACK, 1)
        draw_text(img, _tick_label(t, step), (x + w + 7, ty + 5), 0.42)
    _vertical_text(img, label, (x + w + 62, y + h // 2), 0.45)


def draw_plot_frame(img: np.ndarray, box: tuple[int, int, int, int], xr: tuple[float, float], yr: tuple[float, float],
                    xlabel: str, ylabel: str, y_down: bool = False, grid: bool = True,
                    xticks: list[float] | None = None) -> None:
    """Draw axes with ticks, tick labels and axis titles around ``box = (x, y, w, h)`` of ``img`` in place (data
    ranges ``xr``, ``yr``; ``y_down``: the y axis grows downwards, as an image's rows)."""
    x0, y0, w, h = box
    cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), BLACK, 1)
    xt = xticks if xticks is not None else nice_ticks(*xr, 6)
    xstep = xt[1] - xt[0] if len(xt) > 1 else 1.0
    for t in xt:
        px = int(round(x0 + (t - xr[0]) / (xr[1] - xr[0]) * w))
        cv2.line(img, (px, y0 + h), (px, y0 + h + 5), BLACK, 1)
        draw_text(img, _tick_label(t, xstep), (px, y0 + h + 20), 0.42, anchor="centre")
    yt = nice_ticks(*yr, 5)
    ystep = yt[1] - yt[0] if len(yt) > 1 else 1.0
    for t in yt:
        frac = (t - yr[0]) / (yr[1] - yr[0])
        py = int(round(y0 + frac * h)) if y_down else int(round(y0 + h - frac * h))
        cv2.line(img, (x0 - 5, py), (x0, py), BLACK, 1)
        if grid:
            cv2.line(img, (x0 + 1, py), (x0 + w - 1, py), (225, 225, 225), 1)
        draw_text(img, _tick_label(t, ystep), (x0 - 8, py + 5), 0.42, anchor="right")
    draw_text(img, xlabel, (x0 + w // 2, y0 + h + 42), 0.5, anchor="centre")
    _vertical_text(img, ylabel, (22, y0 + h // 2), 0.5)


def int_point(p) -> tuple[int, int]:
    """The pixel ``(x, y)`` nearest a point (any two numbers), as OpenCV's drawing functions take it.

    Example:
        >>> int_point(np.array([3.4, 7.6]))
        (3, 8)
    """
    return int(round(float(p[0]))), int(round(float(p[1])))


def image_canvas(size: tuple[int, int], title: str, right_margin: int = 130) -> tuple[np.ndarray, tuple[int, int, int, int], float]:
    """A white figure titled ``title`` with a plot area of the image's ``size`` ``(W, H)`` shape (at most 900 x 640);
    returns (figure (h, w, 3) uint8, plot box ``(x, y, w, h)``, image -> plot scale).

    Example:
        >>> fig, box, scale = image_canvas((640, 480), "title")
        >>> fig.shape, box, round(scale, 3)
        ((750, 1063, 3), (80, 50, 853, 640), 1.333)
    """
    w_img, h_img = size
    scale = min(900 / w_img, 640 / h_img)
    w, h = int(round(w_img * scale)), int(round(h_img * scale))
    left, top, bottom = 80, 50, 60
    img = np.full((top + h + bottom, left + w + right_margin, 3), 255, np.uint8)
    draw_text(img, title, (left, 30), 0.6)
    return img, (left, top, w, h), scale


def axis_max(value: float) -> float:
    """The top of an axis showing ``value``: a multiple of a :func:`nice_number` step a quarter of it, with at least
    2 % of headroom (1 where ``value`` is not positive).

    Example:
        >>> axis_max(0.37), axis_max(9.9)
        (0.4, 12.0)
    """
    if not value > 0:
        return 1.0
    step = nice_number(value / 4)
    return math.ceil(value * 1.02 / step) * step
