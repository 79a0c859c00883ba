"""The ``rig_sessions`` benchmark section: a short rendered hand-held rig recording, every method, the summary and
its markdown; the recording's conditions; the transfer error."""

from __future__ import annotations

import math

import torch

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.rig_sessions import (
    CONDITIONS,
    METHODS,
    SEED,
    rendered_session,
    rig_sessions_md,
    run_rig_sessions,
    transfer_error,
)
from ccs_kornia.geometry.models import OPENCV5


def test_rig_sessions_section_runs_and_reports():
    assert "rig_sessions" in SECTIONS
    sec = run_rig_sessions(BenchConfig.tiny(), log=lambda *_: None)
    assert sec["trials"] == 1 and sec["seed"] == SEED and len(sec["rows"]) == 1
    row = sec["rows"][0]
    assert row["condition"] == "handheld" and set(row["methods"]) == set(METHODS)
    for name in ("fixed", "joint", "prior", "ours"):
        got = row["methods"][name]
        assert "failed" not in got, got
        assert len(got["rot_deg"]) == row["cameras"] - 1 and len(got["fx_pct"]) == row["cameras"]
        assert math.isfinite(got["transfer_px"])
    s = sec["summary"]["handheld"]
    assert set(s) == set(METHODS) and s["ours"]["sessions"] == 1
    md = "\n".join(rig_sessions_md(sec))
    assert "| handheld | ours | " in md and "| handheld | fixed | " in md


def test_conditions_share_the_session():
    a = rendered_session(SEED + 5, "handheld", duration=6.0)
    b = rendered_session(SEED + 5, "frozen", duration=6.0)
    c = rendered_session(SEED + 5, "handheld", duration=6.0)
    assert a.corners.shape == b.corners.shape and torch.equal(a.R, b.R) and torch.equal(a.T, b.T)
    assert a.corners.isnan().equal(c.corners.isnan()) and bool((a.corners == c.corners)[a.corners.isfinite()].all())
    assert a.cameras.models == b.cameras.models == (OPENCV5,) * len(a.cameras) and torch.equal(a.cameras.K, b.cameras.K)
    assert a.test_corners.shape[:1] == a.corners.shape[:1] and a.frame_times.shape == a.corners.shape[1:2]
    assert set(CONDITIONS) == {"handheld", "global", "timestamps", "frozen"}


def test_transfer_error_of_the_truth_is_the_noise():
    s = rendered_session(SEED + 6, "frozen", duration=6.0, noise_px=0.0)
    valid = s.test_corners.isfinite().all(-1)
    exact = transfer_error(s.cameras, s.R, s.T, s.test_corners, valid, s.object_points)
    assert exact.numel() > 0 and float(exact.max()) < 1e-6
    T = s.T.clone()
    T[1, 0] += 0.01  # one camera 1 cm off: its corners land away
    off = transfer_error(s.cameras, s.R, T, s.test_corners, valid, s.object_points)
    assert float(off.median()) > 1.0
