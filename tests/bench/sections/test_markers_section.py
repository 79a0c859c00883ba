"""The ``markers`` benchmark section: renders of both boards per condition, every method, the calibration from
partial views, the markdown; the per-view scoring against known corners."""

from __future__ import annotations

import math

import numpy as np

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.markers import _score, markers_md, run_markers
from ccs_kornia.data.scenes.marker_views import CONDITIONS


def test_markers_section_runs_and_reports():
    assert "markers" in SECTIONS
    sec = run_markers(BenchConfig.tiny(), log=lambda *_: None)
    assert set(sec["charuco"]) == set(CONDITIONS) == set(sec["aprilgrid"])
    for condition in CONDITIONS:
        assert set(sec["charuco"][condition]) == {"ours", "marker_path", "lattice_path", "opencv_new", "opencv_legacy",
                                                  "opencv_told"}
        assert set(sec["aprilgrid"][condition]) == {"ours", "marker_path", "lattice_path", "opencv_subpix"}
        for rows in (sec["charuco"][condition], sec["aprilgrid"][condition]):
            for path in ("ours", "marker_path", "lattice_path"):
                assert rows[path]["views"] == 1 and rows[path]["wrong_ids"] == 0
    assert sec["charuco"]["clean"]["ours"]["posed"] == 1
    trial = sec["calibration"][0]
    assert math.isfinite(trial["ours"]["fx_error_pct"]) and trial["ours"]["fx_error_pct"] < 1.0
    md = "\n".join(markers_md(sec))
    assert "| clean | ours | 1 | 1 |" in md and "CharucoDetector (told the layout)" in md
    assert "| strong blur | ours, lattice path | 1 |" in md
    assert "Calibration from partial views" in md
    assert sec["timing"]["charuco_both_s_per_view"] > 0 and "Time per view" in md


def test_score_counts_wrong_ids():
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [np.nan, np.nan]])
    found = truth.copy()
    found[1] = [0.0, 9.0]  # corner 1 reported where corner 2 is: a wrong id
    found[3] = [5.0, 5.0]  # a corner the image does not show
    s = _score(found, truth)
    assert s["corners"] == 4 and s["wrong"] == 2 and len(s["errors"]) == 2 and max(s["errors"]) == 0.0
    assert s["visible"] == 3


def test_score_calls_a_corner_more_than_3_px_off_a_wrong_id():
    truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 40.0]])
    found = truth + np.array([[3.5, 0.0], [2.5, 0.0], [0.0, 0.0]])
    s = _score(found, truth)
    assert s["wrong"] == 1 and s["errors"] == [2.5, 0.0]
