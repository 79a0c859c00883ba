"""``calibrate-rig`` and ``rectify`` on the command line: every output file, every bad input, and the real
Bumblebee2 stereo pair against BoofCV's published calibration."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import stat
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from _real_data import REAL_DATA
from _rig_images import ANGLE_DEG, T_REL, render_stereo, write_stereo

from ccs_kornia import cli
from ccs_kornia.commands import calibrate_rig
from ccs_kornia.geometry.models import RATIONAL
from ccs_kornia.io.images import write_image
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.runtime.errors import UserError

FAST = ["--board", "6x4", "--square", "0.025", "--detector", "opencv", "--no-distortion-correction", "--model", "k1k2",
        "--jobs", "1", "--no-ransac"]


def _no_work(*args, **kwargs):
    raise AssertionError("the command started its work before checking its input")


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, *phrases: str, status: int = 2) -> None:
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == status and len(lines) == 1, err
    assert "Traceback" not in err
    for phrase in phrases:
        assert phrase in lines[0], err


@pytest.fixture(scope="module")
def stereo():
    return render_stereo(frames=8, seed=3)


@pytest.fixture(scope="module")
def rig_run(stereo, tmp_path_factory):
    """One run writing every output: the right camera misses frame 08, the cameras' image sizes differ."""
    root = tmp_path_factory.mktemp("rig")
    left, right = write_stereo(stereo, root, frames=[list(range(8)), list(range(7))])
    out = root / "out"
    out.mkdir()
    argv = ["calibrate-rig", left, right, *FAST, "--names", "left,right", "--output", out / "rig.json",
            "--opencv-yaml", out / "stereo.yml", "--ros-yaml-dir", out / "ros", "--kalibr-yaml", out / "camchain.yaml",
            "--report", out / "report"]
    code = cli.main([str(a) for a in argv])
    return code, root, out


def test_rig_json(rig_run, capsys):
    code, root, out = rig_run
    assert code == 0
    data = json.loads((out / "rig.json").read_text())
    assert stat.S_IMODE(os.stat(out / "rig.json").st_mode) == 0o644
    assert data["convention"] == "x_i = R x_0 + T"
    assert [c["name"] for c in data["cameras"]] == ["left", "right"]
    assert [c["image_size"] for c in data["cameras"]] == [[320, 240], [352, 264]]
    for cam in data["cameras"]:  # each camera as calibrate writes one
        assert {"K", "distortion", "rms", "views", "std", "num_views", "single_camera"} <= set(cam)
        assert cam["distortion"]["model"] == "k1k2"
    ext = data["extrinsics"]
    assert np.allclose(ext[0]["R"], np.eye(3)) and np.allclose(ext[0]["T"], 0)
    assert abs(np.linalg.norm(ext[1]["T"]) - float(T_REL.norm())) < 0.01 * float(T_REL.norm())
    assert np.allclose(np.array(ext[1]["T"]), T_REL.numpy(), atol=2e-3)
    assert len(data["rms_matrix"]) == 2 and len(data["rms_matrix"][0]) == 8
    assert data["rms_matrix"][1][7] is None and data["rms_matrix"][0][7] is not None
    assert data["frame_labels"] == [f"{k:02d}" for k in range(1, 9)]
    assert data["frames"][1][7] is None and data["frames"][1][0].endswith("right01.png")
    pair = data["pairs"][0]
    assert pair["cameras"] == [0, 1]
    assert {"R", "T", "E", "F", "baseline", "baseline_std", "rotation_std_deg", "epipolar_rms",
            "heldout_epipolar_rms"} <= set(pair)
    assert abs(pair["rotation_deg"] - ANGLE_DEG) < 0.1 and pair["epipolar_rms"] < 0.5
    assert isinstance(data["verdict"], str) and data["verdict"]
    order = np.array(data["fit"]["corner_order"])
    assert order.shape == (2, 8) and set(order.ravel().tolist()) <= {0, 1}
    assert np.array(data["fit"]["frames_used"]).shape == (2, 8) and data["fit"]["converged"]
    assert data["fit"]["status"] == "converged"


def test_opencv_stereo_yaml_loads_and_rectifies(rig_run):
    _, _, out = rig_run
    data = json.loads((out / "rig.json").read_text())
    fs = cv2.FileStorage(str(out / "stereo.yml"), cv2.FILE_STORAGE_READ)
    m = {k: fs.getNode(k).mat() for k in ("K1", "D1", "K2", "D2", "R", "T", "E", "F", "R1", "R2", "P1", "P2", "Q")}
    size = (int(fs.getNode("image_width1").real()), int(fs.getNode("image_height1").real()))
    fs.release()
    assert size == (320, 240) and m["Q"].shape == (4, 4) and m["P2"].shape == (3, 4) and m["D1"].size == 5
    for K, D, R, P in ((m["K1"], m["D1"], m["R1"], m["P1"]), (m["K2"], m["D2"], m["R2"], m["P2"])):
        mx, my = cv2.initUndistortRectifyMap(K, D, R, P, size, cv2.CV_32FC1)
        assert mx.shape == (240, 320) and np.isfinite(mx).all()
    # the same board corner lands on the same row in both rectified images
    views = [{v["path"]: v for v in cam["views"]} for cam in data["cameras"]]
    rows = []
    for f in range(7):
        a, b = (np.array(views[c][data["frames"][c][f]]["corners"], dtype=np.float64) for c in (0, 1))
        ra = cv2.undistortPoints(a[:, None], m["K1"], m["D1"], R=m["R1"], P=m["P1"])[:, 0]
        rb = cv2.undistortPoints(b[:, None], m["K2"], m["D2"], R=m["R2"], P=m["P2"])[:, 0]
        rows.append(ra[:, 1] - rb[:, 1])
    assert np.sqrt(np.mean(np.concatenate(rows) ** 2)) < 0.5


def test_ros_yaml_files(rig_run):
    _, _, out = rig_run
    data = json.loads((out / "rig.json").read_text())
    left = yaml.safe_load((out / "ros" / "left.yaml").read_text())
    right = yaml.safe_load((out / "ros" / "right.yaml").read_text())
    for info, cam in ((left, data["cameras"][0]), (right, data["cameras"][1])):
        assert {"image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                "distortion_coefficients", "rectification_matrix", "projection_matrix"} <= set(info)
        assert [info["image_width"], info["image_height"]] == cam["image_size"]
        assert info["distortion_model"] == "plumb_bob" and len(info["distortion_coefficients"]["data"]) == 5
    assert left["camera_name"] == "left" and right["camera_name"] == "right"
    P = np.array(right["projection_matrix"]["data"]).reshape(3, 4)
    assert P[0, 3] == pytest.approx(-P[0, 0] * data["pairs"][0]["baseline"], rel=1e-6)
    assert np.array(left["projection_matrix"]["data"]).reshape(3, 4)[0, 3] == 0.0


def test_kalibr_camchain(rig_run):
    _, _, out = rig_run
    data = json.loads((out / "rig.json").read_text())
    chain = yaml.safe_load((out / "camchain.yaml").read_text())
    assert sorted(chain) == ["cam0", "cam1"]
    for c, name in enumerate(("cam0", "cam1")):
        cam = chain[name]
        K = data["cameras"][c]["K"]
        assert cam["camera_model"] == "pinhole" and cam["distortion_model"] == "radtan"
        assert cam["intrinsics"] == pytest.approx([K[0][0], K[1][1], K[0][2], K[1][2]])
        assert cam["resolution"] == data["cameras"][c]["image_size"] and len(cam["distortion_coeffs"]) == 4
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    assert T.shape == (4, 4) and "T_cn_cnm1" not in chain["cam0"]
    assert np.allclose(T[:3, :3], data["pairs"][0]["R"], atol=1e-9) and np.allclose(T[:3, 3], data["pairs"][0]["T"])


def test_report_figures(rig_run):
    _, _, out = rig_run
    for name in ("index.html", "error_matrix.png", "rectified_pair.png", "rig_top_view.png"):
        assert (out / "report" / name).is_file(), name
    assert cv2.imread(str(out / "report" / "rectified_pair.png")).shape[1] == 2 * 320 + 6


def test_summary_and_missing_frames_info(stereo, tmp_path, capsys):
    left, right = write_stereo(stereo, tmp_path, frames=[list(range(8)), [0, 1, 2, 4, 5, 6]])
    code, out, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json")
    assert code == 0, err
    assert "camera cam1 has no view of frames 04, 08 (6 of 8 frames)" in err
    assert "camera cam0: k1k2, RMS" in out and "pair cam0-cam1: baseline 0.04" in out and "verdict:" in out


def test_console_says_the_joint_fit_did_not_converge(rig_run):
    from ccs_kornia.commands.calibrate_rig import summary_lines

    _, _, out = rig_run
    data = json.loads((out / "rig.json").read_text())
    assert not any("did not converge" in line for line in summary_lines(data, "rig.json"))
    data["fit"].update(converged=False, iterations=100)
    lines = summary_lines(data, "rig.json")
    assert "the joint fit did not converge in 100 iterations" in lines[-2] and lines[-1].startswith("verdict:")


def test_undistort_names_a_rig_file_and_takes_one_of_its_cameras(rig_run, tmp_path, capsys):
    _, root, out = rig_run
    code, _, err = run(capsys, "undistort", root / "right", "--calibration", out / "rig.json", "--out-dir",
                       tmp_path / "und")
    assert_one_line_error(code, err, "a rig calibration written by calibrate-rig (cameras left, right)", "rectify",
                          "--camera NAME")
    assert not (tmp_path / "und").exists()
    code, stdout, err = run(capsys, "undistort", root / "right", "--calibration", out / "rig.json", "--camera",
                            "right", "--out-dir", tmp_path / "und")
    assert code == 0 and "undistorted 7 of 7 images" in stdout, err
    assert cv2.imread(str(tmp_path / "und" / "right01.png")).shape[:2] == (264, 352)
    code, _, err = run(capsys, "undistort", root / "right", "--calibration", out / "rig.json", "--camera", "2",
                       "--out-dir", tmp_path / "und")
    assert_one_line_error(code, err, "--camera 2", "left, right")


def test_fix_intrinsics_names_a_failed_calibration(stereo, tmp_path, capsys):
    left, right = write_stereo(stereo, tmp_path)
    failed = tmp_path / "calib.failed.json"
    failed.write_text(json.dumps({"success": False, "error": "board 6x4 not found in any of 8 images"}))
    code, _, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json",
                       "--fix-intrinsics", f"1={failed}")
    assert_one_line_error(code, err, "is a failed calibration", "board 6x4 not found in any of 8 images")
    assert "not a calibration written by calibrate" not in err
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"cameras": [{"name": "left"}, {"name": "right"}], "extrinsics": []}))
    code, _, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "out.json",
                       "--fix-intrinsics", f"1={rig}")
    assert_one_line_error(code, err, "a rig calibration written by calibrate-rig (cameras left, right)",
                          "give a calibration written by calibrate")


def test_wrong_board_is_named_early(stereo, tmp_path, capsys):
    left, right = write_stereo(stereo, tmp_path)
    argv = [a if a != "6x4" else "7x5" for a in FAST]
    code, _, err = run(capsys, "calibrate-rig", left, right, *argv, "--batch-size", "6", "--output",
                       tmp_path / "rig.json")
    assert_one_line_error(code, err, "camera cam0: board 7x5 not found in the first 6 images, but a 6x4 board")
    assert not (tmp_path / "rig.json").exists()


def test_a_folder_of_non_images_is_said_first(stereo, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(calibrate_rig, "RigPipeline", _no_work)
    left, _ = write_stereo(stereo, tmp_path)
    junk = tmp_path / "junk"
    junk.mkdir()
    for k in range(3):
        (junk / f"junk{k + 1:02d}.png").write_text("not an image")
    code, _, err = run(capsys, "calibrate-rig", left, junk, *FAST, "--output", tmp_path / "rig.json")
    assert_one_line_error(code, err, "camera cam1", "none of the 3 files")
    assert err.splitlines()[0].startswith("ccs_kornia calibrate-rig: error:"), err  # no frame-matching lines first


def test_rectify_command(rig_run, capsys):
    _, root, out = rig_run
    code, stdout, err = run(capsys, "rectify", root / "left", root / "right", "--calibration", out / "rig.json",
                            "--out-dir", out / "rect", "--alpha", "0.5")
    assert code == 0, err
    assert "rectified 7 of 7 pairs" in stdout
    assert sorted(os.listdir(out / "rect"))[:2] == ["left01_rect.png", "left02_rect.png"]
    assert cv2.imread(str(out / "rect" / "right01_rect.png")).shape[:2] == (240, 320)
    code, _, err = run(capsys, "rectify", root / "left", root / "right", "--calibration", root / "left" / "left01.png",
                       "--out-dir", out / "rect2")
    assert_one_line_error(code, err, "not a readable JSON file")


def test_rectify_refuses_swapped_folders(rig_run, tmp_path, capsys):
    """The folders in the wrong order rectify each image with the other camera's model: refused, whether the folders
    are the calibration's own or copies elsewhere (the file names say which camera)."""
    _, root, out = rig_run
    code, _, err = run(capsys, "rectify", root / "right", root / "left", "--calibration", out / "rig.json",
                       "--out-dir", tmp_path / "rect")
    assert_one_line_error(code, err, "camera right's images", "camera left's", "swap")
    assert not (tmp_path / "rect").exists()
    for name, source in (("first", "right"), ("second", "left")):  # copies, swapped again
        shutil.copytree(root / source, tmp_path / name)
    code, _, err = run(capsys, "rectify", tmp_path / "first", tmp_path / "second", "--calibration", out / "rig.json",
                       "--out-dir", tmp_path / "rect")
    assert_one_line_error(code, err, "camera right's images", "swap")
    code, _, err = run(capsys, "rectify", tmp_path / "first", tmp_path / "second", "--calibration", out / "rig.json",
                       "--out-dir", tmp_path / "rect", "--pair", "1,0")
    assert code == 0, err  # in the order of the pair asked for


def test_the_same_camera_twice_is_refused(stereo, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(calibrate_rig, "RigPipeline", _no_work)
    left, _ = write_stereo(stereo, tmp_path)
    code, _, err = run(capsys, "calibrate-rig", left, left, *FAST, "--output", tmp_path / "rig.json")
    assert_one_line_error(code, err, "cameras cam0 and cam1", "the same images")
    shutil.copytree(left, tmp_path / "copy")
    code, _, err = run(capsys, "calibrate-rig", left, tmp_path / "copy", *FAST, "--output", tmp_path / "rig.json")
    assert_one_line_error(code, err, "cameras cam0 and cam1", "the same images")
    assert not (tmp_path / "rig.json").exists()


def test_three_cameras(tmp_path, capsys):
    from _rig_images import R_THIRD, T_THIRD

    rig = render_stereo(frames=8, seed=4, third=True)
    dirs = write_stereo(rig, tmp_path, names=("a", "b", "c"), pattern="frame_{k:04d}.png")
    code, out, err = run(capsys, "calibrate-rig", *dirs, *FAST, "--output", tmp_path / "rig.json", "--kalibr-yaml",
                         tmp_path / "chain.yaml", "--opencv-yaml", tmp_path / "s.yml", "--ros-yaml-dir",
                         tmp_path / "ros", "--report", tmp_path / "report", "--pair", "0,2")
    assert code == 0, err
    assert "hold the pair cam0-cam2" in err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert [p["cameras"] for p in data["pairs"]] == [[0, 1], [0, 2], [1, 2]]
    assert data["pairs"][2]["baseline_std"] is None and data["pairs"][1]["baseline_std"] is not None
    assert np.allclose(data["extrinsics"][2]["T"], T_THIRD.numpy(), atol=2e-3)
    assert abs(data["pairs"][1]["rotation_deg"] - math.degrees(float(cv2.Rodrigues(R_THIRD.numpy())[0].ravel()[0]))) < 0.1
    chain = yaml.safe_load((tmp_path / "chain.yaml").read_text())
    assert sorted(chain) == ["cam0", "cam1", "cam2"] and "T_cn_cnm1" in chain["cam2"]
    assert out.count("pair ") == 3
    # the stereo files and the report hold the pair asked for; the ROS files are named after its cameras
    fs = cv2.FileStorage(str(tmp_path / "s.yml"), cv2.FILE_STORAGE_READ)
    K2, T = fs.getNode("K2").mat(), fs.getNode("T").mat()
    fs.release()
    assert np.allclose(K2, data["cameras"][2]["K"]) and np.allclose(T.ravel(), data["pairs"][1]["T"])
    assert sorted(os.listdir(tmp_path / "ros")) == ["cam0.yaml", "cam2.yaml"]
    assert yaml.safe_load((tmp_path / "ros" / "cam2.yaml").read_text())["camera_name"] == "cam2"
    assert "a rectified pair (cam0, cam2)" in (tmp_path / "report" / "index.html").read_text()


def test_stereo_files_of_a_larger_rig_need_the_pair(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(calibrate_rig, "RigPipeline", _no_work)
    for name in ("a", "b", "c"):
        (tmp_path / name).mkdir()
        assert write_image(tmp_path / name / f"{name}01.png", np.full((48, 64), float(ord(name)) / 255, np.float32))
    dirs = [tmp_path / name for name in ("a", "b", "c")]
    for option in ("--opencv-yaml", "--ros-yaml-dir"):
        code, _, err = run(capsys, "calibrate-rig", *dirs, *FAST, "--output", tmp_path / "rig.json", option,
                           tmp_path / "stereo")
        assert_one_line_error(code, err, f"{option} holds one pair of the 3 cameras", "--pair I,J")
    code, _, err = run(capsys, "calibrate-rig", *dirs, *FAST, "--output", tmp_path / "rig.json", "--pair", "0,3")
    assert_one_line_error(code, err, "--pair 0,3")


# ----------------------------------------------------------------------------------------------
# bad input: one line, exit status 2, nothing written
# ----------------------------------------------------------------------------------------------


def test_fewer_than_two_cameras(stereo, tmp_path, capsys):
    left, _ = write_stereo(stereo, tmp_path)
    code, _, err = run(capsys, "calibrate-rig", left, *FAST, "--output", tmp_path / "rig.json")
    assert_one_line_error(code, err, "at least two camera folders")
    assert not (tmp_path / "rig.json").exists()


def test_camera_without_board(stereo, tmp_path, capsys):
    left, _ = write_stereo(stereo, tmp_path)
    blank = tmp_path / "blank"
    blank.mkdir()
    for k in range(4):
        assert write_image(blank / f"blank{k + 1:02d}.png", np.full((240, 320), 0.5, np.float32))
    code, _, err = run(capsys, "calibrate-rig", left, blank, *FAST, "--output", tmp_path / "rig.json",
                       "--opencv-yaml", tmp_path / "s.yml")
    # images read, no board in them: a run without a result (exit 3), as for one camera
    assert_one_line_error(code, err, "camera cam1", "board 6x4 not found", status=3)
    assert not (tmp_path / "rig.json").exists() and not (tmp_path / "s.yml").exists()


def test_cameras_sharing_no_frame(stereo, tmp_path, capsys):
    left, right = write_stereo(stereo, tmp_path, frames=[[0, 1, 2, 3], [4, 5, 6, 7]])
    code, _, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json",
                       "--kalibr-yaml", tmp_path / "c.yaml")
    assert_one_line_error(code, err, "camera cam1 shares no frame with camera cam0", "cam0 sees frames 01, 02, 03, 04",
                          "cam1: 05, 06, 07, 08")
    assert not (tmp_path / "rig.json").exists() and not (tmp_path / "c.yaml").exists()


def test_camera_of_copied_views(stereo, tmp_path, capsys):
    left, right = write_stereo(stereo, tmp_path)
    for k in range(2, 9):  # every right view a copy of the first
        shutil.copy(right / "right01.png", right / f"right{k:02d}.png")
    code, _, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json")
    assert_one_line_error(code, err, "camera cam1", "copies", status=3)  # as calibrate: images read, no result
    assert not (tmp_path / "rig.json").exists()


@pytest.mark.parametrize("extra, phrase", [
    (["--model", "k1k2,k1k2,k1k2"], "3 models for 2 cameras"),
    (["--model", "pinhole"], "unknown model 'pinhole'"),
    (["--names", "a"], "1 name for 2 camera folders"),
    (["--names", "a,a"], "names must be distinct"),
    (["--fix-intrinsics", "5=x.json"], "camera index 5 out of range"),
    (["--fix-intrinsics", "0=/nonexistent/x.json"], "cannot read"),
    (["--opencv-yaml", "/nonexistent/dir/s.yml"], "does not exist"),
    (["--ros-yaml-dir", "/proc/ros"], "cannot write in /proc"),
    (["--report", "/proc/report"], "cannot write in /proc"),
    (["--model", "rational", "--kalibr-yaml", "camchain.yaml"], "Kalibr has no rational"),
])
def test_bad_options_stop_before_any_work(tmp_path, capsys, extra, phrase):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
    argv = ["calibrate-rig", tmp_path / "a", tmp_path / "b", *FAST, "--output", tmp_path / "rig.json"]
    code, _, err = run(capsys, *argv, *extra)
    assert_one_line_error(code, err, phrase)
    assert not (tmp_path / "rig.json").exists()


def test_kalibr_with_auto_leaves_rational_out_of_the_candidates(tmp_path, capsys, monkeypatch):
    """Kalibr has no rational model: with --model auto the run chooses among the others (and says so) instead of
    stopping after all the work."""
    seen = {}

    def fake(detector, models, fixed, **options):
        seen.update(options, models=models)
        raise UserError("stopped before the work")

    monkeypatch.setattr(calibrate_rig, "RigPipeline", fake)
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        assert write_image(tmp_path / name / f"{name}01.png", np.full((48, 64), float(ord(name)) / 255, np.float32))
    argv = ["calibrate-rig", tmp_path / "a", tmp_path / "b", "--board", "6x4", "--detector", "opencv",
            "--no-distortion-correction", "--jobs", "1", "--output", tmp_path / "rig.json", "--kalibr-yaml",
            tmp_path / "chain.yaml"]
    assert cli.main([str(a) for a in [*argv, "--model", "auto,k1k2"]]) == 2
    assert [str(m) for m in seen["models"]] == ["auto", "k1k2"] and RATIONAL not in seen["models"][0].candidates
    assert "Kalibr has no rational model, so --model auto chooses among k1k2, opencv5, fisheye" in \
        capsys.readouterr().err
    seen.clear()
    assert cli.main([str(a) for a in argv[:-2] + ["--model", "auto"]]) == 2
    assert seen["models"] == [ModelChoice()] * 2  # without a camchain: every candidate


def test_allow_weak_calibrates_a_weak_rig_as_not_reliable(tmp_path, capsys):
    """Boards nearly parallel to camera 0: refused (saying --allow-weak would calibrate it); with --allow-weak the
    rig is solved and its verdict is not reliable, naming the camera and the check."""
    weak = render_stereo(frames=6, seed=5, max_tilt_deg=2.0)
    left, right = write_stereo(weak, tmp_path)
    code, _, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json")
    assert_one_line_error(code, err, "camera cam0", "nearly parallel", "--allow-weak calibrates anyway",
                          status=3)  # as calibrate: a weak camera is a run without a result
    code, out, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json",
                         "--allow-weak")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert data["allow_weak"] and data["verdict"].startswith("not reliable: cam0: tilt the board more")
    assert any(r.startswith("cam0: the board planes of all views are nearly parallel") for r in data["verdict_reasons"])
    assert "camera cam0: calibrated with --allow-weak although the board planes" in err
    assert "verdict: not reliable: cam0: tilt the board more" in out and "camera cam0: 1-sigma of the intrinsics" in out


def test_fixed_intrinsics_from_a_calibrate_json(stereo, tmp_path, capsys):
    left, right = write_stereo(stereo, tmp_path)
    code, _, err = run(capsys, "calibrate", left, *FAST, "--output", tmp_path / "left.json")
    assert code == 0, err
    code, out, err = run(capsys, "calibrate-rig", left, right, *FAST, "--output", tmp_path / "rig.json",
                         "--fix-intrinsics", f"0={tmp_path / 'left.json'}")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert data["cameras"][0]["fixed"] and not data["cameras"][1]["fixed"]
    assert np.allclose(data["cameras"][0]["K"], json.loads((tmp_path / "left.json").read_text())["K"])
    assert "intrinsics fixed" in out


# ----------------------------------------------------------------------------------------------
# the real stereo pair
# ----------------------------------------------------------------------------------------------

BUMBLEBEE = [REAL_DATA / "boofcv_bumblebee2_left", REAL_DATA / "boofcv_bumblebee2_right"]


@pytest.mark.skipif(not all(p.is_dir() for p in BUMBLEBEE), reason=f"real stereo pair not found under {REAL_DATA}")
def test_bumblebee2_baseline_against_boofcv(tmp_path, capsys):
    ref = yaml.safe_load((BUMBLEBEE[0] / "reference" / "stereo.yaml").read_text())
    rot = np.array(ref["rightToLeft"]["rotation"], dtype=np.float64).reshape(3, 3)
    t_mm = np.array([ref["rightToLeft"][k] for k in "xyz"], dtype=np.float64)
    # BoofCV gives right -> left; the rig's pair is left -> right: R = rot^T, T = -rot^T t
    R_ref, T_ref = rot.T, -rot.T @ t_mm / 1000.0
    code, out, err = run(capsys, "calibrate-rig", *BUMBLEBEE, "--board", "4x6", "--square", "0.03", "--jobs", "1",
                         "--names", "left,right", "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    pair = data["pairs"][0]
    assert pair["baseline"] == pytest.approx(float(np.linalg.norm(T_ref)), rel=0.015)
    R = np.array(pair["R"])
    difference = math.degrees(math.acos(np.clip((np.trace(R @ R_ref.T) - 1) / 2, -1, 1)))
    # the relative rotation trades against the principal points (BoofCV's right cx is 3 px larger: 0.33 deg about the
    # vertical axis; its cy 2.6 px closer together: 0.28 deg about the horizontal one); cv2.stereoCalibrate on the
    # same corners lands between the two
    assert difference < 0.6
    assert pair["epipolar_rms"] < 0.5
    # docs/rig.md's table says which model --model auto gives each camera of this run
    table = (Path(__file__).resolve().parents[2] / "docs" / "rig.md").read_text(encoding="utf-8")
    said = re.search(r"calibrate-rig, `--model auto` \(([^)]*)\)", table).group(1)
    models = [cam["distortion"]["model"] for cam in data["cameras"]]
    assert said == (f"{models[0]} for both cameras" if models[0] == models[1] else
                    f"left {models[0]}, right {models[1]}"), said
