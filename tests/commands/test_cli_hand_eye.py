"""``calibrate-hand-eye`` on the command line: a single AprilTag with a given camera, a chessboard with the camera
calibrated from the same images, every output file (handeye.json, the ROS launch file, easy_handeye's YAML, the
report), each pose form, and every refusal (mispaired, swapped and wrongly scaled poses, missing options) as one line
with exit status 2."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import yaml
from _hand_eye_images import board_scene, tag_scene, write_poses

from ccs_kornia import cli
from ccs_kornia.geometry.so3 import log_so3


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *phrases):
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for phrase in phrases:
        assert phrase in lines[0], lines[0]
    return lines[0]


def x_error(data, X):
    got = torch.tensor(data["X"], dtype=torch.float64)
    return (1000 * float((got[:3, 3] - X[:3, 3]).norm()),
            math.degrees(float(log_so3(got[:3, :3] @ X[:3, :3].T).norm())))


@pytest.fixture(scope="module")
def tags(tmp_path_factory):
    root = tmp_path_factory.mktemp("tags")
    return tag_scene("eye_to_hand", 10, 21, str(root / "images"))


def _tag_args(tags, poses, out):
    return ["calibrate-hand-eye", *tags["files"], "--robot-poses", poses, "--eye-to-hand", "--apriltag", "36h11",
            "--tag-size", "0.1", "--calibration", tags["calibration"], "--output", out]


def test_apriltag_every_output(tags, tmp_path, capsys):
    poses = write_poses(str(tmp_path / "poses.csv"), tags["files"], tags["scene"].robot_poses)
    out = tmp_path / "handeye.json"
    code, stdout, err = run(capsys, *_tag_args(tags, poses, out), "--ros-tf", tmp_path / "tf.launch",
                            "--moveit-yaml", tmp_path / "he.yaml", "--ros-frames", "base,flange,cam",
                            "--report", tmp_path / "report")
    assert code == 0, err
    data = json.loads(out.read_text())
    t_mm, r_deg = x_error(data, tags["X"])
    assert t_mm < 3.0 and r_deg < 0.3 and data["success"] and data["setup"] == "eye-to-hand"
    for key in ("X", "X_tq", "X_std", "board_in_robot", "board_in_robot_std", "camera", "heldout", "poses", "verdict"):
        assert key in data
    q = data["X_tq"]["q"]
    assert abs(np.linalg.norm(q) - 1) < 1e-9 and data["X_tq"]["t"] == [row[3] for row in data["X"][:3]]
    assert data["heldout"]["rms_px"] < 2.0 and data["heldout"]["poses"] == 10
    assert len(data["poses"]) == 10 and all(len(p["residuals_px"]) == 4 for p in data["poses"])
    assert data["X_std"]["translation_mm_norm"] > 0 and data["camera"]["source"] == tags["calibration"]
    launch = (tmp_path / "tf.launch").read_text()
    assert "static_transform_publisher" in launch and " base cam\"" in launch
    he = yaml.safe_load((tmp_path / "he.yaml").read_text())
    assert he["eye_on_hand"] is False and he["robot_base_frame"] == "base" and he["tracking_base_frame"] == "cam"
    assert [he["transformation"][k] for k in ("x", "y", "z")] == pytest.approx(data["X_tq"]["t"])
    assert (tmp_path / "report" / "index.html").is_file() and (tmp_path / "report" / "pose_000.png").is_file()
    assert "held-out poses predicted from the robot alone" in stdout and "verdict:" in stdout


@pytest.mark.parametrize("form", ["quat", "matrix"])
def test_every_pose_form_and_millimetres(tags, tmp_path, capsys, form):
    poses = write_poses(str(tmp_path / "poses.csv"), tags["files"], tags["scene"].robot_poses, form, 1000.0,
                        header=False)
    out = tmp_path / "handeye.json"
    code, _, err = run(capsys, *_tag_args(tags, poses, out), "--pose-units", "mm", "--pose-format", form)
    assert code == 0, err
    assert x_error(json.loads(out.read_text()), tags["X"])[0] < 3.0


def test_a_missing_and_an_extra_pose_are_reported_never_shifted(tags, tmp_path, capsys):
    files = tags["files"]
    rows = write_poses(str(tmp_path / "poses.csv"), files, tags["scene"].robot_poses)
    with open(rows, encoding="utf-8") as handle:
        text = handle.read().splitlines()
    del text[4]  # view_03 has no pose
    text.append("not_an_image.png," + text[1].split(",", 1)[1])
    (tmp_path / "poses.csv").write_text("\n".join(text) + "\n")
    code, _, err = run(capsys, *_tag_args(tags, tmp_path / "poses.csv", tmp_path / "he.json"))
    assert code == 0, err
    assert "skipped" in err and "view_03.png: no robot pose" in err and "not_an_image.png matches no image" in err
    data = json.loads((tmp_path / "he.json").read_text())
    view = next(p for p in data["poses"] if p["path"].endswith("view_03.png"))
    assert view["used"] is False and "no robot pose" in view["reason"]
    assert x_error(data, tags["X"])[0] < 3.0


def test_mispaired_and_wrongly_scaled_poses_are_refused(tags, tmp_path, capsys):
    T = tags["scene"].robot_poses
    swapped = write_poses(str(tmp_path / "swapped.csv"), tags["files"], T[[0, 1, 2, 3, 4, 5, 7, 6, 8, 9]])
    code, _, err = run(capsys, *_tag_args(tags, swapped, tmp_path / "a.json"))
    one_line_error(code, err, "view_06.png, view_07.png", "disagree")
    scaled = write_poses(str(tmp_path / "mm.csv"), tags["files"], T, scale=1000.0)
    code, _, err = run(capsys, *_tag_args(tags, scaled, tmp_path / "b.json"))
    one_line_error(code, err, "--pose-units mm")
    assert not (tmp_path / "a.json").exists() and not (tmp_path / "b.json").exists()


def test_quaternions_scalar_first_are_named_as_such(tags, tmp_path, capsys):
    wxyz = write_poses(str(tmp_path / "wxyz.csv"), tags["files"], tags["scene"].robot_poses, "quat-wxyz")
    code, _, err = run(capsys, *_tag_args(tags, wxyz, tmp_path / "a.json"))
    line = one_line_error(code, err, "quaternions", "qw,qx,qy,qz (scalar first)", "--pose-format quat-wxyz")
    assert "--square" not in line and "--pose-units" not in line
    code, _, err = run(capsys, *_tag_args(tags, wxyz, tmp_path / "b.json"), "--pose-format", "quat-wxyz")
    assert code == 0, err
    assert x_error(json.loads((tmp_path / "b.json").read_text()), tags["X"])[0] < 3.0
    assert not (tmp_path / "a.json").exists()


def test_missing_options(tags, tmp_path, capsys):
    poses = write_poses(str(tmp_path / "poses.csv"), tags["files"], tags["scene"].robot_poses)
    args = _tag_args(tags, poses, tmp_path / "x.json")
    no_calibration = [a for a in args if a not in ("--calibration", tags["calibration"])]
    one_line_error(*run(capsys, *no_calibration)[::2], "a single tag cannot calibrate the camera")
    no_size = [a for a in args if a not in ("--tag-size", "0.1")]
    one_line_error(*run(capsys, *no_size)[::2], "--tag-size")
    other = write_poses(str(tmp_path / "other.csv"), ["a.png", "b.png"], tags["scene"].robot_poses[:2])
    one_line_error(*run(capsys, *_tag_args(tags, other, tmp_path / "x.json"))[::2], "no image has a pose")
    code, _, err = run(capsys, "calibrate-hand-eye", *tags["files"][:3], "--robot-poses", poses, "--apriltag",
                       "36h11", "--tag-size", "0.1", "--output", tmp_path / "x.json")
    assert code == 2 and "--eye-in-hand" in err


def test_a_chessboard_and_the_camera_calibrated_from_the_same_images(tmp_path, capsys):
    boards = board_scene("eye_in_hand", 12, 22, str(tmp_path / "images"))
    poses = write_poses(str(tmp_path / "poses.csv"), boards["files"], boards["scene"].robot_poses, "quat")
    out = tmp_path / "handeye.json"
    code, _, err = run(capsys, "calibrate-hand-eye", *boards["files"], "--robot-poses", poses, "--eye-in-hand",
                            "--board", "9x6", "--square", "0.025", "--detector", "opencv", "--jobs", "1",
                            "--no-distortion-correction", "--model", "k1k2", "--output", out)
    assert code == 0, err
    data = json.loads(out.read_text())
    t_mm, r_deg = x_error(data, boards["X"])
    assert t_mm < 2.0 and r_deg < 0.2
    assert data["camera"]["source"] == "calibrated from these images" and data["camera"]["distortion"]["model"] == "k1k2"
    assert abs(data["camera"]["K"][0][0] - float(boards["scene"].K[0, 0])) < 3.0
