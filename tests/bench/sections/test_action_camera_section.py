"""The ``action_camera`` benchmark section: rendered action-camera views of a large ChArUco board made poor, every
method scored against the rendered truth."""

from __future__ import annotations

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.action_camera import action_camera_md, run_action_camera


def test_action_camera_section_runs_and_reports():
    assert "action_camera" in SECTIONS
    sec = run_action_camera(BenchConfig.tiny(), log=lambda *_: None)
    assert sec["conditions"] == ["clean", "dark", "small"] and sec["views"] == 1
    for condition in sec["conditions"]:
        rows = sec["results"][condition]
        assert set(rows) == {"ours", "marker_path", "lattice_path", "opencv"}
        truth = rows["ours"]["truth"]
        assert truth > 50 and all(s["truth"] == truth for s in rows.values())
        assert 0.0 <= rows["ours"]["found_fraction"] <= 1.0
    # the clean view (its near squares 140 px, its far ones 6 px): most corners found with their ids, none wrong
    clean = sec["results"]["clean"]["ours"]
    assert clean["found_fraction"] > 0.7 and clean["wrong_ids"] == 0 and clean["mean_error_px"] < 0.5
    md = "\n".join(action_camera_md(sec))
    assert "| small | ours, lattice path | 1 |" in md and "wrong ids over all conditions" in md
