"""The ``real_poor`` benchmark section: the shared real sets made poor, ours against OpenCV, scored against the
corners both place alike on the clean image; the skip when the folder is absent; the per-view scoring."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _real_data import REAL_DATA

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.real_poor import real_poor_md, run_real_poor, score_view


@pytest.mark.skipif(not REAL_DATA.is_dir(), reason="shared/data/real is not present next to the repository")
def test_real_poor_section_runs_and_reports():
    assert "real_poor" in SECTIONS
    sec = run_real_poor(BenchConfig.tiny(real_dir=str(REAL_DATA)), log=lambda *_: None)
    assert sec["conditions"] == ["clean", "dark", "small"] and not sec["skipped"]
    assert set(sec["charuco"]["dark"]) == {"ours", "marker_path", "lattice_path", "opencv"}
    assert set(sec["chessboard"]["small"]) == {"ours", "opencv"}
    for kind in ("charuco", "chessboard"):
        clean = sec[kind]["clean"]
        # the truth is where both agree on the clean image: both find all of it there, exactly alike
        assert clean["ours"]["truth"] > 0 and clean["ours"]["found_fraction"] == 1.0 == clean["opencv"]["found_fraction"]
        for condition in sec["conditions"]:
            for s in sec[kind][condition].values():
                assert s["wrong_ids"] == 0 and 0.0 <= s["found_fraction"] <= 1.0
                assert math.isnan(s["mean_error_px"]) or s["mean_error_px"] < 1.0
    assert sec["chessboard"]["clean"]["ours"]["boards"] == 1
    md = "\n".join(real_poor_md(sec))
    assert "| dark | ours, lattice path | 1 |" in md and "| small | findChessboardCornersSB | 1 |" in md
    assert "`charuco_opencv_tutorial`" in md and "`boofcv_bumblebee2_left`" in md


def test_real_poor_section_skips_only_without_the_folder(tmp_path):
    missing = tmp_path / "none"
    sec = run_real_poor(BenchConfig.tiny(real_dir=str(missing)), log=lambda *_: None)
    assert sec["skipped"] == {"*": f"real data folder not found: {missing}"}
    assert real_poor_md(sec) == [f"Skipped: real data folder not found: {missing}.", ""]
    tmp_path.joinpath("empty").mkdir()
    sec = run_real_poor(BenchConfig.tiny(real_dir=str(tmp_path / "empty"), real_poor_sets=("opencv_left", "nope")),
                        log=lambda *_: None)
    assert "not found" in sec["skipped"]["opencv_left"] and "unknown set" in sec["skipped"]["nope"]


def test_score_view_wrong_id_and_unjudged():
    truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 4.0], [np.nan, np.nan]])
    found = np.array([[1.0, 0.0], [43.5, 0.0], [0.0, 1.5], [9.0, 9.0]])
    s = score_view(found, truth)
    # corner 1 is 3.5 px off (more than 3 px); corner 2 is 2.5 px off, more than half the 4 px to its neighbour
    assert (s["truth"], s["right"], s["wrong"], s["unjudged"], s["errors"]) == (3, 1, 2, 1, [1.0])
