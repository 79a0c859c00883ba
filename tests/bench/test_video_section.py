"""The ``video`` benchmark section: a short rendered recording, every frame choice solved and judged, the markdown;
the real recording's folds."""

from __future__ import annotations

import math

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.video import RENDERED_METHODS, _folds, run_video, video_md


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
