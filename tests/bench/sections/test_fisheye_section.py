"""bench §7 (fisheye): both solvers on the same synthetic Kannala-Brandt corners, every method on its own corners of
rendered fisheye views, real sets when present."""

from __future__ import annotations

import pytest
from _real_data import REAL_DATA

from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.sections.fisheye import fisheye_md, run_fisheye


def test_synthetic_part_and_markdown():
    sec = run_fisheye(BenchConfig.tiny(fisheye_trials=3, fisheye_views=8), log=lambda *_: None)
    for key in ("ccs", "opencv"):
        s = sec["synthetic"][key]
        assert s["trials"] == 3 and 0 <= s["failures"] <= 3
    ours = sec["synthetic"]["ccs"]
    assert ours["failures"] == 0 and ours["e_ip_mean"] < 2.0  # 0.1 px noise, exact model
    # rendered: every method on its own corners; ours finds and calibrates every camera
    rendered = sec["rendered"]["methods"]
    assert set(rendered) == {"ccs_fisheye", "ccs_auto", "opencv_subpix", "opencv_sb"}
    assert rendered["ccs_fisheye"]["failures"] == 0 and rendered["ccs_fisheye"]["e_ip_mean"] < 2.0
    assert all(0 <= r["boards_found"] <= 24 and len(r["e_ip_per_trial"]) == 3 for r in rendered.values())
    md = "\n".join(fisheye_md(sec))
    assert "cv2.fisheye.calibrate" in md and "| ccs_kornia" in md and sec["real"] == {}
    assert "Rendered: 3 Kannala-Brandt cameras" in md and "OpenCV SB → cv2.fisheye" in md


def test_real_set_through_both_solvers():
    if not (REAL_DATA / "ros_fisheye_mono").is_dir():
        pytest.skip(f"real data set not present at {REAL_DATA / 'ros_fisheye_mono'}")
    cfg = BenchConfig.tiny(fisheye_trials=1, fisheye_views=6, fisheye_real_sets=("ros_fisheye_mono",),
                           real_dir=str(REAL_DATA))
    e = run_fisheye(cfg, log=lambda *_: None)["real"]["ros_fisheye_mono"]
    assert e["classic_found"] == 24 and e["ccs_on_classic"]["views_used"] == 24
    assert e["ccs_on_classic"]["max_diff_to_reference"] < 2.0
    assert e["default_path"]["success"] and e["default_path"]["model"] == "fisheye"
