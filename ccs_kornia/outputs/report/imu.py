"""The report of ``calibrate-imu --report DIR``, drawn with OpenCV only (the plotting primitives of
:mod:`ccs_kornia.outputs.report.drawing`): the gyroscope and the accelerometer against the fitted trajectory over time,
each camera's reprojection residuals, and the time-offset search.
"""

from __future__ import annotations

import html
import os

import cv2
import numpy as np
import torch

from ccs_kornia.modules.imu.result import ImuCameraResult
from ccs_kornia.outputs.report.drawing import (
    BLUE,
    GREY,
    ORANGE,
    RED,
    axis_max,
    board_bend_line,
    draw_legend,
    draw_plot_frame,
    draw_text,
    write_png,
)

__all__ = ["residual_scatter_figure", "sensor_figure", "time_offset_figure", "write_imu_report"]

#: points drawn per curve at most (a minute at 200 Hz is 12000 samples)
_MAX_POINTS = 3000


def _polyline(img, box, xr, yr, x: np.ndarray, y: np.ndarray, colour, thick: int = 1) -> None:
    x0, y0, w, h = box
    px = x0 + (x - xr[0]) / (xr[1] - xr[0]) * w
    py = y0 + h - (np.clip(y, yr[0], yr[1]) - yr[0]) / (yr[1] - yr[0]) * h
    pts = np.stack([px, py], -1).round().astype(np.int32)[:, None]
    cv2.polylines(img, [pts], False, colour, thick, cv2.LINE_AA)


def sensor_figure(times: np.ndarray, measured: np.ndarray, predicted: np.ndarray, title: str, unit: str) -> np.ndarray:
    """Three stacked plots (x, y, z): the sensor's samples (grey) and the fitted trajectory's prediction (blue)."""
    step = max(1, len(times) // _MAX_POINTS)
    t, m, p = times[::step], measured[::step], predicted[::step]
    width, band = 1100, 230
    img = np.full((40 + 3 * band, width, 3), 255, np.uint8)
    draw_text(img, title, (80, 28), 0.55)
    xr = (float(t[0]), float(t[-1]) if t[-1] > t[0] else float(t[0]) + 1)
    for a, name in enumerate("xyz"):
        lo, hi = float(min(m[:, a].min(), p[:, a].min())), float(max(m[:, a].max(), p[:, a].max()))
        pad = 0.05 * (hi - lo) + 1e-9
        yr = (lo - pad, hi + pad)
        box = (80, 50 + a * band, width - 110, band - 70)
        draw_plot_frame(img, box, xr, yr, "time (s)" if a == 2 else "", f"{name} ({unit})")
        _polyline(img, box, xr, yr, t, m[:, a], GREY)
        _polyline(img, box, xr, yr, t, p[:, a], BLUE, 2)
    draw_legend(img, [("line", GREY, "measured"), ("line", BLUE, "fitted trajectory + bias")], (width - 10, 50))
    return img


def residual_scatter_figure(residuals: np.ndarray, title: str) -> np.ndarray:
    """The corners' residuals (px) as points around 0."""
    r = residuals[np.isfinite(residuals).all(-1)]
    size = 520
    img = np.full((size + 90, size + 110, 3), 255, np.uint8)
    draw_text(img, title, (80, 28), 0.55)
    vmax = axis_max(float(np.abs(r).max()) if len(r) else 1.0)
    box = (80, 50, size, size)
    draw_plot_frame(img, box, (-vmax, vmax), (-vmax, vmax), "x residual (px)", "y residual (px)", y_down=True)
    x0, y0, w, h = box
    step = max(1, len(r) // 20000)
    for dx, dy in r[::step]:
        cv2.circle(img, (int(x0 + (dx + vmax) / (2 * vmax) * w), int(y0 + (dy + vmax) / (2 * vmax) * h)), 1, BLUE, -1)
    return img


def time_offset_figure(shifts: np.ndarray, correlation: np.ndarray, starts: np.ndarray, finals: np.ndarray) -> np.ndarray:
    """Each camera's angular-speed correlation with the gyroscope's against the time offset, the start (orange) and
    the fit's offset (red) marked."""
    width = 900
    img = np.full((420, width, 3), 255, np.uint8)
    draw_text(img, "Time offset: the camera's and the gyroscope's angular speeds correlated", (80, 28), 0.55)
    ms = 1000 * shifts
    xr = (float(ms[0]), float(ms[-1]))
    yr = (min(0.0, float(correlation.min())), 1.0)
    box = (80, 50, width - 110, 300)
    draw_plot_frame(img, box, xr, yr, "timeshift_cam_imu (ms)", "correlation")
    x0, y0, w, h = box
    for c in range(correlation.shape[0]):
        _polyline(img, box, xr, yr, ms, correlation[c], BLUE, 2)
        for value, colour in ((starts[c], ORANGE), (finals[c], RED)):
            px = round(x0 + (1000 * value - xr[0]) / (xr[1] - xr[0]) * w)
            cv2.line(img, (px, y0), (px, y0 + h), colour, 1)
    draw_legend(img, [("line", BLUE, "correlation"), ("line", ORANGE, "start"), ("line", RED, "fit")], (width - 10, y0))
    return img


def write_imu_report(directory: str, result: ImuCameraResult, gyro: np.ndarray, accel: np.ndarray,
                     names: list[str], square: float | None = None) -> list[str]:
    """Write the figures and an ``index.html`` into ``directory`` (which must exist); returns the files written.

    Args:
        result: the calibration (its ``residuals`` hold what the figures draw).
        gyro, accel: :math:`(N, 3)` the measurements the fit used (the residuals' times).
        names: the cameras'.
        square: the board's square side as given (the unit of the board's sag, :func:`~.drawing.bend_unit`).
    """
    written: list[str] = []
    res = result.residuals
    t = res["imu_times"].cpu().numpy()
    figures = []

    def save(name: str, image: np.ndarray, caption: str) -> None:
        if write_png(os.path.join(directory, name), image, written):
            figures.append((name, caption))

    rg, ra = res["gyro"].cpu().numpy(), res["accel"].cpu().numpy()
    save("gyroscope.png", sensor_figure(t, gyro, gyro + rg, "Gyroscope: samples and the fitted trajectory", "rad/s"),
         "gyroscope against the fitted trajectory")
    save("accelerometer.png", sensor_figure(t, accel, accel + ra, "Accelerometer: samples and the fitted trajectory",
                                            "m/s^2"), "accelerometer against the fitted trajectory")
    cam = res["frame_camera"].cpu().numpy()
    corners = res["corners"].cpu().numpy().copy()
    corners[~res["seen"].cpu().numpy()] = np.nan
    for c, name in enumerate(names):
        save(f"reprojection_{c}.png", residual_scatter_figure(corners[cam == c].reshape(-1, 2),
                                                              f"{name}: corner residuals (px)"),
             f"{name}: reprojection residuals")
    # the search ran about each camera's clock offset (when the clocks were aligned first): drawn about it
    clock = result.clock_offset if result.clock_offset is not None else torch.zeros_like(result.timeshift_cam_imu)
    save("time_offset.png", time_offset_figure(result.alignment_shifts.cpu().numpy(),
                                               result.alignment_correlation.cpu().numpy(),
                                               (result.alignment_shift - clock).cpu().numpy(),
                                               (result.timeshift_cam_imu - clock).cpu().numpy()),
         "the time-offset search" + (" (about the clocks' offset)" if result.clock_offset is not None else ""))
    rows = "".join(
        f"<tr><td>{html.escape(name)}</td><td>{html.escape(str(np.round(result.T_cam_imu[c].cpu().numpy(), 6).tolist()))}"
        f"</td><td>{1000 * float(result.timeshift_cam_imu[c]):+.4f} ms</td><td>"
        f"{float(result.rotation_std_deg[c].norm()):.4f} deg, {1000 * float(result.translation_std[c].norm()):.3f} mm, "
        f"{1000 * float(result.timeshift_std[c]):.4f} ms</td></tr>" for c, name in enumerate(names))
    body = "".join(f"<h2>{html.escape(caption)}</h2><img src='{name}'>" for name, caption in figures)
    bend = board_bend_line(result.board_flatness, square)
    page = (f"<!doctype html><meta charset='utf-8'><title>camera-IMU calibration</title><h1>Camera-IMU calibration</h1>"
            f"<p>verdict: {html.escape(result.verdict)}</p><ul>"
            + "".join(f"<li>{html.escape(r)}</li>" for r in result.verdict_reasons)
            + "</ul>" + (f"<p>{bend}</p>" if bend else "") + "<table border=1 cellpadding=4><tr><th>camera</th><th>T_cam_imu</th><th>timeshift_cam_imu</th>"
            f"<th>1-sigma</th></tr>{rows}</table>{body}")
    path = os.path.join(directory, "index.html")
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(page)
    written.append(path)
    return written
