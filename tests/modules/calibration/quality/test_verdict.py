"""The verdict scaffold: grades against the good / usable limits, the outcome and its advice."""

from __future__ import annotations

import math

from ccs_kornia.modules.calibration.quality.verdict import Findings


def test_grades():
    f = Findings()
    f.grade(0.5, 1.0, 2.0, "fine", "none needed")
    assert f.outcome() == ("good", [])
    f.grade(math.nan, 1.0, 2.0, "unknown", "none needed")  # NaN grades nothing
    assert f.outcome() == ("good", [])
    f.grade(1.5, 1.0, 2.0, "rms 1.5 px", "check corners", "rms 1.5 px is high")
    assert f.outcome() == ("usable", ["rms 1.5 px is high"])


def test_failures_come_first_with_their_advice_once():
    f = Findings()
    f.warn("few views")
    f.grade(3.0, 1.0, 2.0, "cam a: rms 3.0 px", "check the corners")
    f.fail("cam b: rms 4.0 px", "check the corners")
    f.fail("no cross-validation", "")
    verdict, reasons = f.outcome()
    assert verdict == "not reliable: check the corners"
    assert reasons == ["cam a: rms 3.0 px", "cam b: rms 4.0 px", "no cross-validation", "few views"]
