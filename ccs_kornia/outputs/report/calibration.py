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
* ``undistorted.png``: one used view next to its undistorted version (the view ``undistort --balance 0``
  writes);
* ``summary.md``: the parameter and view tables as Markdown;
* ``.ccs_report_files``: the list of the files above, so that a report written again into ``DIR`` first removes
  what the previous one wrote (overlays of views no longer in the set included) and nothing else: the user's own
  files there are never touched.

Only what ``calibrate`` writes into its JSON is used, plus the images themselves. Large images are
drawn at most :data:`DISPLAY_MAX_SIDE` pixels wide/high so the report stays small and quick.
"""

from __future__ import annotations

import html
import os
import sys
import urllib.parse
from typing import Any

import numpy as np
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.io.files import text_path
from ccs_kornia.io.images import load_image_gray
from ccs_kornia.io.video import VideoReader, split_frame_name
from ccs_kornia.modules.calibration.quality.residual_structure import residual_structure
from ccs_kornia.outputs.calibration_file import camera_from_record
from ccs_kornia.outputs.report.drawing import (
    board_bend_line,
    format_number,
    nice_number,
    write_page,
    write_png,
)
from ccs_kornia.outputs.report.figures import (
    DISPLAY_MAX_SIDE,
    coverage_plot,
    residual_plot,
    rms_chart,
    undistorted_preview,
    view_overlay,
)
from ccs_kornia.outputs.report.quality import (
    distortion_field_plot,
    grid_map_plot,
    quality_html,
    quality_markdown,
    uncertainty_plot,
)

__all__ = ["write_report", "DISPLAY_MAX_SIDE", "MANIFEST"]

#: the file, in a report's directory, listing what the report wrote there (paths relative to it, one JSON list)
MANIFEST = ".ccs_report_files"

_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


# ----------------------------------------------------------------------------------------------
# the report
# ----------------------------------------------------------------------------------------------


def _remove_previous(directory: str) -> None:
    """Remove the files an earlier report listed in its :data:`MANIFEST` (only those, only inside ``directory``), and
    its ``views`` folder once empty."""
    import json

    try:
        with open(os.path.join(directory, MANIFEST), encoding="utf-8") as handle:
            listed = json.load(handle)
    except (OSError, ValueError):
        return
    root = os.path.realpath(directory)
    for name in listed if isinstance(listed, list) else []:
        path = os.path.realpath(os.path.join(root, str(name)))
        if os.path.commonpath([root, path]) == root and os.path.isfile(path):
            os.unlink(path)
    views = os.path.join(directory, "views")
    if os.path.isdir(views) and not os.listdir(views):
        os.rmdir(views)


def _view_image(view: dict[str, Any], readers: dict[str, VideoReader]) -> np.ndarray | None:
    """A view's image as grey ``float32`` in ``[0, 1]``: its file, or its frame of a recording (``VIDEO#INDEX``, read
    with the reader of ``readers`` for that video); ``None`` where it cannot be read."""
    frame = split_frame_name(view["path"])
    if frame is None:
        return load_image_gray(view["path"])[0]
    video, index = frame
    try:
        if video not in readers:
            readers[video] = VideoReader(video)
        got = readers[video].read(index, view.get("timestamp"))
    except (OSError, ValueError):
        return None
    return None if got is None else got.image.astype(np.float32) / 255.0


def _write_manifest(directory: str, written: list[str]) -> None:
    import json

    names = sorted(os.path.relpath(path, directory) for path in written)
    with open(os.path.join(directory, MANIFEST), "w", encoding="utf-8") as handle:
        json.dump(names, handle, indent=0)
        handle.write("\n")


def _coefficient_names(model: Any, count: int) -> list[str]:
    """Names of the first ``count`` coefficients of the model's OpenCV layout (``cv2.fisheye``'s ``k1..k4`` for a
    fisheye; ``k1, k2, p1, p2, k3, ...`` for OpenCV's models, those the model lacks stored as zeros)."""
    names = list(_DIST_NAMES[:count])
    for place, name in zip(model.coeff_index, model.param_names[4:]):
        if place < count:
            names[place] = name
    return names


def _parameter_rows(data: dict[str, Any], camera: Camera) -> list[tuple[str, float, float | None]]:
    K = data["K"]
    std = data.get("std") or {}
    coeffs = data["distortion"]["coeffs"] or []
    std_dist = std.get("distortion") or [None] * len(coeffs)
    rows = [("fx", K[0][0], std.get("fx")), ("fy", K[1][1], std.get("fy")),
            ("cx", K[0][2], std.get("cx")), ("cy", K[1][2], std.get("cy"))]
    rows += [(n, c, s) for n, c, s in zip(_coefficient_names(camera.model, len(coeffs)), coeffs, std_dist)]
    return rows


def write_report(directory: str, data: dict[str, Any], progress: bool | None = None) -> list[str]:
    """Write the report of a calibration (the dict ``calibrate`` writes as JSON) into ``directory``.

    What an earlier report wrote into ``directory`` (listed in its :data:`MANIFEST`) is removed first; other files
    there are left alone.

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
    camera = camera_from_record(data)  # float64, with its image size
    cols, rows = (int(v) for v in data["board"])
    size = camera.image_size
    obj = board_object_points(cols, rows, float(data["square"]), dtype=torch.float64)
    flatness = data.get("board_flatness") or {}
    if flatness.get("kept") and flatness.get("warp_m") is not None:  # the views were fitted to the bent board
        obj = warped_board(obj, torch.tensor(flatness["warp_m"], dtype=torch.float64))
    views = data["views"]
    _remove_previous(directory)
    views_dir = os.path.join(directory, "views")
    os.makedirs(views_dir, exist_ok=True)

    # projections of every view with a pose; residual gain shared by all overlays
    projected: dict[int, np.ndarray] = {}
    for index, view in enumerate(views):
        if view.get("corners") is not None and view.get("rvec") is not None:
            uv = camera.project(obj[None], torch.tensor(view["rvec"], dtype=torch.float64)[None],
                                torch.tensor(view["tvec"], dtype=torch.float64)[None])[0].numpy()
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
    gain = nice_number(0.35 * spacing / p95) if p95 > 0 else 20.0
    gain = float(np.clip(gain, 1.0, 10000.0))

    overlay_names: dict[int, str] = {}
    first_used: tuple[str, np.ndarray, np.ndarray] | None = None
    # every view gets an overlay: the ones without a board too, titled with the reason (what the user needs to see)
    candidates = [i for i, v in enumerate(views) if v.get("path")]
    readers: dict[str, VideoReader] = {}
    for index in tqdm(candidates, desc="report", unit="view", file=sys.stderr, disable=None if progress is None else not progress,
                      leave=False):
        view = views[index]
        gray = _view_image(view, readers)
        if gray is None:
            continue
        found = view.get("found") and view.get("corners") is not None
        detected = np.asarray(view["corners"] if found else np.zeros((0, 2)), dtype=np.float64)
        base = os.path.basename(view["path"])
        status = (f"used, RMS {format_number(view.get('rms'))} px" if view.get("used")
                  else f"not used: {view.get('reason', '')}")
        if not found:
            status = f"no board: {view.get('reason', 'not found')}"
        title = f"view {index}: {base} - {status}"
        vis = view_overlay(gray, detected, projected.get(index), gain, title)
        stem = text_path(os.path.splitext(base)[0])  # the page links to it: a name every browser can ask for
        name = f"view_{index:04d}_{stem}.png"
        if write_png(os.path.join(views_dir, name), vis, written):
            overlay_names[index] = f"views/{urllib.parse.quote(name)}"
        if view.get("used") and first_used is None and (gray.shape[1], gray.shape[0]) == size:
            first_used = (base, gray, detected)
    for reader in readers.values():
        reader.close()

    figures: list[tuple[str, str, str]] = []
    if views:
        if write_png(os.path.join(directory, "rms_per_view.png"), rms_chart(views, data.get("rms")), written):
            figures.append(("rms_per_view.png", "Per-view RMS",
                            "Bars: RMS reprojection error of each view under the final camera. Orange views were "
                            "excluded (RANSAC or outlier check); a view far above the dashed line deserves a look."))
    if residuals:
        fig = residual_plot(size, np.concatenate(detected_used), np.concatenate(residuals))
        if write_png(os.path.join(directory, "residuals.png"), fig, written):
            figures.append(("residuals.png", "Residual vectors",
                            "Each arrow starts at a detected corner and points to its reprojection, magnified. "
                            "Random directions are noise; a pattern (e.g. radial at the borders) is model error."))
    if residuals:
        structure = _structure_plot(size, detected_used, residuals)
        if structure is not None and write_png(os.path.join(directory, "residual_structure.png"), structure[0],
                                               written):
            figures.append(("residual_structure.png", "Residual structure",
                            f"The mean residual of each image cell (px) over the used views; {structure[1]} of "
                            f"{structure[2]} cells judged (outlined) have a mean beyond what the corners' noise explains (99 %), "
                            "grey cells too few corners to judge. Noise alone leaves small, scattered cell means; a "
                            "pattern (larger towards the edges, one side) is what the model or a flat board did not "
                            "explain."))
    coverage = None
    if detected_used:
        fig, coverage = coverage_plot(size, detected_used, (cols, rows))
        if write_png(os.path.join(directory, "coverage.png"), fig, written):
            figures.append(("coverage.png", "Coverage",
                            "Corners per image cell over the used views. Distortion is only constrained where "
                            "corners were seen: empty borders mean extrapolated distortion there."))
    if first_used is not None:
        base, gray, detected = first_used
        seen = np.concatenate(detected_used) if detected_used else None
        preview = undistorted_preview(gray, camera, base, detected, (cols, rows), seen)
        if write_png(os.path.join(directory, "undistorted.png"), preview, written):
            figures.append(("undistorted.png", "Undistorted preview",
                            "A used view and the same view undistorted with the calibration, as 'undistort "
                            "--balance 0' writes it: a pinhole view centred on the optical axis, the largest "
                            "without black borders within the lens's valid field. Red lines are "
                            "straight; the board's outer corners (green) bow away from them under distortion and "
                            "should sit on them once undistorted."))

    field = distortion_field_plot(camera)
    if write_png(os.path.join(directory, "distortion_field.png"), field, written):
        figures.append(("distortion_field.png", "Distortion field",
                        "Where the lens moves each pixel of a pinhole camera with the same K. Beyond the covered "
                        "part of the image (coverage plot) this is extrapolated by the model."))
    quality = data.get("diagnostics") or {}
    if quality.get("uncertainty_grid_px"):
        fig = uncertainty_plot(size, quality["uncertainty_grid_px"])
        if write_png(os.path.join(directory, "uncertainty.png"), fig, written):
            figures.append(("uncertainty.png", "Projection uncertainty",
                            "1-sigma uncertainty of where a fixed ray lands, from the parameter covariance (the "
                            "rotation a principal-point shift mimics fitted out). High values where no board was "
                            "seen: add views with the board there."))
    written.append(_write_html(os.path.join(directory, "index.html"), data, camera, figures, overlay_names, gain,
                               coverage))
    written.append(_write_markdown(os.path.join(directory, "summary.md"), data, camera, gain))
    _write_manifest(directory, written)
    return written


def _structure_plot(size: tuple[int, int], detected: list[np.ndarray], residuals: list[np.ndarray]):
    """The residual structure figure (:func:`residual_structure`'s cell means as a map), the cells beyond their noise
    and the cells judged; ``None`` where the views do not share one board size."""
    if len({d.shape for d in detected}) != 1:
        return None
    corners = torch.from_numpy(np.stack(detected))[None]
    res = torch.from_numpy(np.stack(residuals))[None]
    s = residual_structure(res, corners, corners.isfinite().all(-1) & res.isfinite().all(-1), size)
    length = s.cell_means[0].norm(dim=-1)
    fig = grid_map_plot(size, length.tolist(), "Mean residual per image cell (px); outlined: beyond the noise",
                        "cell mean (px)", cells=True, marked=s.cell_significant[0].tolist())
    return fig, int(s.significant[0]), int(s.cells[0])


def _write_html(path: str, data: dict[str, Any], camera: Camera, figures: list[tuple[str, str, str]],
                overlays: dict[int, str], gain: float, coverage: float | None) -> str:
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
        f"<li>RMS reprojection error <b>{format_number(data['rms'])} px</b> ({esc(data.get('rms_kind', ''))})</li>",
    ]
    if coverage is not None:
        parts.append(f"<li>image coverage: {100 * coverage:.0f}% of the cells hold a detected corner</li>")
    bend = board_bend_line(data.get("board_flatness") or {}, data.get("square"))
    if bend:
        parts.append(f"<li>{bend}</li>")
    structure = data.get("residual_structure") or {}
    if structure.get("message"):
        parts.append(f"<li>residuals: {esc(structure['message'])} (RMS of the cell means "
                     f"{format_number(structure.get('rms_cell_means_px'))} px, {structure.get('cells_significant')} "
                     f"of {structure.get('cells')} cells beyond the noise)</li>")
    parts += ["</ul>", *quality_html(data.get("diagnostics")), "<h2>Parameters</h2>", "<table><tr><th>parameter</th><th>value</th><th>std (1 sigma)</th></tr>"]
    for name, value, std in _parameter_rows(data, camera):
        digits = 3 if name in ("fx", "fy", "cx", "cy") else 6
        parts.append(f"<tr><td class='l'>{name}</td><td>{format_number(value, digits)}</td>"
                     f"<td>&plusmn; {format_number(std, digits)}</td></tr>")
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
            f"<td>{'yes' if view.get('used') else 'no'}</td><td>{format_number(rms)}</td>"
            f"<td class='l'>{esc(view.get('reason', ''))}</td><td>{link}</td></tr>"
        )
    parts += ["</table></body></html>"]
    return write_page(path, "\n".join(parts) + "\n")


def _write_markdown(path: str, data: dict[str, Any], camera: Camera, gain: float) -> str:
    cols, rows = data["board"]
    lines = [
        "# Calibration report",
        "",
        f"- image size: {data['image_size'][0]} x {data['image_size'][1]}",
        f"- board: {cols} x {rows} inner corners, square {data['square']}",
        f"- detector: {data.get('detector', '?')}, model: {data['distortion']['model']}",
        f"- views: {data.get('num_views', {})}",
        f"- RMS reprojection error: {format_number(data['rms'])} px ({data.get('rms_kind', '')})",
        *([f"- {board_bend_line(data['board_flatness'], data.get('square')).replace('&plusmn;', '+-')}"]
          if board_bend_line(data.get("board_flatness") or {}) else []),
        "",
        "| parameter | value | std |",
        "|---|---|---|",
    ]
    for name, value, std in _parameter_rows(data, camera):
        digits = 3 if name in ("fx", "fy", "cx", "cy") else 6
        lines.append(f"| {name} | {format_number(value, digits)} | {format_number(std, digits)} |")
    lines += quality_markdown(data.get("diagnostics"))
    lines += ["", "| view | used | RMS px | note |", "|---|---|---|---|"]
    for view in data["views"]:
        lines.append(f"| {os.path.basename(view['path'])} | {'yes' if view.get('used') else 'no'} | "
                     f"{format_number(view.get('rms'))} | {view.get('reason', '')} |")
    lines += ["", f"Overlays (views/): green circles = detected corners, red crosses = reprojected corners, "
                  f"yellow = residual x{gain:g}, blue ring = first corner (order convention). See index.html."]
    return write_page(path, "\n".join(lines) + "\n")
