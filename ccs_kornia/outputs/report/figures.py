"""The figures of the calibration report (:mod:`ccs_kornia.outputs.report.calibration`), drawn with OpenCV only.

View overlays, the per-view RMS chart, the residual field, the coverage map and the undistorted preview, on
small plotting primitives (text, legend, colour bar, axes with nice ticks).
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera

__all__ = ["DISPLAY_MAX_SIDE", "write_png"]

#: longest side of any picture in the report
DISPLAY_MAX_SIDE = 1280

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_AA = cv2.LINE_AA
# BGR colours
_GREEN, _RED, _YELLOW, _BLUE = (0, 170, 0), (0, 0, 230), (0, 215, 255), (230, 90, 0)
_MAGENTA = (200, 0, 200)
_ORANGE, _BLACK, _GREY, _WHITE = (0, 140, 255), (0, 0, 0), (150, 150, 150), (255, 255, 255)


def write_png(path: str, image: np.ndarray, written: list[str]) -> bool:
    """Encode ``image`` (H, W[, 3] uint8) as PNG into ``path`` (any characters in the path, through
    :func:`numpy.ndarray.tofile`) and add the path to ``written`` (the report's manifest); False if it cannot be
    encoded."""
    ok, buf = cv2.imencode(".png", image)
    if ok:
        buf.tofile(path)
        written.append(path)
    return bool(ok)


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
    """Draw a boxed legend; ``items`` are ``(kind, colour, label)`` with kind circle|cross|x|line|bar|dash."""
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
            if not np.isfinite(p).all():
                continue
            if not np.isfinite(d).all():  # a hidden corner of a partial board: where the camera puts it
                cv2.drawMarker(vis, _pt(p), _MAGENTA, cv2.MARKER_TILTED_CROSS, 2 * radius, 2)
                continue
            tip = d + gain * (p - d)
            cv2.line(vis, _pt(d), _pt(tip), _YELLOW, 1, _AA)
            cv2.drawMarker(vis, _pt(p), _RED, cv2.MARKER_CROSS, 2 * radius, 1)
    for d in det[np.isfinite(det).all(-1)]:
        cv2.circle(vis, _pt(d), radius + 1, _GREEN, 1, _AA)
    if len(det) and np.isfinite(det[0]).all():
        cv2.circle(vis, _pt(det[0]), 2 * radius + 2, _BLUE, 2, _AA)
    header = np.full((30, vis.shape[1], 3), 255, np.uint8)
    _text(header, title, (6, 20), 0.5)
    items = [("circle", _GREEN, "detected corner"), ("ring", _BLUE, "first grid corner")] if len(det) else []
    if proj is not None:
        items[1:1] = [("cross", _RED, "reprojected"), ("line", _YELLOW, f"residual x{gain:g}")]
        if len(det) and not np.isfinite(det).all():
            items.append(("x", _MAGENTA, "hidden corner (glare, occluder)"))
    out = np.vstack([header, vis])
    if items:
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
    measured = np.isfinite(detected).all(-1) & np.isfinite(residual).all(-1)  # partial boards: hidden corners NaN
    detected, residual = detected[measured], residual[measured]
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
    all_pts = all_pts[np.isfinite(all_pts).all(-1)]  # partial boards: hidden corners NaN
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
        if not np.isfinite(outline).all():  # an outer corner of a partial board is hidden
            continue
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


def _resized_camera(camera: Camera, scale: float, size: tuple[int, int]) -> Camera:
    """The same camera (one) on a pixel grid resized by ``scale`` to ``size``: the focal lengths scale and the
    principal point moves with the pixel centres (``x' + 0.5 = s (x + 0.5)``); the lens's coefficients are kept."""
    params = camera.params.clone()
    params[:, 0:2] = camera.params[:, 0:2] * scale
    params[:, 2:4] = (camera.params[:, 2:4] + 0.5) * scale - 0.5
    return Camera(camera.models, params, size)


def _undistorted_preview(gray: np.ndarray, camera: Camera, name: str, corners: np.ndarray | None = None,
                         board: tuple[int, int] | None = None, seen: np.ndarray | None = None) -> np.ndarray:
    """A view of ``camera`` (one, any model) next to what ``undistort --balance 0`` makes of it (``seen``: the
    calibration's corners, which bound the lens's valid field)."""
    from ccs_kornia.modules.undistort.undistort_image import undistort_image
    from ccs_kornia.modules.undistort.valid_field import valid_radius
    from ccs_kornia.modules.undistort.view_camera import horizontal_fov, view_camera_matrix

    camera = camera.to(dtype=torch.float64)
    points_seen = None if seen is None else torch.from_numpy(np.asarray(seen, np.float64).reshape(1, -1, 2))
    field = valid_radius(camera, points_seen)  # a radius on the normalized plane: the same at any scale below
    scale = min(1.0, 640 / max(gray.shape))
    if scale < 1.0:
        gray = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    size = (gray.shape[1], gray.shape[0])
    shown = _resized_camera(camera, scale, size)
    image = torch.from_numpy(gray).double()[None, None]
    P = view_camera_matrix(shown, size, 0.0, max_radius=field)
    out = undistort_image(image, shown, P, field)[0, 0].numpy()
    points = [None, None]
    if corners is not None and board is not None:
        pts = _scaled(corners, scale)
        und = shown.undistort(torch.from_numpy(pts.reshape(1, -1, 2).astype(np.float64)), P)[0].numpy()
        points = [pts, und.reshape(-1, 2)]
    label = f"undistorted (undistort --balance 0: {float(horizontal_fov(P, size)[0]):.0f} deg across)"
    tiles = []
    for label, im, pts in (("original: " + name, gray, points[0]), (label, out, points[1])):
        tile = cv2.cvtColor(np.clip(im * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        if pts is not None:
            cols, rows = board  # type: ignore[misc]
            grid = pts.reshape(rows, cols, 2)
            # outer rows and columns of the board: the corners (green) against the straight chord (red)
            for line in (grid[0], grid[-1], grid[:, 0], grid[:, -1]):
                line = line[np.isfinite(line).all(-1)]  # partial boards: hidden corners NaN
                if len(line) < 2:
                    continue
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
