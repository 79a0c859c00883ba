"""The report's answer to "is my calibration good?": verdict, quality figures, the distortion field and the
projection-uncertainty map (figures as BGR uint8 arrays; see :mod:`ccs_kornia.outputs.report.calibration`)."""

from __future__ import annotations

import html
from typing import Any

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.outputs.report.drawing import (
    BLACK,
    WHITE,
    draw_colour_bar,
    draw_plot_frame,
    draw_text,
    format_number,
    image_canvas,
    int_point,
)

__all__ = ["QUALITY_ROWS", "distortion_field_plot", "grid_map_plot", "quality_html", "quality_markdown", "uncertainty_plot"]

#: (label, key of the diagnostics dict, what it means)
QUALITY_ROWS = (
    ("held-out reprojection RMS", "heldout_rms_px", "views left out of the fit, reprojected with the camera of the rest"),
    ("two halves differ by (RMS)", "cv_rms_px", "two calibrations from disjoint halves of the views, over the image"),
    ("... where boards were", "cv_covered_rms_px", "the same, only where some board was seen"),
    ("... expected from noise", "cv_expected_rms_px", "what the corner noise alone would give"),
    ("projection uncertainty, centre", "uncertainty_centre_px", "1-sigma, from the parameter covariance"),
    ("projection uncertainty, where boards were", "uncertainty_covered_px", "worst over the covered part of the image"),
    ("projection uncertainty, worst", "uncertainty_max_px", "worst over the image (extrapolated where no board was)"),
)


def quality_html(quality: dict[str, Any] | None) -> list[str]:
    """HTML lines of the quality section (empty without diagnostics)."""
    if not quality:
        return []
    esc = html.escape
    parts = ["<h2>Is this calibration good?</h2>", f"<p>Verdict: <b>{esc(str(quality.get('verdict')))}</b></p>"]
    if quality.get("reasons"):
        parts.append("<ul>" + "".join(f"<li>{esc(r)}</li>" for r in quality["reasons"]) + "</ul>")
    for issue in quality.get("errors", []) + quality.get("warnings", []):
        parts.append(f"<p class='l'>{esc(issue['severity'])}: {esc(issue['message'])}</p>")
    parts.append("<table><tr><th>figure</th><th>px</th><th class='l'>meaning</th></tr>")
    for label, key, meaning in QUALITY_ROWS:
        parts.append(f"<tr><td class='l'>{esc(label)}</td><td>{format_number(quality.get(key), 3)}</td>"
                     f"<td class='l'>{esc(meaning)}</td></tr>")
    parts.append("</table><p>See docs/diagnostics.md for how each figure is computed and the verdict's thresholds.</p>")
    return parts


def quality_markdown(quality: dict[str, Any] | None) -> list[str]:
    """Markdown lines of the quality section (empty without diagnostics)."""
    if not quality:
        return []
    lines = ["", "## Is this calibration good?", "", f"Verdict: **{quality.get('verdict')}**", ""]
    lines += [f"- {r}" for r in quality.get("reasons", [])]
    lines += ["", "| figure | px |", "|---|---|"]
    lines += [f"| {label} | {format_number(quality.get(key), 3)} |" for label, key, _ in QUALITY_ROWS]
    return lines


def _field_canvas(size: tuple[int, int], title: str):
    fig, box, scale = image_canvas(size, title, 150)
    x0, y0, w, h = box
    cv2.rectangle(fig, (x0, y0), (x0 + w, y0 + h), (245, 245, 245), -1)
    return fig, box, scale


def distortion_field_plot(camera: Camera, cells: int = 16) -> np.ndarray:
    """Arrows from where a pinhole camera with the same ``K`` would image each ray to where the lens images it
    (the displacement the distortion model applies), coloured by length, over a grid of the image of ``camera`` (one
    camera, any model, with its image size)."""
    if len(camera) != 1 or camera.image_size is None:
        raise ValueError(f"distortion_field_plot takes one camera with its image size, got {camera!r}.")
    w_img, h_img = camera.image_size
    fig, box, scale = _field_canvas((w_img, h_img), "Distortion field: where the lens moves each pinhole pixel")
    x0, y0, w, h = box
    nx, ny = cells, max(2, int(round(cells * h_img / w_img)))
    xs, ys = np.linspace(0, w_img - 1, nx), np.linspace(0, h_img - 1, ny)
    ideal = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    camera = camera.to(dtype=torch.float64)
    K = camera.K
    # each ideal pixel's ray on the normalized plane (the pinhole camera K), then where the lens images it
    normalized = (torch.tensor(ideal, dtype=torch.float64)[None] - K[:, None, :2, 2]) / K[:, None, [0, 1], [0, 1]]
    moved = camera.distort(normalized)[0].numpy()
    d = moved - ideal
    length = np.linalg.norm(d, axis=-1)
    finite = np.isfinite(length)
    vmax = max(float(np.nanmax(np.where(finite, length, np.nan))) if finite.any() else 0.0, 1e-6)
    spacing = min(w / nx, h / ny)
    gain = 0.9 * spacing / (vmax * scale)
    colours = cv2.applyColorMap(np.clip(np.nan_to_num(length) / vmax * 255, 0, 255).astype(np.uint8)[:, None],
                                cv2.COLORMAP_VIRIDIS)[:, 0]
    for k in np.nonzero(finite)[0]:
        start = np.array([x0, y0]) + (ideal[k] + 0.5) * scale
        end = start + gain * d[k] * scale
        colour = tuple(int(c) for c in colours[k])
        if np.linalg.norm(end - start) >= 2:
            cv2.arrowedLine(fig, int_point(start), int_point(end), colour, 1, cv2.LINE_AA, tipLength=0.25)
        else:
            cv2.circle(fig, int_point(start), 1, colour, -1)
    draw_plot_frame(fig, box, (0.0, float(w_img)), (0.0, float(h_img)), "x (px)", "y (px)", y_down=True, grid=False)
    draw_text(fig, f"arrows x{gain:.3g}", (x0 + 8, y0 + h - 10), 0.45, BLACK)
    draw_colour_bar(fig, (x0 + w + 20, y0, 18, h), vmax, "displacement (px)")
    return fig


def uncertainty_plot(size: tuple[int, int], grid_px: list[list[float | None]]) -> np.ndarray:
    """The 1-sigma projection uncertainty over the image (``diagnostics["uncertainty_grid_px"]``), as a colour
    map; grey where the model has no inverse."""
    return grid_map_plot(size, grid_px, "Projection uncertainty (1 sigma, px) over the image", "uncertainty (px)")


def grid_map_plot(size: tuple[int, int], grid_px: list[list[float | None]], title: str, label: str,
                  vmax: float | None = None, cells: bool = False, marked=None) -> np.ndarray:
    """A figure (px) over a grid of the image (``down`` rows of ``across`` values, None or NaN where there is none) as a
    colour map up to ``vmax`` (default its 95th percentile); grey where there is no value. ``cells``: each value
    drawn as its cell (a coarse grid of cell figures), not interpolated; ``marked``: a bool grid of the same shape,
    those cells outlined in white."""
    fig, box, _ = _field_canvas(size, title)
    x0, y0, w, h = box
    values = np.array([[np.nan if v is None else v for v in row] for row in grid_px], np.float64)
    finite = np.isfinite(values)
    if vmax is None:
        vmax = float(np.nanpercentile(values, 95)) if finite.any() else 0.0
    vmax = max(vmax, 1e-6)
    colour = cv2.applyColorMap(np.clip(np.nan_to_num(values) / vmax * 255, 0, 255).astype(np.uint8),
                               cv2.COLORMAP_VIRIDIS)
    colour[~finite] = (200, 200, 200)
    fig[y0:y0 + h, x0:x0 + w] = cv2.resize(colour, (w, h),
                                           interpolation=cv2.INTER_NEAREST if cells else cv2.INTER_LINEAR)
    if marked is not None:
        down, across = values.shape
        for r, c in zip(*np.nonzero(np.asarray(marked, bool))):
            cv2.rectangle(fig, (x0 + round(c * w / across) + 2, y0 + round(r * h / down) + 2),
                          (x0 + round((c + 1) * w / across) - 3, y0 + round((r + 1) * h / down) - 3), WHITE, 2)
    draw_plot_frame(fig, box, (0.0, float(size[0])), (0.0, float(size[1])), "x (px)", "y (px)", y_down=True, grid=False)
    draw_colour_bar(fig, (x0 + w + 20, y0, 18, h), vmax, label)
    return fig
