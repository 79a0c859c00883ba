"""The command line with Kalibr's AprilGrid: ``--aprilgrid TARGET_YAML`` on detect, calibrate and calibrate-rig;
rendered views with exact corners (half of them cut by the frame), bad target files."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from ccs_kornia import cli
from ccs_kornia.data.scenes.marker_views import K, render_condition
from ccs_kornia.modules.detection.boards import AprilGrid
from ccs_kornia.runtime.errors import EXIT_OK, EXIT_USAGE

GRID = AprilGrid(6, 6, 0.088, 0.3)
YAML = "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n"


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if "error" in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def target(tmp_path_factory):
    """The target YAML, 10 rendered views (every other one cut by the frame) and their true corners."""
    folder = tmp_path_factory.mktemp("aprilgrid")
    (folder / "april.yaml").write_text(YAML)
    rng = np.random.default_rng(7)
    truth = {}
    for k in range(10):
        image, corners = render_condition(GRID, "partial" if k % 2 else "clean", rng, supersample=2)
        path = folder / "images" / f"view_{k:02d}.png"
        path.parent.mkdir(exist_ok=True)
        cv2.imwrite(str(path), image)
        truth[str(path)] = corners
    return folder, truth


def test_detect_writes_kalibr_corner_ids(target, tmp_path, capsys):
    folder, truth = target
    out = tmp_path / "corners.json"
    code, stdout, _ = run(capsys, "detect", str(folder / "images"), "--aprilgrid", str(folder / "april.yaml"),
                          "--jobs", "1", "--output", str(out))
    assert code == EXIT_OK
    assert "6x6 AprilGrid (144 tag corners) in 10 of 10 images" in stdout
    data = json.loads(out.read_text())
    assert data["board"] == [12, 12] and data["detector"] == "aprilgrid"
    assert data["aprilgrid"]["tagCols"] == 6 and data["aprilgrid"]["tagSpacing"] == 0.3
    for image in data["images"]:
        assert image["found"] and len(image["corners"]) == 144
        got = np.array([c if c[0] is not None else [np.nan, np.nan] for c in image["corners"]], dtype=float)
        seen = np.isfinite(got).all(-1)
        want = truth[image["path"]]
        assert np.isfinite(want[seen]).all()
        assert np.abs(got[seen] - want[seen]).max() < 0.5  # no wrong id: the next id is a tag side away


def test_calibrate_from_partial_views(target, tmp_path, capsys):
    folder, _ = target
    out = tmp_path / "cal.json"
    code, stdout, _ = run(capsys, "calibrate", str(folder / "images"), "--aprilgrid", str(folder / "april.yaml"),
                          "--model", "opencv5", "--jobs", "1", "--no-distortion-correction", "--no-diagnostics",
                          "--output", str(out))
    assert code == EXIT_OK, stdout
    data = json.loads(out.read_text())
    assert data["aprilgrid"]["tagSize"] == 0.088
    assert abs(data["K"][0][0] - K[0, 0]) < 0.005 * K[0, 0]
    assert data["rms"] < 0.1
    assert "corners not seen left out" in stdout


@pytest.mark.parametrize("text, expected", [
    (None, "cannot read"),
    ("target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7\n", "expected 'aprilgrid'"),
    ("target_type: 'aprilgrid'\ntagCols: 6\n", "missing tagRows, tagSize, tagSpacing"),
    ("target_type: [aprilgrid\n", "not a readable YAML file"),
])
def test_bad_target_file(tmp_path, capsys, text, expected):
    path = tmp_path / "t.yaml"
    if text is not None:
        path.write_text(text)
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.full((32, 32), 128, np.uint8))
    code, _, err = run(capsys, "detect", str(image), "--aprilgrid", str(path), "--output", str(tmp_path / "o.json"))
    assert code == EXIT_USAGE
    assert expected in one_error_line(err)
    assert not (tmp_path / "o.json").exists()


def test_aprilgrid_with_charuco_options(target, tmp_path, capsys):
    folder, _ = target
    code, _, err = run(capsys, "detect", str(folder / "images"), "--aprilgrid", str(folder / "april.yaml"),
                       "--marker", "0.02", "--output", str(tmp_path / "o.json"))
    assert code == EXIT_USAGE
    assert "describes a ChArUco board" in one_error_line(err)


def test_one_board_only(target, tmp_path, capsys):
    folder, _ = target
    code, _, err = run(capsys, "detect", str(folder / "images"), "--aprilgrid", str(folder / "april.yaml"),
                       "--board", "9x6", "--output", str(tmp_path / "o.json"))
    assert code == EXIT_USAGE
    assert "not allowed with argument" in one_error_line(err)


def test_calibrate_many_takes_aprilgrid(target, tmp_path, capsys):
    folder, _ = target
    out = tmp_path / "many.jsonl"
    code, stdout, _ = run(capsys, "calibrate-many", str(folder / "images"), "--aprilgrid", str(folder / "april.yaml"),
                          "--model", "opencv5", "--output", str(out))
    assert code == EXIT_OK, stdout
    (line,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert line["success"] and line["detector"] == "aprilgrid" and line["aprilgrid"]["tagRows"] == 6
    assert abs(line["K"][0][0] - K[0, 0]) < 0.005 * K[0, 0]


def test_calibrate_many_needs_a_board(tmp_path, capsys):
    code, _, err = run(capsys, "calibrate-many", str(tmp_path), "--output", str(tmp_path / "m.jsonl"))
    assert code == EXIT_USAGE
    assert "--board COLSxROWS" in one_error_line(err) and "--aprilgrid TARGET_YAML" in one_error_line(err)


def test_calibrate_rig_takes_aprilgrid(tmp_path, capsys):
    from ccs_kornia.data.scenes.marker_views import (
        random_board_pose,
        render_marker_view,
    )

    (tmp_path / "april.yaml").write_text(YAML)
    rng = np.random.default_rng(9)
    baseline = 0.12  # camera 1 sits 0.12 m right of camera 0, the same orientation
    frame = 0
    while frame < 8:
        rvec, tvec = random_board_pose(GRID, rng, partial=bool(frame % 2))
        views = [render_marker_view(GRID, rvec, tvec - np.array([b, 0.0, 0.0]), supersample=2) for b in (0, baseline)]
        if np.isfinite(views[1][1]).all(-1).sum() < 30:
            continue  # camera 1 sees too little of this pose
        for cam, (image, _) in enumerate(views):
            (tmp_path / f"cam{cam}").mkdir(exist_ok=True)
            cv2.imwrite(str(tmp_path / f"cam{cam}" / f"f{frame:02d}.png"), image)
        frame += 1
    out = tmp_path / "rig.json"
    code, _, err = run(capsys, "calibrate-rig", str(tmp_path / "cam0"), str(tmp_path / "cam1"), "--aprilgrid",
                       str(tmp_path / "april.yaml"), "--model", "opencv5", "--output", str(out))
    assert code == EXIT_OK, err
    data = json.loads(out.read_text())
    assert data["aprilgrid"]["tagCols"] == 6 and data["detector"] == "aprilgrid"
    t = np.array(data["extrinsics"][1]["T"], dtype=float)
    assert abs(np.linalg.norm(t) - baseline) < 0.002 * baseline
