"""Human-readable calibration report (``calibrate --report DIR``), drawn with OpenCV only.

Writes into ``DIR``:

* ``index.html``: parameters with their standard deviations, RMS, the figures below and a table of
  every view (used or not, RMS, reason, link to its overlay);
* ``views/view_XXXX_<name>.png`` for every view with a detected board: detected corners (green
  circles), their reprojection through the calibrated model (red crosses), residuals magnified
  (yellow lines, the gain is printed on the image) and the first grid corner (blue ring);
* ``rms_per_view.png``: bar chart of the per-view RMS (used views green, excluded ones orange at the
  RMS they would have under the final camera), with the overall RMS as a dashed line;
* ``residuals.png``: every residual vector of the used views at its place in the image, magnified,
  coloured by length, with a scale arrow and a colour bar;
* ``coverage.png``: how many detected corners fall in each cell of the image, with the outline of
  every used board (a calibration is well constrained only where corners were seen);
* ``undistorted.png``: one used view next to its undistorted version (same parameters as
  ``cv2.undistort``);
* ``summary.md``: the parameter and view tables as Markdown.

Only what ``calibrate`` writes into its JSON is used, plus the images themselves. Large images are
drawn at most :data:`DISPLAY_MAX_SIDE` pixels wide/high so the report stays small and quick.
"""

from __future__ import annotations

import html
import math
import os
import sys
from typing import Any

import cv2
import numpy as np
import torch

from ccs_kornia.camera import board_object_points, project_points
from ccs_kornia.io import load_image_gray

__all__ = ["write_report", "DISPLAY_MAX_SIDE"]

#: longest side of any picture in the report
DISPLAY_MAX_SIDE = 1280

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_AA = cv2.LINE_AA
# BGR colours
_GREEN, _RED, _YELLOW, _BLUE = (0, 170, 0), (0, 0, 230), (0, 215, 255), (230, 90, 0)
_ORANGE, _BLACK, _GREY, _WHITE = (0, 140, 255), (0, 0, 0), (150, 150, 150), (255, 255, 255)
_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def _fmt(value: float | None, digits: int = 4) -> str:
    return "-" if value is None or value != value else f"{value:.{digits}f}"


def _nice_number(x: float) -> float:
    """The number of the form 1, 2 or 5 times a power of ten nearest below ``x``."""
    if not x > 0 or not math.isfinite(x):
        return 1.0
    e = math.floor(math.log10(x))
    for m in (5.0, 2.0, 1.0):
        if m * 10**e <= x:
            return m * 10**e
    return 10.0**e


def _ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    step = _nice_number((hi - lo) / max(count, 1)) if hi > lo else 1.0
    first = math.ceil(lo / step - 1e-9) * step
    return [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]


def _tick_label(value: float, step: float) -> str:
    digits = max(0, -math.floor(math.log10(step))) if step > 0 else 0
    return f"{value:.{digits}f}"


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.5, color=_BLACK, thick: int = 1,
          anchor: str = "left") -> None:
    (tw, th), _ = cv2.getTextSize(text, _FONT, scale, thick)
    x, y = org
    if anchor == "centre":
        x -= tw // 2
    elif anchor == "right":
        x -= tw
    cv2.putText(img, text, (int(x), int(y)), _FONT, scale, color, thick, _AA)


def _vertical_text(img: np.ndarray, text: str, centre: tuple[int, int], scale: float = 0.5) -> None:
    (tw, th), base = cv2.getTextSize(text, _FONT, scale, 1)
    patch = np.full((th + base + 4, tw + 4, 3), 255, np.uint8)
    cv2.putText(patch, text, (2, th + 2), _FONT, scale, _BLACK, 1, _AA)
    patch = cv2.rotate(patch, cv2.ROTATE_90_COUNTERCLOCKWISE)
    x0, y0 = centre[0] - patch.shape[1] // 2, centre[1] - patch.shape[0] // 2
    y0, x0 = max(0, y0), max(0, x0)
    h, w = min(patch.shape[0], img.shape[0] - y0), min(patch.shape[1], img.shape[1] - x0)
    img[y0 : y0 + h, x0 : x0 + w] = np.minimum(img[y0 : y0 + h, x0 : x0 + w], patch[:h, :w])


def _legend(img: np.ndarray, items: list[tuple[str, Any, str]], top_right: tuple[int, int]) -> None:
    """Draw a boxed legend; ``items`` are ``(kind, colour, label)`` with kind circle|cross|line|bar|dash."""
    scale, pad, row = 0.45, 8, 20
    width = max(cv2.getTextSize(label, _FONT, scale, 1)[0][0] for _, _, label in items) + 3 * pad + 24
    height = row * len(items) + pad
    x1, y0 = top_right
    x0 = x1 - width
    sub = img[y0 : y0 + height, x0:x1]
    sub[:] = (0.25 * sub + 0.75 * 255).astype(np.uint8)  # translucent white box
    cv2.rectangle(img, (x0, y0), (x1, y0 + height), _GREY, 1)
    for k, (kind, colour, label) in enumerate(items):
        cy = y0 + pad + row * k + 6
        cx = x0 + pad + 10
        if kind == "circle":
            cv2.circle(img, (cx, cy), 5, colour, 1, _AA)
        elif kind == "ring":
            cv2.circle(img, (cx, cy), 7, colour, 2, _AA)
        elif kind == "cross":
            cv2.drawMarker(img, (cx, cy), colour, cv2.MARKER_CROSS, 10, 1)
        elif kind == "line":
            cv2.line(img, (cx - 10, cy), (cx + 10, cy), colour, 2, _AA)
        elif kind == "dash":
            for x in range(cx - 10, cx + 10, 6):
                cv2.line(img, (x, cy), (x + 3, cy), colour, 2)
        elif kind == "arrow":
            cv2.arrowedLine(img, (cx - 10, cy), (cx + 10, cy), colour, 2, _AA, tipLength=0.35)
        else:  # bar
            cv2.rectangle(img, (cx - 8, cy - 6), (cx + 8, cy + 6), colour, -1)
            cv2.rectangle(img, (cx - 8, cy - 6), (cx + 8, cy + 6), _GREY, 1)
        _text(img, label, (cx + 18, cy + 5), scale)


def _colour_bar(img: np.ndarray, box: tuple[int, int, int, int], vmax: float, label: str,
                colormap: int = cv2.COLORMAP_VIRIDIS) -> None:
    """Vertical colour bar in ``box = (x, y, w, h)`` for values ``0..vmax`` with ticks and a label."""
    x, y, w, h = box
    ramp = np.linspace(255, 0, h).astype(np.uint8)[:, None].repeat(w, 1)
    img[y : y + h, x : x + w] = cv2.applyColorMap(ramp, colormap)
    cv2.rectangle(img, (x, y), (x + w, y + h), _BLACK, 1)
    ticks = _ticks(0.0, vmax, 4)
    step = ticks[1] - ticks[0] if len(ticks) > 1 else vmax
    for t in ticks:
        ty = int(round(y + h - h * t / vmax)) if vmax > 0 else y + h
        cv2.line(img, (x + w, ty), (x + w + 4, ty), _BLACK, 1)
        _text(img, _tick_label(t, step), (x + w + 7, ty + 5), 0.42)
    _vertical_text(img, label, (x + w + 62, y + h // 2), 0.45)


def _plot_frame(img: np.ndarray, box: tuple[int, int, int, int], xr: tuple[float, float], yr: tuple[float, float],
                xlabel: str, ylabel: str, y_down: bool = False, grid: bool = True, xticks: list[float] | None = None) -> None:
    """Axes with ticks, tick labels and axis titles around ``box = (x, y, w, h)`` (data ranges xr, yr)."""
    x0, y0, w, h = box
    cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), _BLACK, 1)
    xt = xticks if xticks is not None else _ticks(*xr, 6)
    xstep = xt[1] - xt[0] if len(xt) > 1 else 1.0
    for t in xt:
        px = int(round(x0 + (t - xr[0]) / (xr[1] - xr[0]) * w))
        cv2.line(img, (px, y0 + h), (px, y0 + h + 5), _BLACK, 1)
        _text(img, _tick_label(t, xstep), (px, y0 + h + 20), 0.42, anchor="centre")
    yt = _ticks(*yr, 5)
    ystep = yt[1] - yt[0] if len(yt) > 1 else 1.0
    for t in yt:
        frac = (t - yr[0]) / (yr[1] - yr[0])
        py = int(round(y0 + frac * h)) if y_down else int(round(y0 + h - frac * h))
        cv2.line(img, (x0 - 5, py), (x0, py), _BLACK, 1)
        if grid:
            cv2.line(img, (x0 + 1, py), (x0 + w - 1, py), (225, 225, 225), 1)
        _text(img, _tick_label(t, ystep), (x0 - 8, py + 5), 0.42, anchor="right")
    _text(img, xlabel, (x0 + w // 2, y0 + h + 42), 0.5, anchor="centre")
    _vertical_text(img, ylabel, (22, y0 + h // 2), 0.5)


def _display_scale(size: tuple[int, int]) -> float:
    return min(1.0, DISPLAY_MAX_SIDE / max(size))


def _scaled(points: np.ndarray, scale: float) -> np.ndarray:
    # pixel centres: (x + 0.5) * s - 0.5
    return (points + 0.5) * scale - 0.5


def _pt(p) -> tuple[int, int]:
    return int(round(float(p[0]))), int(round(float(p[1])))


# ----------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------


def _overlay(gray: np.ndarray, detected: np.ndarray, projected: np.ndarray | None, gain: float, title: str) -> np.ndarray:
    scale = _display_scale((gray.shape[1], gray.shape[0]))
    if scale < 1.0:
        gray = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    vis = cv2.cvtColor(np.clip(gray * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    det = _scaled(detected, scale)
    radius = max(3, int(round(max(vis.shape[:2]) / 220)))
    proj = None
    if projected is not None:
        proj = _scaled(projected, scale)
        for d, p in zip(det, proj):
            tip = d + gain * (p - d)
            cv2.line(vis, _pt(d), _pt(tip), _YELLOW, 1, _AA)
            cv2.drawMarker(vis, _pt(p), _RED, cv2.MARKER_CROSS, 2 * radius, 1)
    for d in det:
        cv2.circle(vis, _pt(d), radius + 1, _GREEN, 1, _AA)
    cv2.circle(vis, _pt(det[0]), 2 * radius + 2, _BLUE, 2, _AA)
    header = np.full((30, vis.shape[1], 3), 255, np.uint8)
    _text(header, title, (6, 20), 0.5)
    items = [("circle", _GREEN, "detected corner"), ("ring", _BLUE, "first grid corner")]
    if proj is not None:
        items[1:1] = [("cross", _RED, "reprojected"), ("line", _YELLOW, f"residual x{gain:g}")]
    out = np.vstack([header, vis])
    _legend(out, items, (out.shape[1] - 6, 36))
    return out


def _axis_max(value: float) -> float:
    """The smallest "nice" tick at or above ``value`` (at least one tick step of headroom)."""
    if not value > 0:
        return 1.0
    step = _nice_number(value / 4)
    return math.ceil(value * 1.02 / step) * step


def _rms_chart(views: list[dict[str, Any]], overall: float | None) -> np.ndarray:
    n = len(views)
    values = []
    for v in views:
        if v.get("used") and v.get("rms") is not None:
            values.append((v["rms"], _GREEN))
        elif v.get("rms_if_used") is not None:
            values.append((v["rms_if_used"], _ORANGE))
        else:
            values.append((None, None))
    finite = [val for val, _ in values if val is not None]
    top = max(finite + [overall or 0.0]) if finite else 1.0
    used_vals = [val for val, c in values if val is not None and c == _GREEN]
    # a wild excluded view must not flatten the used ones: cap the axis, mark clipped bars with an arrow
    if used_vals and top > 4 * max(used_vals):
        top = 4 * max(used_vals)
    vmax = _axis_max(top)
    legend_w = 290
    width = int(np.clip(110 + 14 * n, 640, 1500)) + legend_w
    left, top_m, right, bottom = 80, 50, 20 + legend_w, 70
    img = np.full((460, width, 3), 255, np.uint8)
    box = (left, top_m, width - left - right, img.shape[0] - top_m - bottom)
    x0, y0, w, h = box
    slot = w / max(n, 1)
    step = max(1, int(math.ceil(n / max(1, w // 40))))
    step = int(_nice_number(step)) if _nice_number(step) >= step else int(2 * _nice_number(step))
    xticks = [k for k in range(0, n, step)]
    _text(img, "Per-view RMS reprojection error", (x0, 30), 0.6, thick=1)
    _plot_frame(img, box, (-0.5, n - 0.5), (0.0, vmax), "view index (order of the input files)",
                "RMS (px)", xticks=[float(t) for t in xticks])
    for k, (val, colour) in enumerate(values):
        a = int(round(x0 + k * slot + 0.15 * slot))
        b = max(a + 1, int(round(x0 + (k + 1) * slot - 0.15 * slot)))
        if val is None:
            if slot >= 8:
                _text(img, "x", ((a + b) // 2, y0 + h - 4), 0.35, _GREY, anchor="centre")
            continue
        top_y = int(round(y0 + h - h * min(val, vmax) / vmax))
        cv2.rectangle(img, (a, top_y), (b, y0 + h - 1), colour, -1)
        if val > vmax:
            cv2.arrowedLine(img, ((a + b) // 2, y0 + 18), ((a + b) // 2, y0 + 2), _BLACK, 1, _AA, tipLength=0.4)
    if overall is not None and overall == overall:
        py = int(round(y0 + h - h * min(overall, vmax) / vmax))
        for x in range(x0, x0 + w, 10):
            cv2.line(img, (x, py), (min(x + 5, x0 + w), py), _BLUE, 2)
    items = [("bar", _GREEN, "used view")]
    if any(c == _ORANGE for _, c in values):
        items.append(("bar", _ORANGE, "excluded (RMS if it were used)"))
    items.append(("dash", _BLUE, f"overall RMS {_fmt(overall)} px"))
    if any(val is None for val, _ in values):
        items.append(("bar", _WHITE, "x: no board / no pose"))
    if any(val is not None and val > vmax for val, _ in values):
        items.append(("arrow", _BLACK, "bar clipped above the axis"))
    _legend(img, items, (width - 10, y0))
    return img


def _image_canvas(size: tuple[int, int], title: str, right_margin: int = 130) -> tuple[np.ndarray, tuple[int, int, int, int], float]:
    """A white figure with an image-shaped plot area; returns (figure, plot box, image->plot scale)."""
    w_img, h_img = size
    scale = min(900 / w_img, 640 / h_img)
    w, h = int(round(w_img * scale)), int(round(h_img * scale))
    left, top, bottom = 80, 50, 60
    img = np.full((top + h + bottom, left + w + right_margin, 3), 255, np.uint8)
    _text(img, title, (left, 30), 0.6)
    return img, (left, top, w, h), scale


def _residual_plot(size: tuple[int, int], detected: np.ndarray, residual: np.ndarray) -> np.ndarray:
    fig, box, scale = _image_canvas(size, "Residuals (reprojected - detected) of the used views, magnified", 150)
    x0, y0, w, h = box
    cv2.rectangle(fig, (x0, y0), (x0 + w, y0 + h), (245, 245, 245), -1)
    length = np.linalg.norm(residual, axis=-1)
    p95 = float(np.percentile(length, 95)) if length.size else 0.0
    # the 95th-percentile residual is drawn 4% of the plot width long (a "nice" gain)
    gain = _nice_number(0.04 * w / scale / p95) if p95 > 0 else 1.0
    vmax = max(float(np.percentile(length, 99)) if length.size else 0.0, 1e-6)
    colours = cv2.applyColorMap(np.clip(length / vmax * 255, 0, 255).astype(np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)[:, 0]
    order = np.argsort(length)  # longest on top
    for k in order:
        start = np.array([x0, y0]) + (detected[k] + 0.5) * scale
        end = start + gain * residual[k] * scale
        colour = tuple(int(c) for c in colours[k])
        if np.linalg.norm(end - start) >= 2:
            cv2.arrowedLine(fig, _pt(start), _pt(end), colour, 1, _AA, tipLength=0.3)
        else:
            cv2.circle(fig, _pt(start), 1, colour, -1)
    _plot_frame(fig, box, (0.0, float(size[0])), (0.0, float(size[1])), "x (px)", "y (px)", y_down=True, grid=False)
    # scale arrow: a nice residual length
    ref = _nice_number(p95) if p95 > 0 else 0.1
    sx, sy = x0 + 12, y0 + h - 14
    cv2.rectangle(fig, (x0 + 4, y0 + h - 34), (x0 + 40 + int(gain * ref * scale) + 150, y0 + h - 4), _WHITE, -1)
    cv2.arrowedLine(fig, (sx, sy), (sx + max(3, int(round(gain * ref * scale))), sy), _BLACK, 2, _AA, tipLength=0.2)
    _text(fig, f"= {ref:g} px residual (x{gain:g})", (sx + int(round(gain * ref * scale)) + 10, sy + 5), 0.45)
    _colour_bar(fig, (x0 + w + 20, y0, 18, h), vmax, "residual length (px)")
    return fig


def _coverage_plot(size: tuple[int, int], corner_sets: list[np.ndarray], board: tuple[int, int]) -> tuple[np.ndarray, float]:
    fig, box, scale = _image_canvas(size, "Coverage: detected corners of the used views per image cell", 150)
    x0, y0, w, h = box
    cells_x = 16
    cells_y = max(1, int(round(cells_x * size[1] / size[0])))
    counts = np.zeros((cells_y, cells_x), np.int64)
    all_pts = np.concatenate(corner_sets) if corner_sets else np.zeros((0, 2))
    if len(all_pts):
        ix = np.clip(((all_pts[:, 0] + 0.5) / size[0] * cells_x).astype(int), 0, cells_x - 1)
        iy = np.clip(((all_pts[:, 1] + 0.5) / size[1] * cells_y).astype(int), 0, cells_y - 1)
        np.add.at(counts, (iy, ix), 1)
    vmax = max(int(counts.max()), 1)
    colours = cv2.applyColorMap((counts / vmax * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    for j in range(cells_y):
        for i in range(cells_x):
            a = (x0 + int(round(i * w / cells_x)), y0 + int(round(j * h / cells_y)))
            b = (x0 + int(round((i + 1) * w / cells_x)), y0 + int(round((j + 1) * h / cells_y)))
            colour = tuple(int(c) for c in colours[j, i]) if counts[j, i] else (245, 245, 245)
            cv2.rectangle(fig, a, b, colour, -1)
            cv2.rectangle(fig, a, b, (210, 210, 210), 1)
    cols, rows = board
    for pts in corner_sets:  # board outlines through the four outer corners
        outline = pts[[0, cols - 1, cols * rows - 1, (rows - 1) * cols]]
        poly = np.round(np.array([x0, y0]) + (outline + 0.5) * scale).astype(np.int32)
        cv2.polylines(fig, [poly], True, _ORANGE, 1, _AA)
    for p in all_pts:
        cv2.circle(fig, _pt(np.array([x0, y0]) + (p + 0.5) * scale), 1, _RED, -1)
    _plot_frame(fig, box, (0.0, float(size[0])), (0.0, float(size[1])), "x (px)", "y (px)", y_down=True, grid=False)
    covered = float((counts > 0).mean())
    _text(fig, f"{100 * covered:.0f}% of the {cells_x}x{cells_y} cells hold a corner", (x0 + w, 30), 0.45, anchor="right")
    _colour_bar(fig, (x0 + w + 20, y0, 18, h), float(vmax), "corners per cell")
    _legend(fig, [("circle", _RED, "detected corner"), ("line", _ORANGE, "board outline of a used view"),
                  ("bar", (245, 245, 245), "cell without corners")], (x0 + w - 4, y0 + 4))
    return fig, covered


def _undistorted_preview(gray: np.ndarray, K: torch.Tensor, dist: torch.Tensor, name: str,
                         corners: np.ndarray | None = None, board: tuple[int, int] | None = None) -> np.ndarray:
    from kornia.geometry.calibration import undistort_image

    scale = min(1.0, 640 / max(gray.shape))
    if scale < 1.0:
        gray = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    Ks = K.clone()
    # the same camera on the resized pixel grid (pixel centres: x' + 0.5 = s (x + 0.5))
    Ks[0, 0], Ks[1, 1] = K[0, 0] * scale, K[1, 1] * scale
    Ks[0, 2], Ks[1, 2] = (K[0, 2] + 0.5) * scale - 0.5, (K[1, 2] + 0.5) * scale - 0.5
    out = undistort_image(torch.from_numpy(gray).double()[None, None], Ks[None], dist[None])[0, 0].numpy()
    points = [None, None]
    if corners is not None and board is not None:
        pts = _scaled(corners, scale)
        und = cv2.undistortPoints(pts.reshape(-1, 1, 2).astype(np.float64), Ks.numpy(), dist.numpy(), P=Ks.numpy())
        points = [pts, und.reshape(-1, 2)]
    tiles = []
    for label, im, pts in (("original: " + name, gray, points[0]), ("undistorted (as cv2.undistort)", out, points[1])):
        tile = cv2.cvtColor(np.clip(im * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        if pts is not None:
            cols, rows = board  # type: ignore[misc]
            grid = pts.reshape(rows, cols, 2)
            # outer rows and columns of the board: the corners (green) against the straight chord (red)
            for line in (grid[0], grid[-1], grid[:, 0], grid[:, -1]):
                ends = line[[0, -1]]
                d = ends[1] - ends[0]
                d = d / (np.linalg.norm(d) + 1e-12)
                cv2.line(tile, _pt(ends[0] - 0.6 * np.linalg.norm(ends[1] - ends[0]) * d),
                         _pt(ends[1] + 0.6 * np.linalg.norm(ends[1] - ends[0]) * d), _RED, 1, _AA)
                cv2.polylines(tile, [np.round(line).astype(np.int32)], False, _GREEN, 1, _AA)
                for p in line:
                    cv2.circle(tile, _pt(p), 2, _GREEN, -1, _AA)
        header = np.full((30, tile.shape[1], 3), 255, np.uint8)
        _text(header, label, (6, 20), 0.5)
        tiles.append(np.vstack([header, tile]))
    gap = np.full((tiles[0].shape[0], 10, 3), 255, np.uint8)
    fig = np.hstack([tiles[0], gap, tiles[1]])
    if points[0] is not None:
        _legend(fig, [("circle", _GREEN, "outer rows/columns of corners"),
                      ("line", _RED, "straight line through their ends")], (fig.shape[1] - 6, 36))
    return fig


# ----------------------------------------------------------------------------------------------
# the report
# ----------------------------------------------------------------------------------------------


def _write_png(path: str, image: np.ndarray, written: list[str]) -> bool:
    ok, buf = cv2.imencode(".png", image)
    if ok:
        buf.tofile(path)
        written.append(path)
    return bool(ok)


def _parameter_rows(data: dict[str, Any]) -> list[tuple[str, float, float | None]]:
    K = data["K"]
    std = data.get("std") or {}
    coeffs = data["distortion"]["coeffs"] or []
    std_dist = std.get("distortion") or [None] * len(coeffs)
    rows = [("fx", K[0][0], std.get("fx")), ("fy", K[1][1], std.get("fy")),
            ("cx", K[0][2], std.get("cx")), ("cy", K[1][2], std.get("cy"))]
    rows += [(n, c, s) for n, c, s in zip(_DIST_NAMES, coeffs, std_dist)]
    return rows


def write_report(directory: str, data: dict[str, Any], progress: bool | None = None) -> list[str]:
    """Write the report of a calibration (the dict ``calibrate`` writes as JSON) into ``directory``.

    Args:
        directory: existing output directory.
        data: the calibration dictionary (``K``, ``distortion``, ``views`` with ``corners``,
            ``rvec``, ``tvec``, ``board``, ``square``, ``image_size``, ...).
        progress: show a progress bar over the views (``None``: only on a terminal).

    Returns:
        The paths written (``index.html`` last but one, ``summary.md`` last).

    Example:
        >>> write_report("report", json.load(open("calib.json")))  # doctest: +SKIP
    """
    from tqdm import tqdm

    written: list[str] = []
    K = torch.tensor(data["K"], dtype=torch.float64)
    coeffs = data["distortion"]["coeffs"] or [0.0] * 5
    dist = torch.tensor(coeffs, dtype=torch.float64)
    cols, rows = (int(v) for v in data["board"])
    size = (int(data["image_size"][0]), int(data["image_size"][1]))
    obj = board_object_points(cols, rows, float(data["square"]), dtype=torch.float64)
    views = data["views"]
    views_dir = os.path.join(directory, "views")
    os.makedirs(views_dir, exist_ok=True)

    # projections of every view with a pose; residual gain shared by all overlays
    projected: dict[int, np.ndarray] = {}
    for index, view in enumerate(views):
        if view.get("corners") is not None and view.get("rvec") is not None:
            uv = project_points(obj, K, dist, torch.tensor(view["rvec"], dtype=torch.float64),
                                torch.tensor(view["tvec"], dtype=torch.float64)).numpy()
            if np.isfinite(uv).all():
                projected[index] = uv
    used_idx = [i for i, v in enumerate(views) if v.get("used") and i in projected]
    detected_used = [np.asarray(views[i]["corners"], np.float64) for i in used_idx]
    residuals = [projected[i] - d for i, d in zip(used_idx, detected_used)]
    res_len = np.linalg.norm(np.concatenate(residuals), axis=-1) if residuals else np.zeros(0)
    spacing = float(np.median([np.linalg.norm(np.diff(d.reshape(rows, cols, 2), axis=1), axis=-1).mean()
                               for d in detected_used])) if detected_used else 30.0
    p95 = float(np.percentile(res_len, 95)) if res_len.size else 0.0
    # the typical large residual is drawn about a third of a square long
    gain = _nice_number(0.35 * spacing / p95) if p95 > 0 else 20.0
    gain = float(np.clip(gain, 1.0, 10000.0))

    overlay_names: dict[int, str] = {}
    first_used: tuple[str, np.ndarray, np.ndarray] | None = None
    candidates = [i for i, v in enumerate(views) if v.get("found") and v.get("corners") is not None]
    for index in tqdm(candidates, desc="report", unit="view", file=sys.stderr, disable=None if progress is None else not progress,
                      leave=False):
        view = views[index]
        gray, _ = load_image_gray(view["path"])
        if gray is None:
            continue
        detected = np.asarray(view["corners"], dtype=np.float64)
        base = os.path.basename(view["path"])
        status = f"used, RMS {_fmt(view.get('rms'))} px" if view.get("used") else f"not used: {view.get('reason', '')}"
        title = f"view {index}: {base} - {status}"
        vis = _overlay(gray, detected, projected.get(index), gain, title)
        stem = os.path.splitext(base)[0]
        name = f"view_{index:04d}_{stem}.png"
        if _write_png(os.path.join(views_dir, name), vis, written):
            overlay_names[index] = f"views/{name}"
        if view.get("used") and first_used is None and (gray.shape[1], gray.shape[0]) == size:
            first_used = (base, gray, detected)

    figures: list[tuple[str, str, str]] = []
    if views:
        if _write_png(os.path.join(directory, "rms_per_view.png"), _rms_chart(views, data.get("rms")), written):
            figures.append(("rms_per_view.png", "Per-view RMS",
                            "Bars: RMS reprojection error of each view under the final camera. Orange views were "
                            "excluded (RANSAC or outlier check); a view far above the dashed line deserves a look."))
    if residuals:
        fig = _residual_plot(size, np.concatenate(detected_used), np.concatenate(residuals))
        if _write_png(os.path.join(directory, "residuals.png"), fig, written):
            figures.append(("residuals.png", "Residual vectors",
                            "Each arrow starts at a detected corner and points to its reprojection, magnified. "
                            "Random directions are noise; a pattern (e.g. radial at the borders) is model error."))
    coverage = None
    if detected_used:
        fig, coverage = _coverage_plot(size, detected_used, (cols, rows))
        if _write_png(os.path.join(directory, "coverage.png"), fig, written):
            figures.append(("coverage.png", "Coverage",
                            "Corners per image cell over the used views. Distortion is only constrained where "
                            "corners were seen: empty borders mean extrapolated distortion there."))
    if first_used is not None:
        base, gray, detected = first_used
        preview = _undistorted_preview(gray, K, dist, base, detected, (cols, rows))
        if _write_png(os.path.join(directory, "undistorted.png"), preview, written):
            figures.append(("undistorted.png", "Undistorted preview",
                            "A used view and the same view undistorted with the calibration. Red lines are "
                            "straight; the board's outer corners (green) bow away from them under distortion and "
                            "should sit on them once undistorted."))

    written.append(_write_html(os.path.join(directory, "index.html"), data, figures, overlay_names, gain, coverage))
    written.append(_write_markdown(os.path.join(directory, "summary.md"), data, gain))
    return written


def _write_html(path: str, data: dict[str, Any], figures: list[tuple[str, str, str]], overlays: dict[int, str],
                gain: float, coverage: float | None) -> str:
    esc = html.escape
    n = data.get("num_views", {})
    size = data["image_size"]
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Calibration report</title>",
        "<style>body{font-family:sans-serif;margin:2em;max-width:1400px}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#eee}"
        "td.l{text-align:left}tr.unused{color:#a55}img{max-width:100%;border:1px solid #ddd}"
        "figure{margin:1.5em 0}figcaption{color:#444;max-width:900px}</style></head><body>",
        "<h1>Calibration report</h1>",
        "<ul>",
        f"<li>image size {int(size[0])} x {int(size[1])} px; board {data['board'][0]} x {data['board'][1]} inner "
        f"corners, square {esc(str(data['square']))}</li>",
        f"<li>detector <b>{esc(str(data.get('detector', '?')))}</b>, distortion model "
        f"<b>{esc(str(data['distortion']['model']))}</b>, device {esc(str(data.get('device', '?')))}</li>",
        f"<li>views: {n.get('files', '?')} files, board found in {n.get('found', '?')}, "
        f"{n.get('usable', '?')} usable, <b>{n.get('used', '?')} used</b></li>",
        f"<li>RMS reprojection error <b>{_fmt(data['rms'])} px</b> ({esc(data.get('rms_kind', ''))})</li>",
    ]
    if coverage is not None:
        parts.append(f"<li>image coverage: {100 * coverage:.0f}% of the cells hold a detected corner</li>")
    parts += ["</ul>", "<h2>Parameters</h2>", "<table><tr><th>parameter</th><th>value</th><th>std (1 sigma)</th></tr>"]
    for name, value, std in _parameter_rows(data):
        digits = 3 if name in ("fx", "fy", "cx", "cy") else 6
        parts.append(f"<tr><td class='l'>{name}</td><td>{_fmt(value, digits)}</td><td>&plusmn; {_fmt(std, digits)}</td></tr>")
    parts.append("</table><p>Standard deviations from the Gauss-Newton covariance at the solution, scaled by the "
                 "residual variance (as OpenCV's <code>stdDeviationsIntrinsics</code>).</p>")
    for file, title, caption in figures:
        parts.append(f"<figure><h2>{esc(title)}</h2><a href='{file}'><img src='{file}'></a>"
                     f"<figcaption>{esc(caption)}</figcaption></figure>")
    parts += ["<h2>Views</h2>",
              f"<p>Overlays: green circles detected corners, red crosses reprojections, yellow lines residuals "
              f"x{gain:g}, blue ring the first grid corner.</p>",
              "<table><tr><th>#</th><th>file</th><th>used</th><th>RMS (px)</th><th>note</th><th>overlay</th></tr>"]
    for index, view in enumerate(data["views"]):
        link = f"<a href='{overlays[index]}'>png</a>" if index in overlays else ""
        cls = "" if view.get("used") else " class='unused'"
        rms = view.get("rms") if view.get("used") else view.get("rms_if_used")
        parts.append(
            f"<tr{cls}><td>{index}</td><td class='l'>{esc(os.path.basename(view['path']))}</td>"
            f"<td>{'yes' if view.get('used') else 'no'}</td><td>{_fmt(rms)}</td>"
            f"<td class='l'>{esc(view.get('reason', ''))}</td><td>{link}</td></tr>"
        )
    parts += ["</table></body></html>"]
    with open(path, "w", encoding="utf-8") as handle:
        handle.write("\n".join(parts) + "\n")
    return path


def _write_markdown(path: str, data: dict[str, Any], gain: float) -> str:
    cols, rows = data["board"]
    lines = [
        "# Calibration report",
        "",
        f"- image size: {data['image_size'][0]} x {data['image_size'][1]}",
        f"- board: {cols} x {rows} inner corners, square {data['square']}",
        f"- detector: {data.get('detector', '?')}, model: {data['distortion']['model']}",
        f"- views: {data.get('num_views', {})}",
        f"- RMS reprojection error: {_fmt(data['rms'])} px ({data.get('rms_kind', '')})",
        "",
        "| parameter | value | std |",
        "|---|---|---|",
    ]
    for name, value, std in _parameter_rows(data):
        digits = 3 if name in ("fx", "fy", "cx", "cy") else 6
        lines.append(f"| {name} | {_fmt(value, digits)} | {_fmt(std, digits)} |")
    lines += ["", "| view | used | RMS px | note |", "|---|---|---|---|"]
    for view in data["views"]:
        lines.append(f"| {os.path.basename(view['path'])} | {'yes' if view.get('used') else 'no'} | "
                     f"{_fmt(view.get('rms'))} | {view.get('reason', '')} |")
    lines += ["", f"Overlays (views/): green circles = detected corners, red crosses = reprojected corners, "
                  f"yellow = residual x{gain:g}, blue ring = first corner (order convention). See index.html."]
    with open(path, "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    return path
