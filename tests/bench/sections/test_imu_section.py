"""The ``imu`` benchmark section: rendered visual-inertial recordings solved against their truth, and the markdown."""

from __future__ import annotations

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.imu import SEED, imu_md, run_imu


def test_imu_section_runs_and_reports():
    assert "imu" in SECTIONS
    sec = run_imu(BenchConfig.tiny(), log=lambda *_: None)
    assert sec["trials"] == 1 and sec["seed"] == SEED and set(sec["conditions"]) == {"given"}
    s = sec["conditions"]["given"]["summary"]
    assert s["t_mm_median"] < 5.0 and s["r_deg_median"] < 0.1 and abs(s["shift_ms_median"]) < 0.5
    assert 0.0 <= s["coverage"] <= 1.0 and sec["peak_rss_mb"] > 0
    md = "\n".join(imu_md(sec))
    assert "| given |" in md and "1-sigma coverage" in md


def test_imu_section_fits_an_imu_with_errors():
    # the scale-misalignment condition: the IMU's intrinsics reported beside T_cam_imu
    from dataclasses import replace

    cfg = replace(BenchConfig.tiny(), imu_seconds=8.0, imu_conditions=("IMU errors, scale-misalignment",))
    sec = run_imu(cfg, log=lambda *_: None)
    s = sec["conditions"]["IMU errors, scale-misalignment"]["summary"]
    assert s["t_mm_median"] < 5.0 and s["imu_matrix_err_pct_median"] < 0.5
    assert "The IMU's intrinsics" in "\n".join(imu_md(sec))


def test_imu_section_reports_the_board_sag():
    # the sag's conditions: whether it was kept and how far it is from the truth, beside T_cam_imu (rows as
    # run_imu_trial makes them, without the fits)
    from ccs_kornia.bench.sections.imu import BENT, CONDITIONS, _summary

    assert CONDITIONS["bent board, sag judged"].board_warp == BENT and CONDITIONS["given, sag judged"].board_flatness
    cam = {"r_deg": 0.005, "t_mm": 0.2, "shift_ms": 0.004, "within": 5, "components": 7}
    rows = [{"cameras": [cam], "fit_s": 9.0, "verdict": "good",
             "sag": {"kept": k, "fitted_err_mm": e, "used_err_mm": e, "heldout_px": {"flat": 0.28, "warp": 0.24}}}
            for k, e in ((True, 0.03), (True, 0.01), (False, 0.05))]
    s = _summary(rows)
    assert s["sag_kept"] == 2 and abs(s["sag_fitted_err_mm_median"] - 0.03) < 1e-12
    md = "\n".join(imu_md({"trials": 3, "recording_s": 20.0, "peak_rss_mb": 1.0, "threads": 2,
                           "conditions": {"bent board, sag judged": {"summary": s}}}))
    assert "| bent board, sag judged |" in md and "kept in 2 of 3" in md
