"""The command line with circle grids: ``--circles COLSxROWS --spacing S [--asymmetric] [--marked-origin]`` on detect
and calibrate (rendered views with exact centres through a strong lens), the options' errors, and ROS-Industrial's
eye-in-hand set (end to end)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from ccs_kornia import cli
from ccs_kornia.data.scenes.marker_views import K, random_board_pose, render_marker_view
from ccs_kornia.modules.detection.boards import CircleGrid
from ccs_kornia.runtime.errors import EXIT_OK, EXIT_USAGE
from tests._real_data import REAL_DATA

GRID = CircleGrid(4, 11, 0.02, asymmetric=True)


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    """8 rendered views of an asymmetric 4x11 grid (tilted up to 50 degrees) and their true centres."""
    folder = tmp_path_factory.mktemp("circles")
    rng = np.random.default_rng(21)
    truth = {}
    for k in range(8):
        rvec, tvec = random_board_pose(GRID, rng, tilt_deg=50.0)
        image, centres = render_marker_view(GRID, rvec, tvec, supersample=2)
        path = folder / f"view_{k:02d}.png"
        cv2.imwrite(str(path), image)
        truth[str(path)] = centres
    return folder, truth


def test_detect_writes_the_grid(views, tmp_path, capsys):
    folder, truth = views
    out = tmp_path / "corners.json"
    code, stdout, _ = run(capsys, "detect", str(folder), "--circles", "4x11", "--spacing", "0.02", "--asymmetric",
                          "--jobs", "1", "--output", str(out))
    assert code == EXIT_OK
    assert "4x11 circle grid in 8 of 8 images" in stdout
    data = json.loads(out.read_text())
    assert data["detector"] == "circles" and data["circles"]["layout"] == "asymmetric"
    for image in data["images"]:
        got = np.array(image["corners"], dtype=float)
        assert np.abs(got - truth[image["path"]]).max() < 1.0  # measured, not yet corrected: the right dots


def test_calibrate_corrects_the_centres(views, tmp_path, capsys):
    folder, _ = views
    out = tmp_path / "cal.json"
    code, stdout, _ = run(capsys, "calibrate", str(folder), "--circles", "4x11", "--spacing", "0.02", "--asymmetric",
                          "--model", "opencv5", "--jobs", "1", "--no-distortion-correction", "--no-diagnostics",
                          "--output", str(out))
    assert code == EXIT_OK, stdout
    data = json.loads(out.read_text())
    assert data["circles"]["spacing"] == 0.02
    assert abs(data["K"][0][0] - K[0, 0]) < 0.003 * K[0, 0]
    assert data["rms"] < 0.05  # the corrected centres fit the camera to the renderer's precision


@pytest.mark.parametrize("argv, words", [
    (["--circles", "4x11"], "--circles needs --spacing"),
    (["--board", "9x6", "--spacing", "0.02"], "--spacing describes a circle grid"),
    (["--circles", "4x11", "--spacing", "0.02", "--asymmetric", "--marked-origin"], "modified circle grid"),
])
def test_option_errors(views, tmp_path, capsys, argv, words):
    folder, _ = views
    code, _, err = run(capsys, "detect", str(folder), *argv, "--output", str(tmp_path / "c.json"))
    assert code == EXIT_USAGE
    lines = [line for line in err.splitlines() if "error" in line]
    assert len(lines) == 1 and words in lines[0], err


@pytest.mark.parametrize("command", [
    ["calibrate-hand-eye", "--robot-poses", "poses.csv", "--eye-in-hand"],
    ["calibrate-rig", "cam1"],
])
@pytest.mark.parametrize("grid, words", [
    (["--circles", "4x5", "--spacing", "0.02"], "a symmetric grid"),
    (["--circles", "4x10", "--spacing", "0.02", "--asymmetric"], "an asymmetric grid of 10 rows"),
])
def test_a_grid_without_its_origin_is_refused_where_views_are_joined(tmp_path, capsys, command, grid, words):
    # refused before any image or pose file is read: its dot ids cannot be told from view to view
    code, stdout, err = run(capsys, command[0], str(tmp_path / "cam0"), *command[1:], *grid,
                            "--output", str(tmp_path / "out.json"))
    assert code == EXIT_USAGE and not stdout
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0], err
    assert "--marked-origin" in lines[0] and "--asymmetric" in lines[0]


def test_a_grid_with_its_origin_is_not_refused(tmp_path, capsys):
    # a marked origin passes the check and fails later, on the missing pose file
    code, _, err = run(capsys, "calibrate-hand-eye", str(tmp_path), "--robot-poses", str(tmp_path / "poses.csv"),
                       "--eye-in-hand", "--circles", "4x5", "--spacing", "0.02", "--marked-origin",
                       "--output", str(tmp_path / "out.json"))
    assert code == EXIT_USAGE and "half a turn" not in err


RIC = REAL_DATA / "ric_circlegrid_eye_in_hand"


@pytest.mark.e2e
@pytest.mark.skipif(not RIC.is_dir(), reason=f"{RIC} not found")
def test_ric_circle_grid_calibrates_and_the_robot_tells_its_spacing(tmp_path, capsys):
    grid = ["--circles", "10x10", "--marked-origin"]
    code, stdout, _ = run(capsys, "calibrate", str(RIC / "images"), *grid, "--spacing", "0.0254",
                          "--output", str(tmp_path / "cal.json"))
    assert code == EXIT_OK, stdout
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert sum(v["used"] for v in cal["views"]) == 15 and cal["rms"] < 0.3
    hand_eye = ["calibrate-hand-eye", str(RIC / "images"), "--robot-poses", str(RIC / "poses.csv"), "--eye-in-hand",
                *grid, "--calibration", str(tmp_path / "cal.json")]
    # the spacing of the source's cal_data.yaml (25.4 mm) disagrees with the robot's translations by about 2 %
    code, _, err = run(capsys, *hand_eye, "--spacing", "0.0254", "--output", str(tmp_path / "refused.json"))
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == EXIT_USAGE and len(lines) == 1 and "--spacing 0.0248" in lines[0], err
    code, stdout, _ = run(capsys, *hand_eye, "--spacing", "0.02482", "--output", str(tmp_path / "he.json"))
    assert code == EXIT_OK, stdout
    he = json.loads((tmp_path / "he.json").read_text())
    assert he["board"]["circles"]["layout"] == "marked_origin"
    assert he["heldout"]["rms_px"] < 3.0


CHARUCO = REAL_DATA / "ric_charuco_eye_to_hand"


@pytest.mark.e2e
@pytest.mark.skipif(not CHARUCO.is_dir(), reason=f"{CHARUCO} not found")
def test_a_camera_without_its_distortion_is_named(tmp_path, capsys):
    # the set's own pinhole intrinsics (cal_data.yaml), without the lens's distortion (k1 about -0.14)
    camera = tmp_path / "pinhole.json"
    camera.write_text(json.dumps({"image_size": [1600, 1200], "K": [[1352.02747, 0, 789.67065],
                                                                   [0, 1356.14287, 627.2995], [0, 0, 1]],
                                  "distortion": {"model": "none", "coeffs": []}}))
    code, stdout, _ = run(capsys, "calibrate-hand-eye", str(CHARUCO / "images"), "--robot-poses",
                          str(CHARUCO / "poses.csv"), "--eye-to-hand", "--charuco", "5x7", "--square", "0.036195",
                          "--marker", "0.018256", "--calibration", str(camera), "--output", str(tmp_path / "he.json"))
    assert code == EXIT_OK
    assert "verdict: not reliable: the given camera does not fit these images" in stdout
    assert "check the robot's pose" not in stdout
