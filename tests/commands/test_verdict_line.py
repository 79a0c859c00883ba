"""The lines the commands print from a camera's figures: the verdict line."""

from __future__ import annotations

from ccs_kornia.commands._messages import verdict_line


def test_the_verdict_line_repeats_the_halves():
    halves = ("two halves of the views disagree by 24.1 px RMS over the image (0.11 px where the boards were): outside "
              "the boards these views do not determine the distortion")
    quality = {"verdict": "usable", "heldout_rms_px": 0.167, "cv_covered_rms_px": 0.11,
               "reasons": [halves, "projection uncertainty up to 3.0 px outside the boards"]}
    line = verdict_line(quality)
    assert line.startswith("verdict: usable (held-out views 0.167 px") and line.endswith("determine the distortion")
    assert "projection uncertainty" not in line
