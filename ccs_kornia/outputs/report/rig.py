"""The report of ``calibrate-rig --report DIR``, drawn with OpenCV only (the plotting primitives of
:mod:`ccs_kornia.outputs.report.drawing`): the error per camera and frame, a rectified pair with horizontal lines (a
point and its match lie on the same row when the rig is right), and the cameras and board poses seen from above.
"""

from __future__ import annotations

import html
import os
from typing import Any

import cv2
import numpy as np

from ccs_kornia.io.images import read_image
from ccs_kornia.outputs.report.drawing import (
    BLACK,
    BLUE,
    GREY,
    RED,
    board_bend_line,
    draw_colour_bar,
    draw_plot_frame,
    draw_text,
    nice_ticks,
    write_page,
    write_png,
)
from ccs_kornia.outputs.rig_records import rectify_maps

__all__ = ["error_matrix_figure", "rectified_pair_figure", "top_view_figure", "write_rig_report"]


def error_matrix_figure(rms_matrix: list[list[float | None]], names: list[str], labels: list[str]) -> np.ndarray:
    """Camera x frame RMS reprojection error (px) as a colour matrix; grey where the camera did not see the frame.

    Example:
        >>> error_matrix_figure([[0.1, None], [0.2, 0.3]], ["left", "right"], ["01", "02"]).shape[2]
        3
    """
    values = np.array([[np.nan if v is None else float(v) for v in row] for row in rms_matrix], dtype=np.float64)
    c, f = values.shape
    cell = max(14, min(48, 900 // max(f, 1)))
    left, top = 20 + 9 * max(len(n) for n in names), 50
    width, height = left + cell * f + 130, top + cell * c + 70
    img = np.full((height, width, 3), 255, np.uint8)
    vmax = float(np.nanmax(values)) if np.isfinite(values).any() else 1.0
    vmax = vmax if vmax > 0 else 1.0
    ramp = np.clip(np.nan_to_num(values / vmax, nan=0.0) * 255, 0, 255).astype(np.uint8)
    colours = cv2.applyColorMap(ramp.reshape(-1, 1), cv2.COLORMAP_VIRIDIS).reshape(c, f, 3)
    for i in range(c):
        for k in range(f):
            x, y = left + k * cell, top + i * cell
            colour = tuple(int(v) for v in colours[i, k]) if np.isfinite(values[i, k]) else (215, 215, 215)
            cv2.rectangle(img, (x, y), (x + cell - 1, y + cell - 1), colour, -1)
        draw_text(img, names[i], (left - 8, top + i * cell + cell // 2 + 5), 0.45, anchor="right")
    step = max(1, int(np.ceil(f * 30 / (cell * f))))
    for k in range(0, f, step):
        draw_text(img, labels[k], (left + k * cell + cell // 2, top + c * cell + 18), 0.38, anchor="centre")
    cv2.rectangle(img, (left, top), (left + cell * f, top + cell * c), BLACK, 1)
    draw_text(img, "RMS reprojection error per camera and frame (px); grey: not seen", (10, 25), 0.5)
    draw_text(img, "frame", (left + cell * f // 2, top + c * cell + 45), 0.5, anchor="centre")
    draw_colour_bar(img, (left + cell * f + 15, top, 16, max(cell * c, 60)), vmax, "px")
    return img


def rectified_pair_figure(data: dict[str, Any], rect: dict[str, Any], i: int = 0, j: int = 1) -> np.ndarray | None:
    """The first frame both cameras saw, rectified side by side with horizontal lines every 32 rows (``None``
    without such a frame or when its images cannot be read)."""
    frames = data["frames"]
    pick = next((k for k in range(len(frames[i])) if frames[i][k] and frames[j][k]), None)
    if pick is None:
        return None
    maps = rectify_maps(data, rect, i, j)
    halves = []
    for path, (mx, my) in zip((frames[i][pick], frames[j][pick]), maps):
        image, _, _ = read_image(path, gray=True)
        if image is None:
            return None
        out = cv2.remap(image, mx, my, cv2.INTER_LINEAR)
        halves.append(cv2.cvtColor((np.clip(out, 0, 1) * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    img = np.concatenate([halves[0], np.full((halves[0].shape[0], 6, 3), 255, np.uint8), halves[1]], 1)
    for y in range(16, img.shape[0], 32):
        cv2.line(img, (0, y), (img.shape[1] - 1, y), (0, 200, 0), 1)
    return img


def top_view_figure(data: dict[str, Any], size: int = 640) -> np.ndarray:
    """The cameras (centre and viewing direction) and the board of every frame seen from above, in camera 0's frame
    (x to the right, z forward), in the unit of ``--square``."""
    Rs = [np.array(e["R"], dtype=np.float64) for e in data["extrinsics"]]
    Ts = [np.array(e["T"], dtype=np.float64) for e in data["extrinsics"]]
    centres = np.stack([-R.T @ T for R, T in zip(Rs, Ts)])
    axes = np.stack([R.T @ np.array([0.0, 0.0, 1.0]) for R in Rs])
    cols, rows = data["board"]
    square = float(data["square"])
    outline = np.array([[0, 0, 0], [(cols - 1) * square, 0, 0], [(cols - 1) * square, (rows - 1) * square, 0],
                        [0, (rows - 1) * square, 0]], dtype=np.float64)
    boards = []
    for pose in data.get("board_poses", []):
        if pose["rvec"] is None or any(v is None for v in pose["rvec"] + pose["tvec"]):
            continue
        R, _ = cv2.Rodrigues(np.array(pose["rvec"], dtype=np.float64))
        boards.append(outline @ R.T + np.array(pose["tvec"], dtype=np.float64))
    points = np.concatenate([centres] + boards) if boards else centres
    span = max(float(np.ptp(points[:, 0])), float(np.ptp(points[:, 2])), 1e-6) * 1.15
    xr = (float(points[:, 0].mean()) - span / 2, float(points[:, 0].mean()) + span / 2)
    zr = (float(points[:, 2].min()) - 0.08 * span, float(points[:, 2].min()) + 1.0 * span)
    img = np.full((size + 110, size + 100, 3), 255, np.uint8)
    box = (80, 40, size, size)
    draw_plot_frame(img, box, xr, zr, "x (camera 0, the board's unit)", "z (forward)", grid=True,
                    xticks=nice_ticks(*xr, 5))

    def px(p: np.ndarray) -> tuple[int, int]:
        u = box[0] + (p[0] - xr[0]) / (xr[1] - xr[0]) * box[2]
        v = box[1] + box[3] - (p[2] - zr[0]) / (zr[1] - zr[0]) * box[3]
        return int(round(u)), int(round(v))

    for b in boards:
        cv2.polylines(img, [np.array([px(p) for p in b], np.int32)], True, GREY, 1, cv2.LINE_AA)
    for c, (centre, axis) in enumerate(zip(centres, axes)):
        tip = centre + axis * 0.12 * span
        cv2.arrowedLine(img, px(centre), px(tip), RED if c == 0 else BLUE, 2, cv2.LINE_AA, tipLength=0.25)
        cv2.circle(img, px(centre), 4, BLACK, -1, cv2.LINE_AA)
        draw_text(img, data["cameras"][c]["name"], (px(centre)[0] + 6, px(centre)[1] + 16), 0.45)
    draw_text(img, "the rig from above: cameras (arrows: viewing direction) and board poses (grey)", (10, 25), 0.5)
    return img


def write_rig_report(directory: str, data: dict[str, Any], rect: dict[str, Any] | None = None,
                     pair: tuple[int, int] = (0, 1)) -> list[str]:
    """Write the figures and an ``index.html`` into ``directory`` (which must exist); returns the files written.
    ``rect``: the rectification of the cameras ``pair``, shown as a rectified pair (the one the stereo files hold)."""
    written: list[str] = []

    def save(name: str, image: np.ndarray | None) -> str | None:
        if image is None:
            return None
        return name if write_png(os.path.join(directory, name), image, written) else None

    names = [cam["name"] for cam in data["cameras"]]
    figures = [
        (save("error_matrix.png", error_matrix_figure(data["rms_matrix"], names, data["frame_labels"])),
         "RMS reprojection error per camera and frame"),
        (save("rectified_pair.png", rectified_pair_figure(data, rect, *pair) if rect is not None else None),
         f"a rectified pair ({names[pair[0]]}, {names[pair[1]]}): matching points lie on the same row"),
        (save("rig_top_view.png", top_view_figure(data)), "the rig and the board poses from above"),
    ]
    def cell(value: float | None, digits: str) -> str:
        return "" if value is None else format(value, digits)

    rows = "".join(
        f"<tr><td>{html.escape(p['names'][0])}-{html.escape(p['names'][1])}</td><td>{cell(p['baseline'], '.6g')}</td>"
        f"<td>{cell(p.get('baseline_std'), '.3g')}</td><td>{cell(p['rotation_deg'], '.4f')}</td>"
        f"<td>{cell(p['epipolar_rms'], '.4f')}</td></tr>" for p in data["pairs"])
    body = "".join(f"<h2>{html.escape(caption)}</h2><img src='{name}'>" for name, caption in figures if name)
    bend = board_bend_line(data.get("board_flatness"), data.get("square"))
    bend = f"<p>{bend}</p>" if bend else ""
    page = (f"<!doctype html><meta charset='utf-8'><title>rig calibration</title><h1>Rig calibration</h1>"
            f"<p>verdict: {html.escape(str(data['verdict']))}; RMS {data['rms']:.4f} px; convention "
            f"{html.escape(data['convention'])}</p>{bend}<table border=1 cellpadding=4><tr><th>pair</th><th>baseline</th>"
            f"<th>1-sigma</th><th>rotation (deg)</th><th>epipolar RMS (px)</th></tr>{rows}</table>{body}")
    path = os.path.join(directory, "index.html")
    written.append(write_page(path, page))
    return written
