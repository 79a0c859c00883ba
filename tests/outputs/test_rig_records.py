"""rig.json's frame consistency and the command's lines that name the inconsistent frames, the moved intrinsics and
what to record next."""

from __future__ import annotations

import torch
from _cameras import cameras

from ccs_kornia.commands.calibrate_rig import summary_lines
from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.rig import RigSolver
from ccs_kornia.outputs.rig_records import (
    INCONSISTENT_WEIGHT,
    frame_lines,
    frame_records,
    pair_record,
)

D = torch.float64
K = torch.tensor([[600.0, 0, 330], [0, 605, 245], [0, 0, 1]], dtype=D)


def solved_with_moving_frames():
    cams = cameras([(K1K2, K, torch.tensor([-0.12, 0.03], dtype=D))] * 2, (640, 480))
    R = exp_so3(torch.tensor([[0.0, 0, 0], [0.01, -0.12, 0.0]], dtype=D))
    T = torch.tensor([[0.0, 0, 0], [-0.2, 0.01, 0.0]], dtype=D)
    s = render_rig(cams, R, T, num_frames=12, seed=3, noise_px=0.1)
    s2 = render_rig(cams, R, T - torch.tensor([0.006, 0, 0], dtype=D), num_frames=12, seed=3,
                    noise_px=0.1)
    corners = s.corners.clone()
    corners[1, [2, 7]] = s2.corners[1, [2, 7]]
    return RigSolver(K1K2, folds=0)(corners, s.valid, s.object_points, s.image_sizes,
                                      frame_times=torch.arange(12, dtype=D))


def test_frame_records_and_lines():
    rig = solved_with_moving_frames()
    labels = [f"{400 + f:04d}" for f in range(12)]
    frames = frame_records(rig, labels)
    assert [f["frame"] for f in frames] == labels
    assert set(frames[0]) == {"frame", "disagreement_px", "weight", "motion_px", "cause"}
    low = [f["frame"] for f in frames if f["weight"] < INCONSISTENT_WEIGHT]
    assert low == ["0402", "0407"]
    assert all(f["cause"] == "" for f in frames if f["weight"] >= INCONSISTENT_WEIGHT)
    lines = frame_lines(frames)
    assert len(lines) == 2 and all(line.startswith("frame 040") and "cameras disagree by" in line for line in lines)
    assert frame_lines(frames, most=1)[-1].startswith("... and 1 more frames")
    pair = pair_record(rig, 0, 1, labels)
    assert "0402" not in pair["frames_carried"] and "0407" not in pair["frames_carried"]
    assert len(pair["frames_carried"]) >= 8 and 8 <= pair["shared_frames"] < 12


def test_summary_lines_name_frames_moves_and_advice():
    data = {
        "cameras": [{"name": "a", "K": [[600, 0, 330], [0, 605, 245], [0, 0, 1]], "distortion": {"model": "k1k2"},
                     "rms": 0.2, "views": [{"used": True}],
                     "intrinsics_moved_sigma": {"fx": 0.5, "fy": -4.2, "cx": 0.1, "cy": 0.0, "distortion": [1.0, 0.0]}},
                    {"name": "b", "K": [[600, 0, 330], [0, 605, 245], [0, 0, 1]], "distortion": {"model": "k1k2"},
                     "rms": 0.2, "views": [{"used": True}], "fixed": True}],
        "pairs": [], "rms": 0.2, "frame_labels": ["1", "2"], "verdict": "usable",
        "frame_consistency": {"frames": [{"frame": "2", "disagreement_px": 6.3, "weight": 0.02,
                                          "cause": "board moving"}]},
        "session_advice": ["move the board slowly"],
    }
    lines = summary_lines(data, "rig.json")
    assert "moved up to 4.2 sigma (fy) from its own calibration" in lines[0]
    assert "intrinsics fixed" in lines[1] and "moved" not in lines[1]
    assert "frame 2: cameras disagree by 6.3 px, board moving (weight 0.02)" in lines
    assert "to record next: move the board slowly" in lines and lines[-1] == "verdict: usable"
    bare = {k: v for k, v in data.items() if k not in ("frame_consistency", "session_advice")}
    assert not any(line.startswith(("frame ", "to record next")) for line in summary_lines(bare, "rig.json"))
