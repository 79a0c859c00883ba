"""The figures of the calibration report (:mod:`ccs_kornia.outputs.report.calibration`), drawn with OpenCV only.

View overlays, the per-view RMS chart, the residual field, the coverage map and the undistorted preview, on the
plotting primitives of :mod:`~ccs_kornia.outputs.report.drawing`. Each returns a BGR ``uint8`` image.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.outputs.report.drawing import (
    BLACK,
    BLUE,
    GREEN,
    GREY,
    MAGENTA,
    ORANGE,
    RED,
    WHITE,
    YELLOW,
    axis_max,
    draw_colour_bar,
    draw_legend,
    draw_plot_frame,
    draw_text,
    format_number,
    image_canvas,
    int_point,
    nice_number,
)

__all__ = ["DISPLAY_MAX_SIDE", "coverage_plot", "residual_plot", "rms_chart", "undistorted_preview", "view_overlay"]

#: longest side of any picture in the report
DISPLAY_MAX_SIDE = 1280


def _display_scale(size: tuple[int, int]) -> float:
    return min(1.0, DISPLAY_MAX_SIDE / max(size))


def _scaled(points: np.ndarray, scale: float) -> np.ndarray:
    # pixel centres: (x + 0.5) * s - 0.5
    return (points + 0.5) * scale - 0.5


def view_overlay(gray: np.ndarray, detected: np.ndarray, projected: np.ndarray | None, gain: float, title: str) -> np.ndarray:
    """One view (``gray`` (H, W) in [0, 1], shown at most :data:`DISPLAY_MAX_SIDE`) with its detected corners
    ``detected`` (N, 2) px (green; the first grid corner ringed blue) and, where given, their reprojection
    ``projected`` (N, 2) (red crosses; the residual drawn ``gain`` times longer, hidden corners of a partial board
    marked where the camera puts them), under a header line ``title``.

    Example:
        >>> view_overlay(np.zeros((40, 60), np.float32), np.array([[10.0, 10.0]]), None, 10.0, "view").shape
        (70, 60, 3)
    """
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
                cv2.drawMarker(vis, int_point(p), MAGENTA, cv2.MARKER_TILTED_CROSS, 2 * radius, 2)
                continue
            tip = d + gain * (p - d)
            cv2.line(vis, int_point(d), int_point(tip), YELLOW, 1, cv2.LINE_AA)
            cv2.drawMarker(vis, int_point(p), RED, cv2.MARKER_CROSS, 2 * radius, 1)
    for d in det[np.isfinite(det).all(-1)]:
        cv2.circle(vis, int_point(d), radius + 1, GREEN, 1, cv2.LINE_AA)
    if len(det) and np.isfinite(det[0]).all():
        cv2.circle(vis, int_point(det[0]), 2 * radius + 2, BLUE, 2, cv2.LINE_AA)
    header = np.full((30, vis.shape[1], 3), 255, np.uint8)
    draw_text(header, title, (6, 20), 0.5)
    items = [("circle", GREEN, "detected corner"), ("ring", BLUE, "first grid corner")] if len(det) else []
    if proj is not None:
        items[1:1] = [("cross", RED, "reprojected"), ("line", YELLOW, f"residual x{gain:g}")]
        if len(det) and not np.isfinite(det).all():
            items.append(("x", MAGENTA, "hidden corner (glare, occluder)"))
    out = np.vstack([header, vis])
    if items:
        draw_legend(out, items, (out.shape[1] - 6, 36))
    return out


def rms_chart(views: list[dict[str, Any]], overall: float | None) -> np.ndarray:
    """Bar chart of the per-view RMS of ``views`` (the records of ``calibrate``'s JSON: used views green, excluded ones
    orange at ``rms_if_used``), the ``overall`` RMS dashed; an excluded view far above the used ones is clipped.

    Example:
        >>> rms_chart([{"used": True, "rms": 0.2}, {"used": False, "rms_if_used": 3.0}], 0.2).shape[2]
        3
    """
    n = len(views)
    values = []
    for v in views:
        if v.get("used") and v.get("rms") is not None:
            values.append((v["rms"], GREEN))
        elif v.get("rms_if_used") is not None:
            values.append((v["rms_if_used"], ORANGE))
        else:
            values.append((None, None))
    finite = [val for val, _ in values if val is not None]
    top = max(finite + [overall or 0.0]) if finite else 1.0
    used_vals = [val for val, c in values if val is not None and c == GREEN]
    # a wild excluded view must not flatten the used ones: cap the axis, mark clipped bars with an arrow
    if used_vals and top > 4 * max(used_vals):
        top = 4 * max(used_vals)
    vmax = axis_max(top)
    legend_w = 290
    width = int(np.clip(110 + 14 * n, 640, 1500)) + legend_w
    left, top_m, right, bottom = 80, 50, 20 + legend_w, 70
    img = np.full((460, width, 3), 255, np.uint8)
    box = (left, top_m, width - left - right, img.shape[0] - top_m - bottom)
    x0, y0, w, h = box
    slot = w / max(n, 1)
    step = max(1, int(math.ceil(n / max(1, w // 40))))
    step = int(nice_number(step)) if nice_number(step) >= step else int(2 * nice_number(step))
    xticks = [k for k in range(0, n, step)]
    draw_text(img, "Per-view RMS reprojection error", (x0, 30), 0.6, thick=1)
    draw_plot_frame(img, box, (-0.5, n - 0.5), (0.0, vmax), "view index (order of the input files)",
                    "RMS (px)", xticks=[float(t) for t in xticks])
    for k, (val, colour) in enumerate(values):
        a = int(round(x0 + k * slot + 0.15 * slot))
        b = max(a + 1, int(round(x0 + (k + 1) * slot - 0.15 * slot)))
        if val is None:
            if slot >= 8:
                draw_text(img, "x", ((a + b) // 2, y0 + h - 4), 0.35, GREY, anchor="centre")
            continue
        top_y = int(round(y0 + h - h * min(val, vmax) / vmax))
        cv2.rectangle(img, (a, top_y), (b, y0 + h - 1), colour, -1)
        if val > vmax:
            cv2.arrowedLine(img, ((a + b) // 2, y0 + 18), ((a + b) // 2, y0 + 2), BLACK, 1, cv2.LINE_AA, tipLength=0.4)
    if overall is not None and overall == overall:
        py = int(round(y0 + h - h * min(overall, vmax) / vmax))
        for x in range(x0, x0 + w, 10):
            cv2.line(img, (x, py), (min(x + 5, x0 + w), py), BLUE, 2)
    items = [("bar", GREEN, "used view")]
    if any(c == ORANGE for _, c in values):
        items.append(("bar", ORANGE, "excluded (RMS if it were used)"))
    items.append(("dash", BLUE, f"overall RMS {format_number(overall)} px"))
    if any(val is None for val, _ in values):
        items.append(("bar", WHITE, "x: no board / no pose"))
    if any(val is not None and val > vmax for val, _ in values):
        items.append(("arrow", BLACK, "bar clipped above the axis"))
    draw_legend(img, items, (width - 10, y0))
    return img


def residual_plot(size: tuple[int, int], detected: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Every residual ``residual`` (N, 2) px (reprojected - detected) at its corner ``detected`` (N, 2) on an image of
    ``size`` ``(W, H)``, magnified by a nice gain, coloured by length, with a scale arrow and a colour bar.

    Example:
        >>> residual_plot((64, 48), np.array([[10.0, 10.0]]), np.array([[0.1, 0.0]])).shape[2]
        3
    """
    fig, box, scale = image_canvas(size, "Residuals (reprojected - detected) of the used views, magnified", 150)
    x0, y0, w, h = box
    measured = np.isfinite(detected).all(-1) & np.isfinite(residual).all(-1)  # partial boards: hidden corners NaN
    detected, residual = detected[measured], residual[measured]
    cv2.rectangle(fig, (x0, y0), (x0 + w, y0 + h), (245, 245, 245), -1)
    length = np.linalg.norm(residual, axis=-1)
    p95 = float(np.percentile(length, 95)) if length.size else 0.0
    # the 95th-percentile residual is drawn 4% of the plot width long (a "nice" gain)
    gain = nice_number(0.04 * w / scale / p95) if p95 > 0 else 1.0
    vmax = max(float(np.percentile(length, 99)) if length.size else 0.0, 1e-6)
    colours = cv2.applyColorMap(np.clip(length / vmax * 255, 0, 255).astype(np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)[:, 0]
    order = np.argsort(length)  # longest on top
    for k in order:
        start = np.array([x0, y0]) + (detected[k] + 0.5) * scale
        end = start + gain * residual[k] * scale
        colour = tuple(int(c) for c in colours[k])
        if np.linalg.norm(end - start) >= 2:
            cv2.arrowedLine(fig, int_point(start), int_point(end), colour, 1, cv2.LINE_AA, tipLength=0.3)
        else:
            cv2.circle(fig, int_point(start), 1, colour, -1)
    draw_plot_frame(fig, box, (0.0, float(size[0])), (0.0, float(size[1])), "x (px)", "y (px)", y_down=True, grid=False)
    # scale arrow: a nice residual length
    ref = nice_number(p95) if p95 > 0 else 0.1
    sx, sy = x0 + 12, y0 + h - 14
    cv2.rectangle(fig, (x0 + 4, y0 + h - 34), (x0 + 40 + int(gain * ref * scale) + 150, y0 + h - 4), WHITE, -1)
    cv2.arrowedLine(fig, (sx, sy), (sx + max(3, int(round(gain * ref * scale))), sy), BLACK, 2, cv2.LINE_AA, tipLength=0.2)
    draw_text(fig, f"= {ref:g} px residual (x{gain:g})", (sx + int(round(gain * ref * scale)) + 10, sy + 5), 0.45)
    draw_colour_bar(fig, (x0 + w + 20, y0, 18, h), vmax, "residual length (px)")
    return fig


def coverage_plot(size: tuple[int, int], corner_sets: list[np.ndarray], board: tuple[int, int]) -> tuple[np.ndarray, float]:
    """How many corners of the used views (``corner_sets``, one (N, 2) array per view of a ``board`` ``(cols, rows)``)
    fall in each cell of a 16-column grid over an image of ``size`` ``(W, H)``, with each board's outline; returns the
    figure and the fraction of cells that hold a corner.

    Example:
        >>> corners = np.array([[1.0, 1.0], [60.0, 1.0], [1.0, 40.0], [60.0, 40.0]])
        >>> fig, covered = coverage_plot((64, 48), [corners], (2, 2))
        >>> covered  # 4 of the 16 x 12 cells
        0.020833333333333332
    """
    fig, box, scale = image_canvas(size, "Coverage: detected corners of the used views per image cell", 150)
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
        cv2.polylines(fig, [poly], True, ORANGE, 1, cv2.LINE_AA)
    for p in all_pts:
        cv2.circle(fig, int_point(np.array([x0, y0]) + (p + 0.5) * scale), 1, RED, -1)
    draw_plot_frame(fig, box, (0.0, float(size[0])), (0.0, float(size[1])), "x (px)", "y (px)", y_down=True, grid=False)
    covered = float((counts > 0).mean())
    draw_text(fig, f"{100 * covered:.0f}% of the {cells_x}x{cells_y} cells hold a corner", (x0 + w, 30), 0.45, anchor="right")
    draw_colour_bar(fig, (x0 + w + 20, y0, 18, h), float(vmax), "corners per cell")
    draw_legend(fig, [("circle", RED, "detected corner"), ("line", ORANGE, "board outline of a used view"),
                      ("bar", (245, 245, 245), "cell without corners")], (x0 + w - 4, y0 + 4))
    return fig, covered


def _resized_camera(camera: Camera, scale: float, size: tuple[int, int]) -> Camera:
    """The same camera (one) on a pixel grid resized by ``scale`` to ``size``: the focal lengths scale and the
    principal point moves with the pixel centres (``x' + 0.5 = s (x + 0.5)``); the lens's coefficients are kept."""
    params = camera.params.clone()
    params[:, 0:2] = camera.params[:, 0:2] * scale
    params[:, 2:4] = (camera.params[:, 2:4] + 0.5) * scale - 0.5
    return Camera(camera.models, params, size)


def undistorted_preview(gray: np.ndarray, camera: Camera, name: str, corners: np.ndarray | None = None,
                         board: tuple[int, int] | None = None, seen: np.ndarray | None = None) -> np.ndarray:
    """A view of ``camera`` (one, any model) next to what ``undistort --balance 0`` makes of it (``seen``: the
    calibration's corners, which bound the lens's valid field)."""
    from ccs_kornia.modules.undistort.undistort_image import undistort_image
    from ccs_kornia.modules.undistort.valid_field import valid_radius
    from ccs_kornia.modules.undistort.view_camera import (
        horizontal_fov,
        view_camera_matrix,
    )

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
                cv2.line(tile, int_point(ends[0] - 0.6 * np.linalg.norm(ends[1] - ends[0]) * d),
                         int_point(ends[1] + 0.6 * np.linalg.norm(ends[1] - ends[0]) * d), RED, 1, cv2.LINE_AA)
                cv2.polylines(tile, [np.round(line).astype(np.int32)], False, GREEN, 1, cv2.LINE_AA)
                for p in line:
                    cv2.circle(tile, int_point(p), 2, GREEN, -1, cv2.LINE_AA)
        header = np.full((30, tile.shape[1], 3), 255, np.uint8)
        draw_text(header, label, (6, 20), 0.5)
        tiles.append(np.vstack([header, tile]))
    gap = np.full((tiles[0].shape[0], 10, 3), 255, np.uint8)
    fig = np.hstack([tiles[0], gap, tiles[1]])
    if points[0] is not None:
        draw_legend(fig, [("circle", GREEN, "outer rows/columns of corners"),
                          ("line", RED, "straight line through their ends")], (fig.shape[1] - 6, 36))
    return fig
