"""``capture`` on a rendered video file: the frames it keeps (still, new, lowering the predicted uncertainty) give the
same calibration through ``calibrate FRAMES_DIR``; bad input is one line, exit 2 or 3, nothing written."""

from __future__ import annotations

import json
import os
import socket
import threading
import time
import urllib.request

import numpy as np
import pytest
from _videos import BOARD, board_frames, write_video

from ccs_kornia import cli
from ccs_kornia.io.live import source_kind

FAST = ["--board", f"{BOARD[0]}x{BOARD[1]}", "--detector", "opencv", "--no-distortion-correction", "--jobs", "1",
        "--square", "0.025", "--model", "k1k2", "--no-ransac", "--no-diagnostics"]


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def held_video(tmp_path_factory):
    """A person holding the board still at 12 poses for 3 frames each, moving between them (10 fps)."""
    root = tmp_path_factory.mktemp("capture")
    poses = board_frames(24, seed=3)[::2]
    return write_video(str(root / "held.avi"), np.repeat(poses, 3, axis=0))


def test_capture_keeps_frames_and_calibrate_reproduces_it(held_video, tmp_path, capsys):
    frames = tmp_path / "kept"
    code, out, err = run(capsys, "capture", held_video, *FAST, "--no-page", "--fast", "--output", tmp_path / "calib.json",
                         "--frames-dir", frames, "--target", "0.01")
    assert code == 0, err
    kept = sorted(os.listdir(frames))
    assert 6 <= len(kept) <= 12 and all(k.endswith(".png") for k in kept)
    # one frame per held pose at most (the others of a hold are near copies), none while moving
    indices = [int(k[6:12]) for k in kept]
    assert len({i // 3 for i in indices}) == len(indices)
    assert "kept frame_" in out and "next: " in out and "stream ended" in out
    captured = json.loads((tmp_path / "calib.json").read_text())
    assert captured["success"] and captured["num_views"]["used"] == len(kept)
    code, _, err = run(capsys, "calibrate", frames, *FAST, "--output", tmp_path / "again.json")
    assert code == 0, err
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["K"] == captured["K"] and again["distortion"] == captured["distortion"]
    assert again["rms"] == captured["rms"]


def test_capture_stops_at_the_target(held_video, tmp_path, capsys):
    code, out, err = run(capsys, "capture", held_video, *FAST, "--no-page", "--fast", "--output", tmp_path / "calib.json",
                         "--target", "5")
    assert code == 0, err
    assert "target reached" in out
    assert len(os.listdir(tmp_path / "calib_frames")) == 4  # the first solve (4 views) already predicts < 5 px


def test_bad_sources_are_one_line_and_write_nothing(tmp_path, capsys):
    blank = write_video(str(tmp_path / "blank.avi"), np.full((12, 240, 320), 128, np.uint8))
    cases = [(["capture", tmp_path / "none.avi"], 2, "no such file"),
             (["capture", blank], 3, "the board was never seen"),
             (["capture", blank, blank], 3, "the board was never held still")]
    for argv, status, words in cases:
        code, _, err = run(capsys, *argv, *FAST, "--no-page", "--fast", "--output", tmp_path / "calib.json")
        lines = [line for line in err.splitlines() if "error" in line]
        assert code == status and len(lines) == 1 and words in lines[0], err
    assert sorted(os.listdir(tmp_path)) == ["blank.avi"]


def test_capture_of_a_rig_keeps_instants_and_calibrate_rig_reproduces_it(tmp_path, capsys):
    """Two cameras 3 cm apart before one board held still at 12 poses."""
    left = write_video(str(tmp_path / "left.avi"), np.repeat(board_frames(24, seed=3)[::2], 3, axis=0))
    right = write_video(str(tmp_path / "right.avi"),
                        np.repeat(board_frames(24, seed=3, shift=(-0.03, 0.0, 0.0))[::2], 3, axis=0))
    code, out, err = run(capsys, "capture", left, right, *FAST, "--no-page", "--fast", "--output", tmp_path / "rig.json",
                         "--target", "5")
    assert code == 0, err
    assert "cameras 0 and 1 need views in common" in out and "target reached: 5 instants kept" in out
    cams = [tmp_path / "rig_frames" / f"cam{c}" for c in range(2)]
    assert sorted(os.listdir(cams[0])) == sorted(os.listdir(cams[1])) and len(os.listdir(cams[0])) == 5
    rig = json.loads((tmp_path / "rig.json").read_text())
    assert abs(rig["extrinsics"][1]["T"][0] + 0.03) < 1e-3
    code, _, err = run(capsys, "calibrate-rig", *cams, *FAST[:-1], "--output", tmp_path / "again.json")
    assert code == 0, err
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["extrinsics"] == rig["extrinsics"] and again["rms"] == rig["rms"]


def test_a_non_empty_frames_dir_is_refused(held_video, tmp_path, capsys):
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "old.png").write_bytes(b"")
    code, _, err = run(capsys, "capture", held_video, *FAST, "--no-page", "--output", tmp_path / "c.json", "--frames-dir",
                       tmp_path / "kept")
    assert code == 2 and "not empty" in err
    assert not (tmp_path / "c.json").exists()


def test_a_port_in_use_stops_before_anything(held_video, tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        code, _, err = run(capsys, "capture", held_video, *FAST, "--port", port, "--output", tmp_path / "c.json")
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(lines) == 1 and "in use" in lines[0], err
    assert os.listdir(tmp_path) == []


def test_the_page_runs_with_capture_and_shows_the_result(held_video, tmp_path, capsys):
    with socket.socket() as s:  # a free port for the page
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    result: dict = {}
    worker = threading.Thread(target=lambda: result.update(code=cli.main([str(a) for a in (
        "capture", held_video, *FAST[:-1], "--fast", "--port", port, "--output", tmp_path / "calib.json", "--target", "5",
        "--page-linger", "1")])))
    worker.start()
    states = []
    while worker.is_alive():
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/state.json", timeout=2) as r:
                states.append(json.loads(r.read()))
        except OSError:
            pass
        time.sleep(0.1)
    worker.join()  # (with diagnostics: the page gives the held-out figure)
    out, err = capsys.readouterr()
    assert result["code"] == 0, err
    assert "page: http://127.0.0.1:" in out and "target reached" in out
    # while the result lingers the page says it: the verdict, the held-out figure and the file
    final = [s for s in states if s["status"].startswith("calibrated from 4 frames")]
    assert final and final[-1]["done"] and "held-out views" in final[-1]["status"], states[-1:]
    assert str(tmp_path / "calib.json") in final[-1]["status"] and len(final[-1]["kept"]) == 4


def test_source_kinds():
    assert [source_kind(s) for s in ("3", "/dev/video1", "http://host:8080/video", "x.mp4")] == [
        "index", "device", "stream", "file"]
