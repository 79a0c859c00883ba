"""The GPU check (``ccs_kornia/bench/gpu_check.sh``) as a dry run: what it says it would check and the CPU half it runs."""

from __future__ import annotations

import json

from ccs_kornia.bench import gpu_check


def test_dry_run_says_what_it_would_check_and_runs_the_cpu_half(tmp_path, capsys):
    out = tmp_path / "report.json"
    status = gpu_check.main(["--dry-run", "--no-tests", "--out", str(out)])
    printed = capsys.readouterr().out
    report = json.loads(out.read_text())

    assert status == 0 and report["ok"] is True
    assert report["dry_run"] is True and report["cuda"] is False and "syncs" not in report and "tests" not in report
    assert "DRY RUN" in printed and "PASS" in printed and "dry run: CPU half only" in printed
    for i, line in enumerate(gpu_check.would_check(), 1):
        assert f"  {i}. {line}" in printed
    assert report["would_check"] == gpu_check.would_check()
    assert "1e-06 relative" in printed and "0.001 px" in printed  # the tolerances are the defaults
    # the CPU half: every rendered board found and calibrated, positive throughput at each size it ran
    assert report["parity"] == {"cpu_found": 8, "cpu_calibrated": True}
    assert set(report["throughput"]["detect_images_per_s"]) == {"1", "8"}
    assert set(report["throughput"]["calibrations_per_s"]) == {"1", "16"}
    assert all(v > 0 for part in report["throughput"].values() for v in part.values())
    for b in (1, 8):
        assert f"cpu detection batch {b}:" in printed


def test_dry_run_lists_the_device_tests():
    listed = gpu_check._tests(cuda=False, time_limit=120)
    assert listed["ok"] is True and listed["command"] == "pytest -q -k cuda tests"
    # the device fixture's tests exist (several modules take it); each has one cuda variant per cpu variant
    assert listed["would_run"] >= 10
    assert "collected" in listed["summary"]
