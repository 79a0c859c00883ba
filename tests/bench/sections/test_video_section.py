"""The ``video`` benchmark section: a short rendered recording, every frame choice solved and judged, the markdown;
the real recording's folds."""

from __future__ import annotations

import math

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.video import (
    RENDERED_METHODS,
    _folds,
    run_video,
    video_md,
)


def test_video_section_runs_and_reports(tmp_path):
    assert "video" in SECTIONS
    sec = run_video(BenchConfig.tiny(real_dir=str(tmp_path)), log=lambda *_: None)
    assert len(sec["rendered"]) == 1 and sec["real"] is None and "caliscope_4cam_charuco" in sec["skipped"]
    r = sec["rendered"][0]
    assert set(r["methods"]) == set(RENDERED_METHODS) and r["board_seen"] <= r["frames"]
    assert r["screening_fps"] > 0 and r["candidates"] <= r["detected"]
    chosen = r["methods"]["selected"]["frames"]
    # the baselines take as many frames as the selection kept (fewer where the frames run out)
    assert 1 <= r["methods"]["coverage"]["frames"] <= r["methods"]["uniform"]["frames"] == max(1, chosen)
    for name, entry in r["methods"].items():
        if not entry.get("failed"):
            assert math.isfinite(entry["proj_rms"]) and entry["efl"] >= 0, name
    md = "\n".join(video_md(sec))
    assert "| selected | " in md and "| coverage | " in md and "skipped caliscope_4cam_charuco" in md


def test_folds_alternate_blocks():
    a, b = _folds(40)
    assert sorted(a + b) == list(range(40)) and not set(a) & set(b)
    assert a[:8] == list(range(8)) and b[:8] == list(range(8, 16))


def test_real_recording_table_shows_projection_against_published():
    entry = {"frames": [3, 4], "heldout_rms": [0.1, 0.2], "whole_frames": 7,
             "vs_reference": {"efl": 1.24, "epp": 2.5, "proj_rms": 3.71}}
    sec = {"model": "opencv5", "max_frames": 60, "jobs": 2, "rendered": [],
           "real": {"cameras": [{"camera": 0, "found": 7, "frames": 8,
                                 "methods": {m: dict(entry) for m in ("selected", "all", "uniform", "coverage")}}],
                    "rig": None}}
    md = "\n".join(video_md(sec))
    assert "| cam_0 | 1.2 / 2.5 / 3.7 (7) |" in md
    assert "projection over the whole image" in md


def test_still_frames_are_those_the_command_gate_passes():
    from types import SimpleNamespace

    import numpy as np

    from ccs_kornia.bench.sections.video import _still_frames
    from ccs_kornia.modules.detection.screening import Sighting

    box = np.array([[0.0, 0.0], [400.0, 0.0], [400.0, 300.0], [0.0, 300.0]])
    # 1280x720: the gate is 0.1 % of the diagonal a frame, 1.47 px
    shifts = [0.0, 1.0, 2.0, 6.0, 6.5, 7.0, 7.0]
    frames = [SimpleNamespace(index=i, found=True, sighting=Sighting(True, box + [dx, 0.0]))
              for i, dx in enumerate(shifts)]
    frames.append(SimpleNamespace(index=7, found=False, sighting=Sighting(False)))
    frames.append(SimpleNamespace(index=9, found=True, sighting=Sighting(True, box)))  # no neighbour with a board
    still = _still_frames(SimpleNamespace(frames=frames), [0, 1, 2, 3, 4, 5, 6, 9], (1280, 720))
    # frame 2 moved 4 px to frame 3 and frame 3 moved 4 px from frame 2; an unknown motion counts as still
    assert still == [0, 1, 4, 5, 6, 9]
