"""Videos on the command line: ``calibrate``, ``detect``, ``calibrate-rig`` and ``calibrate-many`` on recordings,
the frame span and the frame choice, pairing a rig's frames (by time, by a timestamps table, at different rates),
every bad input, and the shared caliscope recording against its frame folders."""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest
from _real_data import REAL_DATA
from _videos import BOARD, K_VIDEO, board_frames, board_video, truncated, write_video

from ccs_kornia import cli
from ccs_kornia.pipeline.frame_candidates import NO_BOARD_LOOKS

FAST = ["--board", f"{BOARD[0]}x{BOARD[1]}", "--detector", "opencv", "--no-distortion-correction", "--jobs", "1"]
SOLVE = ["--square", "0.025", "--model", "k1k2", "--no-ransac"]
BASELINE = 0.04


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(code: int, err: str, status: int = 2) -> str:
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == status and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    """A camera's recording in both containers, a rig's second camera (moved by BASELINE along x), the same at half
    the rate, one started three frames late, a recording without a board and a damaged one."""
    root = tmp_path_factory.mktemp("videos")
    frames = board_frames(24, seed=2, blank=(5,))
    right = board_frames(24, seed=2, shift=(-BASELINE, 0.0, 0.0))
    out = {
        "avi": write_video(str(root / "cam.avi"), frames),
        "mp4": write_video(str(root / "cam.mp4"), frames, fourcc="mp4v"),
        "right": write_video(str(root / "right.avi"), right),
        "right_half_rate": write_video(str(root / "right_5fps.avi"), right[::2], fps=5.0),
        "right_late": write_video(str(root / "right_late.avi"), right[3:]),
        "blank": write_video(str(root / "blank.avi"), np.full((12, 240, 320), 128, np.uint8)),
    }
    out["cut"] = truncated(board_video(str(root / "long.avi"), 30, seed=4), str(root / "cut.avi"), keep=0.6)
    out["broken"] = truncated(out["mp4"], str(root / "broken.mp4"), keep=0.5)
    return out


@pytest.mark.parametrize("kind", ["avi", "mp4"])
def test_calibrate_a_video(videos, tmp_path, capsys, kind):
    path = videos[kind]
    report = ["--report", tmp_path / "report"] if kind == "avi" else []
    code, out, err = run(capsys, "calibrate", path, *FAST, *SOLVE, "--no-diagnostics", "--output",
                         tmp_path / "c.json", *report)
    assert code == 0, err
    if report:  # the report's overlays are drawn on the recording's frames
        assert len(list((tmp_path / "report" / "views").glob("view_*.png"))) == 24
    data = json.loads((tmp_path / "c.json").read_text())
    assert abs(data["K"][0][0] - K_VIDEO[0, 0]) < 3 and abs(data["K"][1][2] - K_VIDEO[1, 2]) < 3
    views = data["views"]
    assert [v["path"] for v in views] == [f"{path}#{k}" for k in range(24)]  # 24 frames <= --max-frames: all
    assert [v["timestamp"] for v in views] == pytest.approx([k / 10 for k in range(24)])
    assert views[5]["found"] is False
    (video,) = data["video"]
    assert video["path"] == path and video["frames_screened"] == 24 and video["fps"] == 10.0
    assert video["frames"][5] == {"index": 5, "timestamp": 0.5, "board": False, "outline": None, "motion_px": None,
                                  "chosen": True}
    assert f"{path}: 24 frames screened" in err


def test_detect_a_video_with_a_span(videos, tmp_path, capsys):
    code, out, err = run(capsys, "detect", videos["avi"], *FAST, "--every", "3", "--start", "0.6", "--end", "1.9",
                         "--output", tmp_path / "d.json")
    assert code == 0, err
    data = json.loads((tmp_path / "d.json").read_text())
    assert [i["path"] for i in data["images"]] == [f"{videos['avi']}#{k}" for k in (6, 9, 12, 15, 18)]
    assert [i["timestamp"] for i in data["images"]] == pytest.approx([0.6, 0.9, 1.2, 1.5, 1.8])
    assert all(i["found"] and len(i["corners"]) == BOARD[0] * BOARD[1] for i in data["images"])
    assert data["video"][0]["every"] == 3 and data["video"][0]["start"] == 0.6


def test_max_frames_bounds_the_detector_and_says_why(videos, tmp_path, capsys):
    # (without the frame selection: --max-frames bounds the frames the detector sees)
    code, out, err = run(capsys, "calibrate", videos["avi"], *FAST, *SOLVE, "--no-diagnostics", "--max-frames", "8",
                         "--jobs", "2", "--no-select", "--output", tmp_path / "c.json")
    assert code == 0, err
    data = json.loads((tmp_path / "c.json").read_text())
    assert 3 <= len(data["views"]) <= 8
    frames = data["video"][0]["frames"]
    assert sum(f["chosen"] for f in frames) == len(data["views"])
    reasons = {f["reason"].split(" (")[0].split(" of frame")[0] for f in frames if not f["chosen"]}
    assert reasons <= {"no board at screening", "moving", "near copy", "over --max-frames"}
    assert frames[5]["reason"] == "no board at screening"


def test_calibrate_rig_from_videos_by_time(videos, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate-rig", videos["avi"], videos["right"], *FAST, *SOLVE, "--no-select",
                         "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert data["frames_matched_by"] == "time"
    assert abs(data["pairs"][0]["baseline"] - BASELINE) < 0.002
    assert data["frames"][1][0] == f"{videos['right']}#0"
    assert data["frame_times"][0][:2] == pytest.approx([0.0, 0.1])
    assert max(s for s in data["frame_spread_s"] if s is not None) < 1e-3
    assert data["cameras"][1]["views"][0]["timestamp"] == 0.0 and data["cameras"][1]["video"][0]["frames_screened"] == 24
    assert "frames paired by timestamp: 24 instants, 24 of them with frames of two cameras or more (frames per " \
           "camera: cam0 24, cam1 24); largest time spread of a paired frame 0.0 ms" in err


def test_calibrate_rig_at_different_rates(videos, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate-rig", videos["avi"], videos["right_half_rate"], *FAST, *SOLVE,
                         "--no-select", "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert abs(data["pairs"][0]["baseline"] - BASELINE) < 0.003
    assert "frames per camera: cam0 24, cam1 12" in err
    paired = [(a, b) for a, b in zip(*data["frames"]) if a and b]
    assert all(int(a.rsplit("#")[1]) == 2 * int(b.rsplit("#")[1]) for a, b in paired)


def test_a_rig_of_two_frame_rates_shares_the_frame_budget(tmp_path, capsys):
    # 6 fps over the whole path, 12 fps over its first three quarters: the budget must keep the pairs of both cameras
    left = board_frames(96, seed=2)[::2]
    right = board_frames(96, seed=2, shift=(-BASELINE, 0.0, 0.0))[:72]
    slow = write_video(str(tmp_path / "cam_6fps.avi"), left, fps=6.0)
    fast = write_video(str(tmp_path / "cam_12fps.avi"), right, fps=12.0)
    code, out, err = run(capsys, "calibrate-rig", slow, fast, *FAST, *SOLVE, "--no-select", "--max-frames", "20",
                         "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    paired = [(a, b) for a, b in zip(*data["frames"]) if a and b]
    assert len(paired) >= 10, data["frames"]
    assert all(int(a.rsplit("#")[1]) * 2 == int(b.rsplit("#")[1]) for a, b in paired)
    assert abs(data["pairs"][0]["baseline"] - BASELINE) < 0.003


def _table(path, rows) -> str:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sync_index", "cam_id", "frame_index", "frame_time"])
        writer.writerows(rows)
    return str(path)


def test_calibrate_rig_with_a_timestamps_table(videos, tmp_path, capsys):
    # the right camera started three frames late: its frame k is the left camera's frame k + 3
    rows = [(100 + k, 0, k, 50.0 + k / 10) for k in range(3, 24)] + \
           [(100 + k, 1, k - 3, 50.002 + k / 10) for k in range(3, 24)]
    code, out, err = run(capsys, "calibrate-rig", videos["avi"], videos["right_late"], *FAST, *SOLVE, "--timestamps",
                         _table(tmp_path / "t.csv", rows), "--no-select", "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert data["frames_matched_by"] == "table" and data["frame_labels"][0] == "103"
    assert data["frames"][0][0].endswith("#3") and data["frames"][1][0].endswith("#0")
    assert abs(data["pairs"][0]["baseline"] - BASELINE) < 0.002
    assert "largest time spread of a paired frame 2.0 ms" in err
    (left,) = data["cameras"][0]["video"]
    assert left["frames"][0]["reason"] == "not in the timestamps table"


def test_an_older_caliscope_table_is_read_as_caliscope_reads_it(videos, tmp_path, capsys):
    # frame_index counted from the recording's start (26-49 for videos of 24 frames): each camera's rows in time order
    rows = [(k, cam, 26 + k, 7.0 + k / 10 + cam * 0.002) for k in range(24) for cam in (0, 1)]
    code, out, err = run(capsys, "calibrate-rig", videos["avi"], videos["right"], *FAST, *SOLVE, "--timestamps",
                         _table(tmp_path / "t.csv", rows), "--no-select", "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    assert data["frames_matched_by"] == "table order"
    assert "frames paired by the timestamps table read as caliscope reads it" in err
    assert all(a.rsplit("#")[1] == b.rsplit("#")[1] for a, b in zip(*data["frames"]) if a and b)
    assert abs(data["pairs"][0]["baseline"] - BASELINE) < 0.002


def test_calibrate_many_videos(videos, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate-many", videos["avi"], videos["right"], *FAST[:-2], *SOLVE, "--max-frames",
                         "10", "--output", tmp_path / "many.jsonl")
    assert code == 0, err
    lines = [json.loads(line) for line in (tmp_path / "many.jsonl").read_text().splitlines()]
    assert [d["set"] for d in lines] == [videos["avi"], videos["right"]]
    assert all(d["success"] and d["views"][0]["path"].startswith(d["set"] + "#") for d in lines)
    assert all("timestamp" in v for d in lines for v in d["views"]) and len(lines[0]["video"][0]["frames"]) == 24


# ----------------------------------------------------------------------------------------------
# bad input: one line, exit 2 or 3, nothing half written
# ----------------------------------------------------------------------------------------------


def test_damaged_video_uses_the_frames_before(videos, tmp_path, capsys):
    code, out, err = run(capsys, "detect", videos["cut"], *FAST, "--output", tmp_path / "d.json")
    assert code == 0, err
    assert "damaged or truncated" in err and "frames before are used" in err
    data = json.loads((tmp_path / "d.json").read_text())
    assert 0 < len(data["images"]) < 30 and "damaged" in data["video"][0]["stopped"]


@pytest.mark.parametrize("command", ["calibrate", "detect"])
def test_unreadable_video(videos, tmp_path, capsys, command):
    code, out, err = run(capsys, command, videos["broken"], *FAST, "--output", tmp_path / "o.json")
    assert "not a readable video" in one_error_line(code, err)
    assert len(err.strip().splitlines()) == 1 and out == ""
    assert os.listdir(tmp_path) == []


def test_unreadable_video_among_several_is_skipped(videos, tmp_path, capsys):
    code, out, err = run(capsys, "detect", videos["broken"], videos["avi"], *FAST, "--output", tmp_path / "d.json")
    assert code == 0, err
    assert f"warning: skipped {videos['broken']}: not a readable video" in err
    data = json.loads((tmp_path / "d.json").read_text())
    assert {i["path"].rsplit("#")[0] for i in data["images"]} == {videos["avi"]}


def test_video_without_a_board(videos, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate", videos["blank"], *FAST, *SOLVE, "--output", tmp_path / "c.json")
    line = one_error_line(code, err, status=3)
    assert "not found" in line and "12 frames of" in line and "the board seen in none" in line
    # the screen saw no board: a few frames spread over the recording go to the detector, not every frame
    assert f"not found in any of {NO_BOARD_LOOKS} images" in line
    assert not (tmp_path / "c.json").exists()


def test_a_rig_of_recordings_without_a_board_is_a_run_without_result(videos, tmp_path, capsys):
    other = write_video(str(tmp_path / "blank2.avi"), np.full((12, 240, 320), 100, np.uint8), fps=5.0)
    code, out, err = run(capsys, "calibrate-rig", videos["blank"], other, *FAST, *SOLVE, "--max-frames", "1",
                         "--output", tmp_path / "rig.json")
    one_error_line(code, err, status=3)
    assert "internal error" not in err and not (tmp_path / "rig.json").exists()


def test_span_with_no_frame(videos, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate", videos["avi"], *FAST, "--start", "100", "--output", tmp_path / "c.json")
    assert "no frame between --start and --end could be read" in one_error_line(code, err)


def test_end_before_start(videos, tmp_path, capsys):
    code, out, err = run(capsys, "detect", videos["avi"], *FAST, "--start", "2", "--end", "1", "--output",
                         tmp_path / "d.json")
    assert "must come after start" in one_error_line(code, err)


def test_images_and_videos_together(videos, tmp_path, capsys):
    image = tmp_path / "a.png"
    image.write_bytes(b"")
    code, out, err = run(capsys, "calibrate", videos["avi"], image, *FAST, "--output", tmp_path / "c.json")
    assert "give either videos or images, not both" in one_error_line(code, err)


@pytest.mark.parametrize("case, phrase", [
    ("unreadable", "not a readable video"),
    ("folder", "a rig of recordings takes one video per camera, got images"),
    ("table_camera", "names camera 2 but 2 videos were given"),
    ("table_frame", "frame_index 99 of camera 1 is past the end of its video (24 frames)"),
    ("table_columns", "no column frame_time"),
    ("timestamps_with_folders", "--timestamps pairs the frames of videos"),
])
def test_bad_rig_inputs(videos, tmp_path, capsys, case, phrase):
    folder = tmp_path / "images"
    folder.mkdir()
    cams = [videos["avi"], videos["right"]]
    extra: list = []
    if case == "unreadable":
        cams[1] = videos["broken"]
    elif case == "folder":
        cams[1] = folder
    elif case == "table_camera":
        extra = ["--timestamps", _table(tmp_path / "t.csv", [(0, 0, 0, 1.0), (0, 2, 0, 1.0)])]
    elif case == "table_frame":
        extra = ["--timestamps", _table(tmp_path / "t.csv", [(0, 0, 0, 1.0), (0, 1, 99, 1.0)])]
    elif case == "table_columns":
        (tmp_path / "t.csv").write_text("sync_index,cam_id\n0,0\n")
        extra = ["--timestamps", tmp_path / "t.csv"]
    else:
        cams = [folder, folder]
        extra = ["--timestamps", tmp_path / "t.csv"]
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    code, out, err = run(capsys, "calibrate-rig", *cams, *FAST, *SOLVE, *extra, "--output", out_dir / "rig.json")
    assert phrase in one_error_line(code, err)
    assert os.listdir(out_dir) == []


def test_every_must_be_positive(videos, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate", videos["avi"], *FAST, "--every", "0", "--output", tmp_path / "c.json")
    assert code == 2 and "--every" in err


# ----------------------------------------------------------------------------------------------
# the shared caliscope recording: the videos with their timestamps table against the frame folders
# ----------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_caliscope_videos_give_the_rig_of_the_frame_folders(tmp_path, capsys):
    folder = REAL_DATA / "caliscope_4cam_charuco"
    if not (folder / "video").is_dir():
        pytest.skip(f"real data set not present at {folder} (set CCS_REAL_DATA)")
    cams = (0, 2)  # two of the four cameras: the table's rows of theirs, renumbered by position
    with open(folder / "video" / "timestamps.csv", newline="") as handle:
        rows = [r for r in csv.DictReader(handle) if int(r["cam_id"]) in cams]
    table = tmp_path / "t.csv"
    with open(table, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["sync_index", "cam_id", "frame_time"])
        writer.writerows((r["sync_index"], cams.index(int(r["cam_id"])), r["frame_time"]) for r in rows)
    board = ["--charuco", "4x5", "--dictionary", "DICT_4X4_1000", "--square", "0.054", "--marker", "0.0405",
             "--model", "k1k2", "--jobs", "2", "--no-select"]
    results = {}
    for name, inputs in (("folders", [folder / f"cam_{c}" for c in cams]),
                         ("videos", [folder / "video" / f"cam_{c}.mp4" for c in cams] + ["--timestamps", table])):
        code, out, err = run(capsys, "calibrate-rig", *inputs, *board, "--output", tmp_path / f"{name}.json")
        assert code == 0, err
        results[name] = json.loads((tmp_path / f"{name}.json").read_text())
    a, b = results["folders"], results["videos"]
    assert b["frames_matched_by"] == "table order"  # no frame_index: each camera's rows in time order, as caliscope
    assert [int(x) for x in b["frame_labels"]] == [int(x) for x in a["frame_labels"]]  # the same 48 instants
    pa, pb = a["pairs"][0], b["pairs"][0]
    print(f"\nbaseline folders {pa['baseline']:.4f} videos {pb['baseline']:.4f}; held-out epipolar RMS folders "
          f"{pa['heldout_epipolar_rms']:.3f} videos {pb['heldout_epipolar_rms']:.3f} px")
    assert abs(pb["baseline"] - pa["baseline"]) < 0.01 * pa["baseline"]
    assert abs(pb["rotation_deg"] - pa["rotation_deg"]) < 1.0
    assert pb["heldout_epipolar_rms"] < 1.1 * pa["heldout_epipolar_rms"]


def test_help_states_the_frame_cap(capsys):
    from ccs_kornia.pipeline.frame_candidates import DEFAULT_MAX_FRAMES

    code, out, err = run(capsys, "calibrate", "--help")
    assert code == 0 and f"at most (default {DEFAULT_MAX_FRAMES})" in " ".join(out.split())
