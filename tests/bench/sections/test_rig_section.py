"""The ``rig`` benchmark section: one rendered rig, both methods, the summary and its markdown."""

from __future__ import annotations

import math

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.rig import SEED, random_rig, rig_md, run_rig
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5


def test_rig_section_runs_and_reports():
    assert "rig" in SECTIONS
    sec = run_rig(BenchConfig.tiny(), log=lambda *_: None)
    assert sec["trials"] == 1 and sec["seed"] == SEED
    C = len(random_rig(SEED, sec["frames"])[0].cameras)
    assert len(sec["rows"]) == C - 1
    for name in ("ours", "opencv"):
        s = sec["summary"][name]
        assert s["pairs"] == C - 1 and 0 <= s["failures"] <= C - 1
    ours = sec["summary"]["ours"]
    assert ours["failures"] == 0 and math.isfinite(ours["rot_deg_median"]) and ours["rot_deg_median"] < 1.0
    md = "\n".join(rig_md(sec))
    assert "| ccs_kornia RigSolver | " in md and "| OpenCV calibrate + stereoCalibrate | " in md


def test_random_rig_is_deterministic_and_mixed():
    a, noise_a = random_rig(SEED + 3, 8)
    b, noise_b = random_rig(SEED + 3, 8)
    assert noise_a == noise_b and 0.1 <= noise_a <= 0.3
    assert a.corners.isnan().equal(b.corners.isnan()) and bool((a.corners == b.corners)[a.valid].all())
    assert 2 <= len(a.cameras) <= 4 and a.cameras.image_sizes == ((640, 480),) * len(a.cameras)
    assert set(a.cameras.models) <= {FISHEYE, K1K2, OPENCV5}
