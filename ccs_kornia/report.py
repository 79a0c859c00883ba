"""Human-readable calibration report (``calibrate --report DIR``).

Writes into ``DIR``:

* ``summary.md``: intrinsics and distortion with standard deviations, RMS, and a table of views
  (used or not, RMS, reason);
* ``view_XX_<name>.png`` for every view with a detected board: the detected corners (green
  circles), their reprojection through the calibrated model (red crosses) and the residuals
  magnified 20x (yellow lines);
* ``undistorted_<name>.png``: the first used view undistorted with the calibration.

Only what ``calibrate`` already wrote into its JSON is used, plus the images themselves.
"""

from __future__ import annotations

import os
from typing import Any

import cv2
import numpy as np
import torch

from ccs_kornia.camera import board_object_points, project_points
from ccs_kornia.io import load_image_gray

__all__ = ["write_report"]

_RESIDUAL_GAIN = 20.0


def _fmt(value: float | None, digits: int = 4) -> str:
    return "-" if value is None or value != value else f"{value:.{digits}f}"


def _overlay(gray: np.ndarray, detected: np.ndarray, projected: np.ndarray | None) -> np.ndarray:
    vis = cv2.cvtColor(np.clip(gray * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    radius = max(2, int(round(max(gray.shape) / 320)))
    for k, (x, y) in enumerate(detected):
        centre = (int(round(x)), int(round(y)))
        cv2.circle(vis, centre, radius + 1, (0, 200, 0), 1, cv2.LINE_AA)
        if projected is not None:
            px, py = projected[k]
            tip = (int(round(x + _RESIDUAL_GAIN * (px - x))), int(round(y + _RESIDUAL_GAIN * (py - y))))
            cv2.line(vis, centre, tip, (0, 220, 255), 1, cv2.LINE_AA)
            cv2.drawMarker(vis, (int(round(px)), int(round(py))), (0, 0, 255), cv2.MARKER_CROSS, 2 * radius, 1)
    # the first corner marks the order convention
    cv2.circle(vis, (int(round(detected[0][0])), int(round(detected[0][1]))), 2 * radius + 2, (255, 0, 0), 2)
    return vis


def write_report(directory: str, data: dict[str, Any]) -> list[str]:
    """Write the report of a calibration (the dict ``calibrate`` writes as JSON) into ``directory``.

    Args:
        directory: existing output directory.
        data: the calibration dictionary (``K``, ``distortion``, ``views`` with ``corners``,
            ``rvec``, ``tvec``, ``board``, ``square``, ...).

    Returns:
        The paths written.
    """
    written: list[str] = []
    K = torch.tensor(data["K"], dtype=torch.float64)
    coeffs = data["distortion"]["coeffs"]
    dist = torch.tensor(coeffs if coeffs else [0.0] * 5, dtype=torch.float64)
    cols, rows = data["board"]
    obj = board_object_points(cols, rows, float(data["square"]), dtype=torch.float64)
    first_used: tuple[str, np.ndarray] | None = None
    names: set[str] = set()
    for index, view in enumerate(data["views"]):
        if not view.get("found") or view.get("corners") is None:
            continue
        gray, _ = load_image_gray(view["path"])
        if gray is None:
            continue
        detected = np.asarray(view["corners"], dtype=np.float64)
        projected = None
        if view.get("rvec") is not None:
            rvec = torch.tensor(view["rvec"], dtype=torch.float64)
            tvec = torch.tensor(view["tvec"], dtype=torch.float64)
            projected = project_points(obj, K, dist, rvec, tvec).numpy()
            if not np.isfinite(projected).all():
                projected = None
        vis = _overlay(gray, detected, projected)
        stem = os.path.splitext(os.path.basename(view["path"]))[0]
        name = f"view_{index:02d}_{stem}.png"
        if name in names:
            continue
        names.add(name)
        target = os.path.join(directory, name)
        if cv2.imwrite(target, vis):
            written.append(target)
        if view.get("used") and first_used is None:
            first_used = (stem, gray)
    if first_used is not None:
        from kornia.geometry.calibration import undistort_image

        stem, gray = first_used
        image = torch.from_numpy(gray).double()[None, None]
        out = undistort_image(image, K[None], dist[None])[0, 0].numpy()
        target = os.path.join(directory, f"undistorted_{stem}.png")
        if cv2.imwrite(target, np.clip(out * 255.0, 0, 255).astype(np.uint8)):
            written.append(target)

    std = data.get("std", {})
    std_dist = std.get("distortion") or [None] * len(coeffs)
    names_dist = ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"][: len(coeffs)]
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
        f"| fx | {_fmt(K[0, 0].item(), 3)} | {_fmt(std.get('fx'))} |",
        f"| fy | {_fmt(K[1, 1].item(), 3)} | {_fmt(std.get('fy'))} |",
        f"| cx | {_fmt(K[0, 2].item(), 3)} | {_fmt(std.get('cx'))} |",
        f"| cy | {_fmt(K[1, 2].item(), 3)} | {_fmt(std.get('cy'))} |",
    ]
    lines += [f"| {n} | {_fmt(c, 6)} | {_fmt(s, 6)} |" for n, c, s in zip(names_dist, coeffs, std_dist)]
    lines += ["", "| view | used | RMS px | note |", "|---|---|---|---|"]
    for view in data["views"]:
        lines.append(
            f"| {os.path.basename(view['path'])} | {'yes' if view.get('used') else 'no'} | "
            f"{_fmt(view.get('rms'))} | {view.get('reason', '')} |"
        )
    lines += [
        "",
        "Overlays: green circles = detected corners, red crosses = reprojected corners, yellow = residual x20, "
        "blue ring = first corner (order convention).",
    ]
    target = os.path.join(directory, "summary.md")
    with open(target, "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    written.append(target)
    return written
