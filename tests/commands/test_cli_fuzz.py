"""The command line's contract under random inputs (``_fuzz_cli.py``: random bytes as images and videos, damaged and
tiny real ones, random pose files and option values), seeded: every case ends with exit status 0, 2, 3 or 130, never
a signal, an internal error or a traceback; a usage error (2) writes nothing; no file is written or replaced that no
output option named."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
SEED = 20260
CASES = 96


def _named(path: str, named: list[str]) -> bool:
    """``path`` is an output the case named, inside a named output folder, or the record of a failed run beside the
    output (``NAME.failed.json``)."""
    for out in named:
        stem, ext = os.path.splitext(out)
        if path in (out, f"{stem}.failed{ext or '.json'}") or path.startswith(out + os.sep):
            return True
    return False


@pytest.fixture(scope="module")
def cases(tmp_path_factory) -> list[dict]:
    root = tmp_path_factory.mktemp("fuzz")
    report = root / "cases.jsonl"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parents[1]), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, str(HERE / "_fuzz_cli.py"), str(SEED), str(CASES), str(root / "cases"),
                           str(report)], capture_output=True, text=True, env=env, timeout=240, check=False)
    lines = [json.loads(line) for line in report.read_text().splitlines()]
    last = lines[-1] if lines else {}
    assert done.returncode == 0, (f"the process ended with {done.returncode} (a signal where negative) in case "
                                  f"{last.get('case')}: {last.get('argv')}\n{done.stderr[-3000:]}")
    return [line for line in lines if "code" in line]


def test_every_case_ran(cases):
    assert len(cases) == CASES
    assert {case["argv"][0] for case in cases} == {"detect", "calibrate", "calibrate-rig", "calibrate-hand-eye",
                                                     "undistort", "rectify"}
    codes = {case["code"] for case in cases}
    assert {0, 2}.issubset(codes), codes  # the cases reach both results and refusals


def test_exit_statuses_and_one_line_errors(cases):
    for case in cases:
        err = case["stderr"]
        assert case["code"] in (0, 2, 3, 130), (case["argv"], err)
        assert "Traceback" not in err and "internal error" not in err, (case["argv"], err)
        if case["code"] in (2, 3):
            errors = [line for line in err.splitlines() if ": error: " in line]
            assert len(errors) == 1, (case["argv"], err)


def test_nothing_written_on_a_usage_error_and_nothing_unnamed_replaced(cases):
    for case in cases:
        before, after = case["before"], case["after"]
        changed = sorted(p for p in after if before.get(p) != after[p])
        removed = sorted(p for p in before if p not in after)
        assert not removed, (case["argv"], removed)
        if case["code"] == 2:
            assert not changed, (case["argv"], changed)
        assert all(_named(p, case["named"]) for p in changed), (case["argv"], changed)
