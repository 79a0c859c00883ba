"""``--corners corners.json`` on ``calibrate`` and ``calibrate-rig``: the corners ``detect`` wrote, solved without
detecting again, give the calibration the images give; every refusal is one line with nothing written.

``detect`` writes corners to 1e-4 px (``CORNER_DECIMALS``), so a solve on its file differs from the solve on the images
by what that rounding moves (a relative 1e-6 in the focal length); the solve on unrounded corners is the same to the
last digits (``tests/pipeline/test_corners_input.py``).
"""

from __future__ import annotations

import json
import math

import cv2
import pytest
from _charuco_views import POSES, render_view
from _real_data import REAL_DATA
from _rig_images import render_stereo, write_stereo

from ccs_kornia import cli
from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.runtime.errors import EXIT_OK, EXIT_USAGE

FAST = ["--detector", "opencv", "--no-distortion-correction", "--jobs", "1"]
RIG = ["--board", "6x4", "--square", "0.025", *FAST, "--model", "k1k2", "--no-ransac"]
CHARUCO = ["--charuco", "5x7", "--dictionary", "DICT_6X6_250", "--square", "0.04", "--marker", "0.02", "--jobs", "1"]
OPENCV_LEFT = REAL_DATA / "opencv_left"


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_refused(code: int, err: str, output, *phrases: str) -> None:
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == EXIT_USAGE and len(lines) == 1 and "Traceback" not in err, err
    for phrase in phrases:
        assert phrase in lines[0], lines[0]
    assert not output.exists()


def assert_same_camera(a: dict, b: dict, rel: float) -> None:
    assert a["distortion"]["model"] == b["distortion"]["model"]
    for i in range(3):
        for j in range(3):
            assert math.isclose(a["K"][i][j], b["K"][i][j], rel_tol=rel, abs_tol=1e-12)
    for x, y in zip(a["distortion"]["coeffs"], b["distortion"]["coeffs"]):
        assert abs(x - y) <= rel * 100 * max(1.0, abs(x))
    assert [v["used"] for v in a["views"]] == [v["used"] for v in b["views"]]
    assert math.isclose(a["rms"], b["rms"], rel_tol=100 * rel)


@pytest.fixture(scope="module")
def stereo_files(tmp_path_factory):
    """A rendered stereo pair as folders, and each camera's corners as detect writes them."""
    root = tmp_path_factory.mktemp("corners_rig")
    left, right = write_stereo(render_stereo(frames=8, seed=3), root)
    files = []
    for folder in (left, right):
        out = root / f"{folder.name}.json"
        assert cli.main(["detect", str(folder), "--board", "6x4", *FAST, "--output", str(out)]) == EXIT_OK
        files.append(out)
    return root, [left, right], files


@pytest.mark.skipif(not OPENCV_LEFT.is_dir(), reason=f"real data not present in {REAL_DATA}")
def test_detect_then_calibrate_gives_the_calibration_of_the_images(tmp_path, capsys):
    on_images, corners, given = tmp_path / "images.json", tmp_path / "corners.json", tmp_path / "given.json"
    assert run(capsys, "calibrate", OPENCV_LEFT, "--board", "9x6", "--square", "0.025", "--output", on_images)[0] == 0
    assert run(capsys, "detect", OPENCV_LEFT, "--board", "9x6", "--output", corners)[0] == EXIT_OK
    detected = json.loads(corners.read_text())
    assert detected["image_size"] == [640, 480]
    assert all(len(v["corner_sigma"]) == 54 and all(s > 0 for s in v["corner_sigma"]) for v in detected["images"])
    code, _, err = run(capsys, "calibrate", "--corners", corners, "--board", "9x6", "--square", "0.025",
                         "--output", given)
    assert code == EXIT_OK, err
    assert "board in 13 of 13 views of 640x480 images (corners given, not detected again)" in err
    a, b = json.loads(on_images.read_text()), json.loads(given.read_text())
    assert b["corners_file"] == str(corners) and b["corner_weights"] and "video" not in b
    assert a["model_selection"]["chosen"] == b["model_selection"]["chosen"]
    assert a["distortion_correction"]["tried"] == b["distortion_correction"]["tried"]
    assert [v["path"] for v in a["views"]] == [v["path"] for v in b["views"]]
    assert_same_camera(a, b, rel=1e-5)


def test_charuco_corners_give_the_calibration_of_the_images(tmp_path, capsys):
    board = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")
    folder = tmp_path / "views"
    folder.mkdir()
    for k, pose in enumerate(POSES):
        cv2.imwrite(str(folder / f"view_{k}.png"), render_view(board, pose)[0])
    on_images, corners, given = tmp_path / "images.json", tmp_path / "corners.json", tmp_path / "given.json"
    solve = ["--model", "opencv5", "--no-diagnostics"]
    assert run(capsys, "calibrate", folder, *CHARUCO, *solve, "--output", on_images)[0] == EXIT_OK
    assert run(capsys, "detect", folder, *CHARUCO, "--output", corners)[0] == EXIT_OK
    code, _, err = run(capsys, "calibrate", "--corners", corners, *CHARUCO, *solve, "--output", given)
    assert code == EXIT_OK, err
    a, b = json.loads(on_images.read_text()), json.loads(given.read_text())
    assert b["charuco"] == a["charuco"]
    assert [v.get("hidden_corners") for v in a["views"]] == [v.get("hidden_corners") for v in b["views"]]
    assert_same_camera(a, b, rel=1e-5)
    # another dictionary is another board
    other = tmp_path / "other.json"
    code, _, err = run(capsys, "calibrate", "--corners", corners, *CHARUCO[:2], "--dictionary", "DICT_4X4_50",
                       *CHARUCO[4:], "--output", other)
    assert_refused(code, err, other, "5x7 ChArUco board (DICT_6X6_250)", "not the 5x7 ChArUco board (DICT_4X4_50)")


def test_rig_from_corners_files(stereo_files, tmp_path, capsys):
    _, folders, files = stereo_files
    on_images, given = tmp_path / "images.json", tmp_path / "given.json"
    assert run(capsys, "calibrate-rig", *folders, *RIG, "--output", on_images)[0] == EXIT_OK
    code, _, err = run(capsys, "calibrate-rig", "--corners", files[0], "--corners", files[1], *RIG,
                         "--output", given)
    assert code == EXIT_OK, err
    a, b = json.loads(on_images.read_text()), json.loads(given.read_text())
    assert b["corners_files"] == [str(f) for f in files] and a["frame_labels"] == b["frame_labels"]
    for ca, cb in zip(a["cameras"], b["cameras"]):
        assert_same_camera(ca, cb, rel=1e-5)
    for ea, eb in zip(a["extrinsics"], b["extrinsics"]):
        assert all(abs(x - y) < 1e-6 for x, y in zip(ea["T"], eb["T"]))


def test_rig_views_pair_by_their_timestamps(stereo_files, tmp_path, capsys):
    """Views with timestamps pair by time, as a rig's recordings do: the second camera 3 ms late, its first view
    missing and its views named out of order."""
    files = stereo_files[2]
    timed = []
    for c, path in enumerate(files):
        data = json.loads(path.read_text())
        for k, view in enumerate(data["images"]):
            view["timestamp"] = 0.1 * k + 0.003 * c
            view["path"] = f"cam{c}.mp4#{k if c == 0 else 100 - k}"
        if c == 1:
            data["images"] = data["images"][1:]
        timed.append(tmp_path / f"cam{c}.json")
        timed[-1].write_text(json.dumps(data))
    out = tmp_path / "rig.json"
    code, _, err = run(capsys, "calibrate-rig", "--corners", timed[0], "--corners", timed[1], *RIG, "--output", out)
    assert code == EXIT_OK, err
    assert "frames paired by timestamp: 8 instants, 7 of them with frames of two cameras" in err
    data = json.loads(out.read_text())
    assert data["frame_times"][1][0] is None and data["frame_times"][1][1] == pytest.approx(0.103)
    assert data["cameras"][1]["views"][0]["timestamp"] == pytest.approx(0.103)
    assert max(s for s in data["frame_spread_s"] if s is not None) == pytest.approx(0.003)


def test_image_size_is_required_where_the_file_does_not_say_it(stereo_files, tmp_path, capsys):
    files = stereo_files[2]
    data = json.loads(files[0].read_text())
    del data["image_size"]
    for view in data["images"]:
        view.pop("image_size", None)
    old = tmp_path / "old.json"
    old.write_text(json.dumps(data))
    out = tmp_path / "camera.json"
    base = ["calibrate", "--corners", old, *RIG, "--output", out]
    code, _, err = run(capsys, *base)
    assert_refused(code, err, out, "does not say the images' size", "give --image-size WxH")
    code, _, err = run(capsys, *base, "--image-size", "320x240")
    assert code == EXIT_OK, err
    assert json.loads(out.read_text())["image_size"] == [320, 240]
    other = tmp_path / "other.json"
    code, _, err = run(capsys, "calibrate", "--corners", files[0], *RIG, "--image-size", "640x480", "--output", other)
    assert_refused(code, err, other, "--image-size 640x480: the corners of", "are on 320x240 images")


def test_report_without_the_images(stereo_files, tmp_path, capsys):
    files = stereo_files[2]
    moved = tmp_path / "corners.json"
    data = json.loads(files[0].read_text())
    for view in data["images"]:
        view["path"] = str(tmp_path / "gone" / view["path"].rsplit("/", 1)[-1])
    moved.write_text(json.dumps(data))
    report = tmp_path / "report"
    code, _, err = run(capsys, "calibrate", "--corners", moved, *RIG, "--output", tmp_path / "c.json",
                       "--report", report)
    assert code == EXIT_OK, err
    assert "--report: no overlay of the 8 of 8 views whose images are not at the paths the corners file names" in err
    assert (report / "index.html").is_file() and not list((report / "views").iterdir())


@pytest.mark.parametrize(
    "change, phrases",
    [
        (["--board", "5x4"], ["its corners are of a 6x4 chessboard, not the 5x4 chessboard of --board"]),
        (["--charuco", "7x5", "--marker", "0.01"], ["6x4 chessboard, not the 7x5 ChArUco board"]),
        (["IMAGES"], ["give either images or --corners, not both"]),
        (["--save-frames", "DIR", "--select"], ["--save-frames reads images or recordings"]),
        (["--image-size", "320"], ["--image-size 320: expected WIDTHxHEIGHT"]),
        (["--image-topics", "/cam0/image_raw"], ["--image-topics reads images or recordings"]),
    ],
)
def test_refusals_are_one_line_and_write_nothing(stereo_files, tmp_path, capsys, change, phrases):
    _, folders, files = stereo_files
    out = tmp_path / "camera.json"
    argv = ["calibrate", "--corners", files[0], "--square", "0.025", *FAST, "--output", out]
    if "--board" not in change and "--charuco" not in change:
        argv += ["--board", "6x4"]
    argv += [str(folders[0]) if a == "IMAGES" else str(tmp_path / "dir") if a == "DIR" else a for a in change]
    code, _, err = run(capsys, *argv)
    assert_refused(code, err, out, *phrases)


def test_files_that_are_not_corners_are_refused(stereo_files, tmp_path, capsys):
    _, folders, files = stereo_files
    calibration = tmp_path / "camera.json"
    assert run(capsys, "calibrate", folders[0], *RIG, "--output", calibration)[0] == EXIT_OK
    out = tmp_path / "again.json"
    code, _, err = run(capsys, "calibrate", "--corners", calibration, *RIG, "--output", out)
    assert_refused(code, err, out, f"--corners {calibration}: a calibration, not the corners file detect writes")
    rig = tmp_path / "rig.json"
    code, _, err = run(capsys, "calibrate-rig", "--corners", files[0], *RIG, "--output", rig)
    assert_refused(code, err, rig, "a rig needs at least two --corners files (one per camera), got 1")
    code, _, err = run(capsys, "calibrate-rig", "--corners", files[0], "--corners", files[0], *RIG, "--output", rig)
    assert_refused(code, err, rig, "is given twice: one corners file per camera")
    code, _, err = run(capsys, "calibrate", *RIG, "--output", out)
    assert_refused(code, err, out, "no images given")


def test_mrcal_vnl_calibrates_with_image_size(tmp_path, capsys):
    import torch

    from ccs_kornia.geometry.board_points import board_object_points
    from ccs_kornia.geometry.camera import project_points
    from ccs_kornia.geometry.board_warp import warped_board

    # a bent board (mrcal's sag, -1 / +0.5 mm), as mrgingham would list its corners
    obj = warped_board(board_object_points(6, 5, 0.03, dtype=torch.float64),
                       torch.tensor([-0.001, 0.0005], dtype=torch.float64))
    K = torch.tensor([[600.0, 0, 330], [0, 605, 235], [0, 0, 1]], dtype=torch.float64)
    g = torch.Generator().manual_seed(1)
    rvec = 0.5 * (torch.rand(10, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.08, -0.06, 0.4], dtype=torch.float64) + 0.03 * torch.rand(10, 3, generator=g,
                                                                                         dtype=torch.float64)
    uv = project_points(obj.expand(10, -1, -1), K.expand(10, 3, 3), None, rvec, tvec)
    lines = ["# filename x y level"]
    for v in range(10):
        lines += [f"frame{v:03d}.jpg {x:.4f} {y:.4f} 0" for x, y in uv[v].tolist()]
    lines.append("frame010.jpg - -")
    vnl, out = tmp_path / "corners.vnl", tmp_path / "calib.json"
    vnl.write_text("\n".join(lines) + "\n")
    code, _, err = run(capsys, "calibrate", "--corners", vnl, "--board", "6x5", "--square", "0.03", "--model",
                       "k1k2", "--output", out)
    assert_refused(code, err, out, "--image-size")
    code, printed, err = run(capsys, "calibrate", "--corners", vnl, "--board", "6x5", "--square", "0.03", "--model",
                             "k1k2", "--image-size", "640x480", "--output", out)
    assert code == EXIT_OK, err
    assert "board: bent by -1.000 / +0.500 mm" in printed and ", kept (held-out median" in printed
    assert "board in 10 of 11 views of 640x480 images" in err
    result = json.loads(out.read_text())
    assert result["image_size"] == [640, 480] and result["rms"] < 1e-3
    assert abs(result["K"][0][0] - 600) < 0.05 and abs(result["K"][1][2] - 235) < 0.05
    flatness = result["board_flatness"]
    assert flatness["kept"] and flatness["heldout_median_px"]["warp"] < 0.1 * flatness["heldout_median_px"]["flat"]
    assert [round(w * 1000, 3) for w in flatness["warp_m"]] == [-1.0, 0.5]
    code, _, err = run(capsys, "calibrate", "--corners", vnl, "--board", "6x5", "--square", "0.03", "--model",
                       "k1k2", "--image-size", "640x480", "--flat-board", "--output", out)
    flat = json.loads(out.read_text())
    assert code == EXIT_OK and "board_flatness" not in flat and flat["rms"] > 100 * result["rms"]


def test_model_splined_fits_the_spline_outright(tmp_path, capsys):
    import torch

    from ccs_kornia.geometry.board_points import board_object_points
    from ccs_kornia.geometry.camera import Camera
    from ccs_kornia.geometry.models import SplinedStereographicModel
    from ccs_kornia.geometry.so3 import exp_so3

    # a stereographic lens with a local bump of a few px, which no OpenCV model fits
    lens = SplinedStereographicModel(8, 6, 120)
    x = (torch.arange(lens.nx, dtype=torch.float64) - (lens.nx - 1) / 2) / lens.segments_per_u
    y = (torch.arange(lens.ny, dtype=torch.float64) - (lens.ny - 1) / 2) / lens.segments_per_u
    u = torch.stack(torch.meshgrid(y, x, indexing="ij")[::-1], -1)
    bump = 0.01 * torch.exp(-((u - torch.tensor([0.2, 0.1], dtype=torch.float64)) ** 2).sum(-1, keepdim=True) / 0.05)
    knots = -0.1 * (u * u).sum(-1, keepdim=True) * u + bump
    truth = Camera(lens, torch.cat([torch.tensor([400.0, 400, 320, 240], dtype=torch.float64), knots.reshape(-1)]),
                   (640, 480))
    obj = board_object_points(8, 6, 0.03, dtype=torch.float64)
    g = torch.Generator().manual_seed(4)
    V = 8
    R = exp_so3(0.8 * (torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5))
    centre = torch.stack([0.4 * (torch.rand(V, generator=g, dtype=torch.float64) - 0.5),
                          0.3 * (torch.rand(V, generator=g, dtype=torch.float64) - 0.5),
                          0.3 + 0.1 * torch.rand(V, generator=g, dtype=torch.float64)], -1)
    uv = truth.project((obj @ R.transpose(-1, -2) + (centre - R @ obj.mean(0))[:, None])[None])[0]
    lines = ["# filename x y level"]
    for v in range(V):
        lines += [f"frame{v:03d}.jpg {x:.4f} {y:.4f} 0" if 0 < x < 639 and 0 < y < 479 else f"frame{v:03d}.jpg - -"
                  for x, y in uv[v].tolist()]
    vnl, out = tmp_path / "corners.vnl", tmp_path / "calib.json"
    vnl.write_text("\n".join(lines) + "\n")
    code, printed, err = run(capsys, "calibrate", "--corners", vnl, "--board", "8x6", "--square", "0.03", "--image-size",
                             "640x480", "--model", "splined", "--flat-board", "--no-ransac", "--no-diagnostics",
                             "--output", out)
    assert code == EXIT_OK, err
    assert " asked for, from " in printed and "control-point values)" in printed  # not hundreds of numbers
    result = json.loads(out.read_text())
    model = result["distortion"]["model"]
    assert model.startswith("splined_stereographic") and result["rms"] < 0.05, (model, result["rms"])
    table = result["model_selection"]
    assert table["chosen"] == model and table["splined"]["kept"]
    assert "asked for (--model splined)" in table["splined"]["rule"]
