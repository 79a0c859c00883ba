"""ROS bags on the command line: ``calibrate`` and ``calibrate-rig`` with ``--bag BAG --image-topics ...``, an image
topic read as a recording is (frames ``BAG#TOPIC#INDEX`` with their header stamps), and the refusals."""

from __future__ import annotations

import json

import pytest
from _rosbags import T0, write_frames_bag
from _videos import BOARD, K_VIDEO, board_frames

from ccs_kornia import cli

FAST = ["--board", f"{BOARD[0]}x{BOARD[1]}", "--detector", "opencv", "--no-distortion-correction", "--jobs", "1"]
SOLVE = ["--square", "0.025", "--model", "k1k2", "--no-ransac"]
BASELINE = 0.04


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(code: int, err: str) -> str:
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module", params=["ros1", "ros2"])
def bag(request, tmp_path_factory):
    """A rig's two cameras (the second moved by BASELINE along x, its stamps 2 ms late) at 10 Hz, one frame without
    the board."""
    times = [0.1 * k for k in range(24)]
    left = board_frames(24, seed=2, blank=(5,))
    right = board_frames(24, seed=2, shift=(-BASELINE, 0.0, 0.0))
    root = tmp_path_factory.mktemp(request.param)
    ros1 = request.param == "ros1"
    return write_frames_bag(root / ("rec.bag" if ros1 else "rec"), {
        "/cam0/image_raw": (left, times), "/cam1/image_raw": (right, [t + 0.002 for t in times])}, ros1=ros1)


def test_calibrate_a_bag_topic(bag, tmp_path, capsys):
    out = tmp_path / "c.json"
    code, _, err = run(capsys, "calibrate", "--bag", bag, "--image-topics", "/cam0/image_raw", *FAST, *SOLVE,
                       "--no-diagnostics", "--output", out)
    assert code == 0, err
    data = json.loads(out.read_text())
    assert abs(data["K"][0][0] - K_VIDEO[0, 0]) < 3 and abs(data["K"][1][2] - K_VIDEO[1, 2]) < 3
    views = data["views"]
    assert [v["path"] for v in views] == [f"{bag}#/cam0/image_raw#{k}" for k in range(24)]
    assert [v["timestamp"] for v in views] == pytest.approx([T0 + 0.1 * k for k in range(24)], abs=1e-6)
    assert views[5]["found"] is False and all(v["found"] for k, v in enumerate(views) if k != 5)
    (video,) = data["video"]
    assert video["path"] == f"{bag}#/cam0/image_raw" and video["frames_screened"] == 24
    assert video["fps"] == pytest.approx(10.0) and video["size"] == [320, 240]


def test_calibrate_rig_from_two_topics(bag, tmp_path, capsys):
    out = tmp_path / "rig.json"
    code, _, err = run(capsys, "calibrate-rig", "--bag", bag, "--image-topics", "/cam0/image_raw,/cam1/image_raw",
                       *FAST, *SOLVE, "--output", out)
    assert code == 0, err
    data = json.loads(out.read_text())
    assert data["frames_matched_by"] == "time" and abs(data["pairs"][0]["baseline"] - BASELINE) < 0.002
    assert data["frames"][1][0] == f"{bag}#/cam1/image_raw#0"
    assert max(s for s in data["frame_spread_s"] if s is not None) == pytest.approx(0.002, abs=1e-6)
    assert "frames paired by timestamp: 24 instants, 24 of them with frames of two cameras" in err


def test_a_bag_after_detect_gives_its_corners_with_stamps(bag, tmp_path, capsys):
    """The corners of a bag's frames, with their stamps, as --corners takes them back."""
    corners = []
    for c in (0, 1):
        path = tmp_path / f"cam{c}.json"
        code, _, err = run(capsys, "detect", "--bag", bag, "--image-topics", f"/cam{c}/image_raw", *FAST,
                           "--output", path)
        assert code == 0, err
        corners.append(path)
    data = json.loads(corners[1].read_text())
    assert data["images"][0]["timestamp"] == pytest.approx(T0 + 0.002, abs=1e-6)
    out = tmp_path / "rig.json"
    code, _, err = run(capsys, "calibrate-rig", "--corners", corners[0], "--corners", corners[1], *FAST, *SOLVE,
                       "--output", out)
    assert code == 0, err
    rig = json.loads(out.read_text())
    assert rig["frames_matched_by"] == "time" and abs(rig["pairs"][0]["baseline"] - BASELINE) < 0.002


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["calibrate", "--bag", "BAG", "--image-topics", "/cam2/image_raw"],
         "no topic /cam2/image_raw; the bag has: /cam0/image_raw (sensor_msgs/Image), /cam1/image_raw"),
        (["calibrate", "--bag", "BAG"], "give --image-topics (its image topics: /cam0/image_raw, /cam1/image_raw)"),
        (["calibrate", "--image-topics", "/cam0/image_raw"], "--image-topics names the image topics of a --bag"),
        (["calibrate", "--bag", "BAG", "--image-topics", "/cam0/image_raw,/cam1/image_raw"],
         "one camera takes one image topic"),
        (["calibrate-rig", "--bag", "BAG", "--image-topics", "/cam0/image_raw"],
         "a rig needs at least two --image-topics (one per camera), got 1"),
        (["calibrate-rig", "--bag", "BAG", "--image-topics", "/cam0/image_raw,/cam0/image_raw"], "a topic given twice"),
        (["calibrate", "IMAGES", "--bag", "BAG", "--image-topics", "/cam0/image_raw"],
         "give either images or --bag, not both"),
    ],
)
def test_bag_refusals_are_one_line(bag, tmp_path, capsys, argv, phrase):
    out = tmp_path / "out.json"
    args = [str(bag) if a == "BAG" else str(tmp_path) if a == "IMAGES" else a for a in argv]
    code, _, err = run(capsys, *args, *FAST, *SOLVE, "--output", out)
    assert phrase in one_error_line(code, err) and not out.exists()
