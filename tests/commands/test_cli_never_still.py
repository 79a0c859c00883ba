"""A hand-held recording whose board never stops: a short hesitation of nearly parallel poses, then a sweep of well
tilted poses at a few px a frame. ``calibrate`` takes the moving frames the still ones miss, says how many, and
where even those do not cover the poses, names the still gate as the cause of the refusal."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _videos import BOARD, K_VIDEO, posed_frames, tilted_pose, write_video

from ccs_kornia import cli

ARGS = ["--board", f"{BOARD[0]}x{BOARD[1]}", "--detector", "opencv", "--no-distortion-correction", "--jobs", "1",
        "--square", "0.025", "--model", "k1k2", "--no-ransac", "--no-diagnostics", "--max-frames", "12"]


@pytest.fixture(scope="module")
def never_still(tmp_path_factory) -> str:
    """16 frames drifting 0.3 px a frame within 1 deg, then the board tilted 0.5 rad and turned round its axis, 3 px a
    frame (the still gate at 320x240 is 0.4 px a frame)."""
    hesitation = [tilted_pose(0.05 + 0.001 * k, 0.0, (0.0003 * k, 0.0)) for k in range(16)]
    ramp = [tilted_pose(0.05 + 0.45 * (k + 1) / 6, 0.0, (0.0014, 0.0)) for k in range(6)]
    sweep = [tilted_pose(0.5 * math.cos(a), 0.5 * math.sin(a), (0.0014, 0.0))
             for a in np.linspace(0.0, 2 * math.pi, 24)[1:]]
    path = tmp_path_factory.mktemp("never_still") / "hand_held.avi"
    return write_video(str(path), posed_frames(hesitation + ramp + sweep))


def test_a_board_that_never_stops_calibrates_on_its_moving_frames(never_still, tmp_path, capsys):
    out = tmp_path / "cal.json"
    code = cli.main(["calibrate", never_still, *ARGS, "--output", str(out)])
    stderr = capsys.readouterr().err
    assert code == 0, stderr
    data = json.loads(out.read_text())
    video = data["video"][0]
    assert video["still_spread_deg"] < 5.0 and video["chosen_moving"] >= 5
    assert sum(bool(f.get("moving")) for f in video["frames"]) == video["chosen_moving"]
    assert f"{video['chosen_moving']} of them moving" in stderr
    K = np.asarray(data["K"])
    assert abs(K[0, 0] - K_VIDEO[0, 0]) < 3.0 and abs(K[0, 2] - K_VIDEO[0, 2]) < 2.0


def test_the_refusal_names_the_still_gate_when_even_the_moving_frames_do_not_cover(never_still, tmp_path, capsys):
    code = cli.main(["calibrate", never_still, *ARGS, "--max-motion", "0.9", "--output", str(tmp_path / "cal.json")])
    err = capsys.readouterr().err
    assert code == 3, err
    line = next(line for line in err.splitlines() if "error" in line)
    assert "the board was never still long enough" in line and "--max-motion" in line
    assert line.index("never still") < line.index("tilt the board more")
