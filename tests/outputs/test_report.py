"""Tests of the calibration report (ccs_kornia.outputs.report.calibration): files, content, scaling, robustness."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, PINHOLE, camera_model
from ccs_kornia.outputs.report.calibration import DISPLAY_MAX_SIDE, write_report
from ccs_kornia.outputs.report.figures import undistorted_preview
from ccs_kornia.outputs.report.quality import distortion_field_plot

BOARD = (6, 4)
K = [[300.0, 0.0, 161.0], [0.0, 298.0, 119.0], [0.0, 0.0, 1.0]]
DIST = [-0.1, 0.01, 0.0, 0.0, 0.0]


def _calibration(tmp_path, size=(320, 240), views=5, unreadable=False, model="opencv5", coeffs=DIST, warp=None):
    """A calibration dict as ``calibrate`` writes it, from projected corners (no detection needed); ``warp``: the
    board bent by mrcal's sag (m)."""
    obj = warped_board(board_object_points(*BOARD, 0.03, dtype=torch.float64),
                       None if warp is None else torch.tensor(warp, dtype=torch.float64))
    g = torch.Generator().manual_seed(3)
    scale = size[0] / 320
    Kt = torch.tensor(K, dtype=torch.float64) * torch.tensor([[scale], [scale], [1.0]], dtype=torch.float64)
    camera = Camera.from_opencv(camera_model(model), Kt, torch.tensor(coeffs, dtype=torch.float64), size)
    out_views = []
    for k in range(views):
        rvec = 0.5 * (torch.rand(3, generator=g, dtype=torch.float64) - 0.5)
        tvec = torch.tensor([-0.08 + 0.01 * k, -0.05, 0.35], dtype=torch.float64)
        uv = camera.project(obj[None], rvec[None], tvec[None])[0]
        noisy = uv + 0.05 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
        image = np.full((size[1], size[0]), 90, np.uint8)
        cv2.fillConvexPoly(image, np.round(uv[[0, BOARD[0] - 1, -1, -BOARD[0]]].numpy()).astype(np.int32), 220)
        path = tmp_path / f"img_{k}.png"
        cv2.imwrite(str(path), image)
        used = k != views - 1  # the last view plays an excluded one
        out_views.append({
            "path": str(path), "found": True, "corners": noisy.tolist(), "used": used,
            "rms": 0.07 if used else None, "rvec": rvec.tolist(), "tvec": tvec.tolist(),
            **({} if used else {"reason": "rejected by image RANSAC", "rms_if_used": 0.9}),
        })
    out_views.append({"path": str(tmp_path / "nothing.png"), "found": False, "used": False, "rms": None,
                      "reason": "board not found"})
    if unreadable:  # a view whose file disappeared after calibration
        out_views[0]["path"] = str(tmp_path / "gone.png")
    return {
        "image_size": list(size), "K": Kt.tolist(), "distortion": {"model": model, "coeffs": list(coeffs)}, "rms": 0.07,
        "rms_kind": "RMS, px", "views": out_views, "board": list(BOARD), "square": 0.03, "detector": "opencv",
        "model": model, "std": {"fx": 0.5, "fy": 0.4, "cx": 0.3, "cy": 0.2, "distortion": [1e-3] * len(coeffs)},
        "num_views": {"files": views + 1, "found": views, "usable": views, "used": views - 1},
    }


def test_files_and_html(tmp_path):
    data = _calibration(tmp_path)
    report = tmp_path / "report"
    report.mkdir()
    written = write_report(str(report), data, progress=False)
    for name in ("index.html", "summary.md", "rms_per_view.png", "residuals.png", "coverage.png", "undistorted.png"):
        assert (report / name).is_file() and str(report / name) in written
    overlays = sorted((report / "views").glob("view_*.png"))
    assert len(overlays) == 5  # every found view, used or not; none for the view without a board
    text = (report / "index.html").read_text()
    for needle in ("fx", "&plusmn; 0.500", "k1", "rejected by image RANSAC", "board not found", "0.0700 px"):
        assert needle in text, needle
    # every image the page refers to exists
    for ref in re.findall(r"(?:src|href)='([^']+)'", text):
        assert (report / ref).is_file(), ref


def test_a_bent_board_and_the_residual_structure(tmp_path):
    data = _calibration(tmp_path, views=8, warp=(0.002, -0.001))
    data["board_flatness"] = {"kept": True, "warp_m": [0.002, -0.001], "std_m": [1e-4, 2e-4],
                              "heldout_median_px": {"flat": 0.41, "warp": 0.07}}
    data["residual_structure"] = {"message": "the residuals are noise", "rms_cell_means_px": 0.01, "cells": 6,
                                  "cells_significant": 0}
    write_report(str(tmp_path), data, progress=False)
    text = (tmp_path / "index.html").read_text()
    assert "board bend (mrcal's sag c_x, c_y): +2.000 &plusmn; 0.100, -1.000 &plusmn; 0.200 mm: kept" in text
    assert "residuals: the residuals are noise" in text and "+2.000 +- 0.100" in (tmp_path / "summary.md").read_text()
    # the views are reprojected through the bent board: its cell means are noise (a flat board leaves mm of sag)
    judged = re.search(r"; (\d+) of (\d+) cells judged", text)
    assert judged and int(judged.group(2)) >= 3 and int(judged.group(1)) <= 1, judged
    figure = cv2.imread(str(tmp_path / "residual_structure.png"))
    assert figure is not None and figure.std() > 10
    data["board_flatness"]["kept"] = False
    write_report(str(tmp_path), data, progress=False)
    judged = re.search(r"; (\d+) of (\d+) cells judged", (tmp_path / "index.html").read_text())
    assert int(judged.group(1)) >= 2  # the same views against the flat board: the sag shows in cells


def test_figures_are_readable_images(tmp_path):
    data = _calibration(tmp_path)
    write_report(str(tmp_path), data, progress=False)
    chart = cv2.imread(str(tmp_path / "rms_per_view.png"))
    assert chart is not None and chart.shape[0] >= 400 and chart.shape[1] >= 640
    # used bars are green, the excluded view's bar orange
    assert ((chart[..., 1] == 170) & (chart[..., 0] == 0) & (chart[..., 2] == 0)).sum() > 500
    assert ((chart[..., 2] == 255) & (chart[..., 1] == 140) & (chart[..., 0] == 0)).sum() > 100
    overlay = cv2.imread(str(sorted((tmp_path / "views").glob("*.png"))[0]))
    assert overlay.shape[1] == 320 and overlay.shape[0] == 240 + 30  # image plus a title strip
    # green circles of the detected corners are drawn
    assert ((overlay[..., 1] > 150) & (overlay[..., 0] < 60) & (overlay[..., 2] < 60)).sum() > 50
    for name in ("residuals.png", "coverage.png", "undistorted.png"):
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.std() > 10, name


def test_large_images_are_downscaled_and_missing_files_skipped(tmp_path):
    data = _calibration(tmp_path, size=(2560, 1920), views=3, unreadable=True)
    written = write_report(str(tmp_path), data, progress=False)
    overlays = sorted((tmp_path / "views").glob("*.png"))
    assert len(overlays) == 2  # the vanished file is skipped, not fatal
    for path in overlays:
        assert max(cv2.imread(str(path)).shape[:2]) <= DISPLAY_MAX_SIDE + 30
    assert any(p.endswith("index.html") for p in written)


@pytest.mark.parametrize("coeffs", [[], [-0.1, 0.01, 0.0, 0.0, 0.0, 0.001, 0.0, 0.0]])
def test_other_distortion_models(tmp_path, coeffs):
    data = _calibration(tmp_path, views=4)
    data["distortion"] = {"model": "none" if not coeffs else "rational", "coeffs": coeffs}
    data["std"]["distortion"] = [1e-3] * len(coeffs)
    write_report(str(tmp_path), data, progress=False)
    text = (tmp_path / "index.html").read_text()
    assert ("k6" in text) == bool(coeffs)


def test_a_fisheye_calibration_is_reported_through_its_camera(tmp_path):
    data = _calibration(tmp_path, views=4, model="fisheye", coeffs=[0.02, -0.01, 0.002, 0.0])
    written = write_report(str(tmp_path), data, progress=False)
    for name in ("residuals.png", "coverage.png", "undistorted.png", "distortion_field.png"):
        image = cv2.imread(str(tmp_path / name))
        assert str(tmp_path / name) in written and image is not None and image.std() > 10, name
    text = (tmp_path / "index.html").read_text()
    # cv2.fisheye's k1..k4 named as such (not as OpenCV's k1, k2, p1, p2)
    assert "<td class='l'>k4</td>" in text and "<td class='l'>p1</td>" not in text


LENSES = {"k1k2": (K1K2, [-0.3, 0.1]), "opencv5": (OPENCV5, DIST), "fisheye": (FISHEYE, [-0.05, 0.01, 0.0, 0.0])}


@pytest.mark.parametrize("name", list(LENSES))
def test_undistorted_preview_of_any_model_has_no_black_border(name):
    model, coeffs = LENSES[name]
    camera = Camera.from_opencv(model, torch.tensor(K, dtype=torch.float64), torch.tensor(coeffs), (320, 240))
    gray = np.full((240, 320), 0.5)
    fig = undistorted_preview(gray, camera, "flat.png")
    assert fig.shape == (240 + 30, 2 * 320 + 10, 3)
    view = fig[30:, 330:]  # the undistorted tile below its title
    assert int(view.min()) == int(view.max()) == 127  # balance 0: every pixel comes from the image
    # the board's outer rows: drawn on both tiles where corners are given
    obj = board_object_points(*BOARD, 0.03, dtype=torch.float64)
    corners = camera.project(obj[None] + torch.tensor([-0.08, -0.05, 0.35], dtype=torch.float64))[0].numpy()
    drawn = undistorted_preview(gray, camera, "flat.png", corners, BOARD)
    assert (np.abs(drawn[30:, 330:].astype(int) - (0, 170, 0)).sum(-1) < 60).sum() > 20  # green corners


def test_distortion_field_of_any_model():
    Kt = torch.tensor(K, dtype=torch.float64)
    flat = distortion_field_plot(Camera.from_opencv(PINHOLE, Kt, None, (320, 240)))
    fields = [distortion_field_plot(Camera.from_opencv(m, Kt, torch.tensor(c), (320, 240))) for m, c in LENSES.values()]
    for fig in fields:
        assert fig.shape == flat.shape and int(np.abs(fig.astype(int) - flat).max()) > 100  # arrows where it has none
    with pytest.raises(ValueError, match="image size"):
        distortion_field_plot(Camera.from_opencv(PINHOLE, Kt))


def test_partial_boards_are_drawn_without_their_hidden_corners(tmp_path):
    """A view with hidden corners (null in the JSON, NaN here) is drawn and plotted on its measured corners, the hidden
    ones marked where the camera puts them."""
    data = _calibration(tmp_path)
    data["views"][1]["corners"][0] = [float("nan"), float("nan")]  # the first grid corner: an outer one
    data["views"][1]["corners"][8] = [None, None]
    data["views"][1]["hidden_corners"] = 2
    write_report(tmp_path / "rep", data)
    assert (tmp_path / "rep" / "index.html").exists()
    for name in ("residuals.png", "coverage.png"):
        assert cv2.imread(str(tmp_path / "rep" / name)) is not None
    view = cv2.imread(str(next((tmp_path / "rep" / "views").glob("view_0001_*.png"))))
    assert view is not None and (np.abs(view.astype(int) - (200, 0, 200)).sum(-1) < 30).sum() > 20  # magenta marks
