"""The command line with ChArUco boards: ``--charuco SXxSY --dictionary --square --marker [--legacy]`` on detect,
calibrate and calibrate-rig; rendered views with exact corners, a wrong dictionary, the real ChArUco sets."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from _charuco_views import POSES, K, render_view
from _real_data import REAL_DATA

from ccs_kornia import cli
from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.runtime.errors import EXIT_OK, EXIT_USAGE

BOARD = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
CHARUCO = ["--charuco", "5x7", "--dictionary", "DICT_6X6_250", "--square", "0.04", "--marker", "0.02", "--jobs", "1"]


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if "error" in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    """The rendered poses as files (plain, and a white-on-black print seen from its back) and their true corners."""
    folder = tmp_path_factory.mktemp("charuco")
    truth = {}
    for k, pose in enumerate(POSES):
        for variant, flags in (("plain", {}), ("back", {"inverted": True, "mirrored": True})):
            image, corners = render_view(BOARD, pose, **flags)
            path = folder / variant / f"view_{k}.png"
            path.parent.mkdir(exist_ok=True)
            cv2.imwrite(str(path), image)
            truth[str(path)] = corners
    return folder, truth


def test_detect_writes_one_entry_per_corner_id(views, tmp_path, capsys):
    folder, truth = views
    out = tmp_path / "corners.json"
    code, stdout, _ = run(capsys, "detect", str(folder / "plain"), str(folder / "back"), *CHARUCO, "--output", str(out))
    assert code == EXIT_OK
    assert "5x7 ChArUco board (4x6 inner corners) in 8 of 8 images" in stdout
    data = json.loads(out.read_text())
    assert data["board"] == [4, 6] and data["detector"] == "charuco"
    assert data["charuco"]["squares"] == [5, 7] and data["charuco"]["dictionary"] == "DICT_6X6_250"
    for image in data["images"]:
        assert image["found"] and len(image["corners"]) == 24
        seen = np.array([c[0] is not None for c in image["corners"]])
        pts = np.array([c if c[0] is not None else [np.nan, np.nan] for c in image["corners"]], dtype=float)
        expected = truth[image["path"]]
        assert seen.sum() >= 6 and np.isfinite(expected[seen]).all()
        assert np.abs(pts[seen] - expected[seen]).max() < 0.1  # right ids: a wrong one is tens of px off
        assert image.get("hidden_corners", 0) == 24 - seen.sum()
        # which path named the corners: each path's count before the merge, and the merge keeps no more than both
        by_path = image["corners_by_path"]
        assert set(by_path) == {"marker_path", "lattice_path"} and max(by_path.values()) >= 6
        assert seen.sum() <= by_path["marker_path"] + by_path["lattice_path"]
        assert image["method"].endswith(f"(named by the marker path: {by_path['marker_path']}, the lattice path: "
                                        f"{by_path['lattice_path']})")


def test_calibrate_rendered_views(views, tmp_path, capsys):
    folder, _ = views
    out = tmp_path / "camera.json"
    code, stdout, err = run(capsys, "calibrate", str(folder / "plain"), *CHARUCO, "--model", "opencv5",
                            "--no-diagnostics", "--output", str(out))
    assert code == EXIT_OK, err
    data = json.loads(out.read_text())
    assert data["charuco"]["marker"] == 0.02
    fx, fy = data["K"][0][0], data["K"][1][1]
    print(f"\nrendered ChArUco views: fx {fx:.2f} fy {fy:.2f} (true {K[0, 0]:.0f}), rms {data['rms']:.4f} px")
    assert abs(fx - K[0, 0]) < 0.01 * K[0, 0] and abs(fy - K[1, 1]) < 0.01 * K[1, 1]


def test_wrong_dictionary_is_named(views, tmp_path, capsys):
    folder, _ = views
    args = [a if a != "DICT_6X6_250" else "DICT_4X4_250" for a in CHARUCO]
    out = tmp_path / "camera.json"
    code, _, err = run(capsys, "calibrate", str(folder / "plain"), *args, "--output", str(out))
    assert code == EXIT_USAGE
    assert one_error_line(err).endswith(
        "no DICT_4X4_250 marker in any image; DICT_6X6_250 markers in 4 of them: wrong --dictionary?")
    assert not out.exists()


@pytest.mark.parametrize("argv, phrase", [
    (["--charuco", "5x7", "--square", "0.04"], "--charuco needs --marker"),
    (["--charuco", "5x7", "--board", "4x6", "--marker", "0.02"], "not allowed with argument"),
    (["--marker", "0.02"], "the following arguments are required: --board COLSxROWS"),
    (["--board", "4x6", "--marker", "0.02"], "--marker describes a ChArUco board"),
    (["--charuco", "5x7", "--marker", "0.02", "--dictionary", "DICT_X"], "unknown ArUco dictionary 'DICT_X'"),
    (["--charuco", "2x7", "--marker", "0.02"], "at least 3x3 squares"),
    (["--charuco", "5x7", "--marker", "2"], "smaller than the square"),
])
def test_bad_charuco_arguments(tmp_path, capsys, argv, phrase):
    code, _, err = run(capsys, "calibrate", str(tmp_path), *argv, "--output", str(tmp_path / "c.json"))
    assert code == EXIT_USAGE
    assert phrase in one_error_line(err)


def test_real_caliscope_cameras_calibrate(tmp_path, capsys):
    folder = REAL_DATA / "caliscope_4cam_charuco"
    if not folder.is_dir():
        pytest.skip(f"real data set not present at {folder} (set CCS_REAL_DATA)")
    import tomllib

    reference = tomllib.loads((folder / "reference" / "camera_array.toml").read_text())["cameras"]
    # white-on-black; cam_1 sees the mirrored back of the board: no flag says so
    for camera in (0, 1):
        out = tmp_path / f"cam_{camera}.json"
        code, _, err = run(capsys, "calibrate", str(folder / f"cam_{camera}"), "--charuco", "4x5", "--dictionary",
                           "DICT_4X4_1000", "--square", "0.054", "--marker", "0.0405", "--model", "opencv5",
                           "--no-diagnostics", "--jobs", "1", "--output", str(out))
        assert code == EXIT_OK, err
        fx = json.loads(out.read_text())["K"][0][0]
        ref = reference[str(camera)]["matrix"][0][0]
        print(f"\ncam_{camera}: fx {fx:.1f}, caliscope's {ref:.1f}")
        assert abs(fx - ref) < 0.03 * ref


@pytest.mark.parametrize("command", ["detect", "calibrate-rig", "calibrate-many"])
def test_every_board_command_takes_charuco(tmp_path, capsys, command):
    code, _, err = run(capsys, command, str(tmp_path), "--charuco", "5x7", "--output", str(tmp_path / "c.json"))
    assert code == EXIT_USAGE
    assert "--charuco needs --marker" in one_error_line(err)


@pytest.mark.parametrize("squares", ["6x8", "7x5"])
def test_wrong_square_count_is_named(views, tmp_path, capsys, squares):
    folder, _ = views
    args = [a if a != "5x7" else squares for a in CHARUCO]
    out = tmp_path / "camera.json"
    code, _, err = run(capsys, "calibrate", str(folder / "plain"), *args, "--output", str(out))
    assert code == EXIT_USAGE
    assert "the DICT_6X6_250 markers fit a 5x7 board" in one_error_line(err)
    assert f"not {squares}" in one_error_line(err) and "wrong --charuco?" in one_error_line(err)
    assert not out.exists()


def test_plain_chessboard_given_as_charuco(tmp_path, capsys):
    # a printed chessboard (white squares without markers), seen twice
    board = np.kron((np.indices((7, 10)).sum(0) % 2) * 255, np.ones((40, 40))).astype(np.uint8)
    image = np.full((480, 640), 200, np.uint8)
    image[40:320, 80:480] = board
    for k in range(2):
        cv2.imwrite(str(tmp_path / f"chess_{k}.png"), np.roll(image, 20 * k, axis=1))
    out = tmp_path / "camera.json"
    code, _, err = run(capsys, "calibrate", str(tmp_path), *CHARUCO, "--output", str(out))
    assert code == EXIT_USAGE
    line = one_error_line(err)
    assert "no DICT_6X6_250 marker in any image" in line and "is it a ChArUco board?" in line
    assert "--board" not in line
    assert not out.exists()
