"""The report of ``calibrate-hand-eye --report DIR``, drawn with OpenCV only (the plotting primitives of
:mod:`ccs_kornia.outputs.report.drawing`): per pose, the board predicted from the robot's pose alone over the image;
the residuals by pose (the fit's and the held-out prediction's); the camera and the board in the robot's frame.
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
    GREEN,
    GREY,
    ORANGE,
    RED,
    YELLOW,
    axis_max,
    board_bend_line,
    draw_legend,
    draw_plot_frame,
    draw_text,
    nice_ticks,
    write_page,
    write_png,
)

__all__ = ["pose_figure", "residuals_figure", "robot_frame_figure", "write_hand_eye_report"]


def pose_figure(gray: np.ndarray, view: dict[str, Any], title: str) -> np.ndarray:
    """One pose's image with the observed corners (green) and the corners predicted from its robot pose alone by the
    calibration of the other poses (red crosses, the error drawn in yellow; none where the pose was not held out).

    Example:
        >>> v = {"residuals_px": [[0.5, 0.0]], "heldout_predicted": [[12.0, 10.0]], "corners": [[10.0, 10.0]]}
        >>> pose_figure(np.zeros((40, 60), np.float32), v, "pose").shape[2]
        3
    """
    vis = cv2.cvtColor(np.clip(gray * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    radius = max(3, int(round(max(vis.shape[:2]) / 200)))
    observed = np.array(view.get("corners") or [], dtype=np.float64).reshape(-1, 2)
    predicted = view.get("heldout_predicted")
    if predicted is not None:
        for d, p in zip(observed, np.array(predicted, dtype=np.float64)):
            if np.isfinite(d).all() and np.isfinite(p).all():
                cv2.line(vis, tuple(int(round(x)) for x in d), tuple(int(round(x)) for x in p), YELLOW, 1, cv2.LINE_AA)
                cv2.drawMarker(vis, tuple(int(round(x)) for x in p), RED, cv2.MARKER_CROSS, 2 * radius + 2, 2)
    for d in observed[np.isfinite(observed).all(-1)]:
        cv2.circle(vis, tuple(int(round(x)) for x in d), radius, GREEN, 1, cv2.LINE_AA)
    header = np.full((30, vis.shape[1], 3), 255, np.uint8)
    draw_text(header, title, (6, 20), 0.5)
    out = np.vstack([header, vis])
    if out.shape[1] >= 320:
        draw_legend(out, [("circle", GREEN, "observed corner"), ("cross", RED, "predicted from the robot alone")],
                    (out.shape[1] - 6, 36))
    return out


def residuals_figure(views: list[dict[str, Any]], labels: list[str]) -> np.ndarray:
    """Per pose: the fit's RMS (blue) and the held-out prediction's (orange), px."""
    n = len(views)
    fit = [v.get("rms_px") for v in views]
    held = [v.get("heldout_px") for v in views]
    finite = [x for x in fit + held if x is not None]
    vmax = axis_max(max(finite) if finite else 1.0)
    width = int(np.clip(140 + 40 * n, 640, 1600))
    img = np.full((420, width, 3), 255, np.uint8)
    box = (80, 50, width - 110, 300)
    x0, y0, w, h = box
    draw_text(img, "Residuals by pose: the fit's RMS and the held-out prediction's (px)", (x0, 30), 0.55)
    draw_plot_frame(img, box, (-0.5, n - 0.5), (0.0, vmax), "pose", "px", xticks=[float(k) for k in range(n)])
    slot = w / max(n, 1)
    for k in range(n):
        for j, (val, colour) in enumerate(((fit[k], BLUE), (held[k], ORANGE))):
            if val is None:
                continue
            a = int(round(x0 + k * slot + (0.12 + 0.38 * j) * slot))
            b = max(a + 1, int(round(a + 0.36 * slot)))
            top = int(round(y0 + h - h * min(val, vmax) / vmax))
            cv2.rectangle(img, (a, top), (b, y0 + h - 1), colour, -1)
    for k, label in enumerate(labels):
        if slot >= 30 or k % max(1, int(30 // max(slot, 1))) == 0:
            draw_text(img, label[:12], (int(x0 + (k + 0.5) * slot), y0 + h + 40), 0.35, anchor="centre")
    draw_legend(img, [("bar", BLUE, "fit RMS"), ("bar", ORANGE, "held-out prediction RMS")], (width - 10, y0))
    return img


def _outline(data: dict[str, Any]) -> np.ndarray:
    pts = np.array(data.get("board", {}).get("outline") or [[0.0, 0.0, 0.0]], dtype=np.float64)
    return np.vstack([pts, pts[:1]])


def robot_frame_figure(data: dict[str, Any], size: int = 520) -> np.ndarray:
    """The robot base (origin), the flange at every pose, the camera (arrow: its optical axis) and the board, seen
    from above (x, y of the base frame) and from the side (x, z), metres."""
    poses = [np.array(v["robot_pose"], dtype=np.float64) for v in data["poses"] if v.get("robot_pose") is not None]
    X, Z = np.array(data["X"], dtype=np.float64), np.array(data["board_in_robot"], dtype=np.float64)
    eye_in_hand = data["setup"] == "eye-in-hand"
    cams = [T @ X for T in poses] if eye_in_hand else [X]
    boards = [Z] if eye_in_hand else [T @ Z for T in poses]
    outline = _outline(data)
    board_pts = [(outline @ B[:3, :3].T) + B[:3, 3] for B in boards]
    flange = np.array([T[:3, 3] for T in poses]).reshape(-1, 3)
    everything = np.vstack([np.zeros((1, 3)), flange, *[c[None, :3, 3] for c in cams], *board_pts])
    panels = []
    for (i, j, xl, yl) in ((0, 1, "x (base, m)", "y (base, m)"), (0, 2, "x (base, m)", "z (base, m)")):
        span = max(float(np.ptp(everything[:, i])), float(np.ptp(everything[:, j])), 0.1) * 1.2
        ci = 0.5 * float(everything[:, i].min() + everything[:, i].max())
        cj = 0.5 * float(everything[:, j].min() + everything[:, j].max())
        xr, yr = (ci - span / 2, ci + span / 2), (cj - span / 2, cj + span / 2)
        img = np.full((size + 90, size + 100, 3), 255, np.uint8)
        box = (80, 30, size, size)
        draw_plot_frame(img, box, xr, yr, xl, yl, grid=True, xticks=nice_ticks(*xr, 5))

        def px(p, xr=xr, yr=yr, box=box, i=i, j=j):
            u = box[0] + (p[i] - xr[0]) / (xr[1] - xr[0]) * box[2]
            v = box[1] + box[3] - (p[j] - yr[0]) / (yr[1] - yr[0]) * box[3]
            return int(round(u)), int(round(v))

        for b in board_pts:
            cv2.polylines(img, [np.array([px(p) for p in b], np.int32)], True, GREEN, 1, cv2.LINE_AA)
        for p in flange:
            cv2.circle(img, px(p), 3, GREY, -1, cv2.LINE_AA)
        for c in cams:
            tip = c[:3, 3] + c[:3, 2] * 0.08 * span
            cv2.arrowedLine(img, px(c[:3, 3]), px(tip), RED, 2, cv2.LINE_AA, tipLength=0.3)
        cv2.drawMarker(img, px(np.zeros(3)), BLACK, cv2.MARKER_SQUARE, 10, 2)
        panels.append(img)
    out = np.hstack(panels)
    header = np.full((34, out.shape[1], 3), 255, np.uint8)
    draw_text(header, "The robot's base (square), the flange at each pose (grey), the camera (red: its optical axis) "
              "and the board (green)", (8, 22), 0.5)
    return np.vstack([header, out])


def write_hand_eye_report(directory: str, data: dict[str, Any]) -> list[str]:
    """Write the figures and an ``index.html`` into ``directory`` (which must exist); returns the files written."""
    written: list[str] = []

    def save(name: str, image: np.ndarray | None) -> str | None:
        if image is None:
            return None
        return name if write_png(os.path.join(directory, name), image, written) else None

    labels = [os.path.basename(v["path"]) for v in data["poses"]]
    parts = [("residuals.png", residuals_figure(data["poses"], labels), "residuals by pose"),
             ("robot_frame.png", robot_frame_figure(data), "the camera and the board in the robot's frame")]
    figures = [(save(name, img), caption) for name, img, caption in parts]
    for k, view in enumerate(data["poses"]):
        if not view.get("used"):
            continue
        gray = read_image(view["path"])[0]
        if gray is None:
            continue
        held = view.get("heldout_px")
        title = (f"{labels[k]}: predicted from the robot alone {held:.2f} px RMS off" if held is not None
                 else f"{labels[k]}: not held out")
        figures.append((save(f"pose_{k:03d}.png", pose_figure(gray, view, title)), title))
    std = data["X_std"]
    held = data["heldout"]
    rows = (f"<tr><td>X (translation, m)</td><td>{html.escape(str([round(v, 6) for v in data['X_tq']['t']]))}</td>"
            f"<td>{std['translation_mm_norm']:.3g} mm</td></tr>"
            f"<tr><td>X (quaternion x, y, z, w)</td><td>{html.escape(str([round(v, 6) for v in data['X_tq']['q']]))}"
            f"</td><td>{std['rotation_deg_norm']:.3g} deg</td></tr>")
    body = "".join(f"<h2>{html.escape(caption)}</h2><img src='{name}'>" for name, caption in figures if name)
    held_text = "not measured" if held["rms_px"] is None else f"{held['rms_px']:.3f} px, {held['rms_mm']:.3f} mm"
    bend = board_bend_line(data.get("board_flatness"))
    bend = f"<p>{bend}</p>" if bend else ""
    page = (f"<!doctype html><meta charset='utf-8'><title>hand-eye calibration</title><h1>Hand-eye calibration "
            f"({html.escape(data['setup'])})</h1><p>verdict: {html.escape(str(data['verdict']))}; fit RMS "
            f"{data['rms_px']:.3f} px; held-out prediction {held_text}; {html.escape(data['convention']['X'])}</p>"
            f"{bend}"
            f"<table border=1 cellpadding=4><tr><th></th><th>value</th><th>1-sigma</th></tr>{rows}</table>{body}")
    path = os.path.join(directory, "index.html")
    written.append(write_page(path, page))
    return written
