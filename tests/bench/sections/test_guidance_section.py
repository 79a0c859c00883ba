"""The ``guidance`` benchmark section: simulated people against the truth, ROS's rule as ROS states it, and the
markdown."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.guidance import (
    BOARD,
    SQUARE,
    _camera,
    _inside,
    _project,
    _random_stream,
    _ros_bars_full,
    guidance_md,
    projection_error,
    ros_parameters,
    run_guidance,
)
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.modules.calibration.quality.next_pose import MIN_SEEN


def test_ros_parameters_as_ros_computes_them():
    # a 200 x 100 px board at (100..300, 100..200) of a 640 x 480 image, square: no skew
    c = np.array([[x, y] for y in (100.0, 200.0) for x in (100.0, 300.0)])
    x, y, size, skew = ros_parameters(c, (2, 2), (640, 480))
    border = math.sqrt(200 * 100)
    assert x == pytest.approx((200 - border / 2) / (640 - border))
    assert y == pytest.approx((150 - border / 2) / (480 - border))
    assert size == pytest.approx(math.sqrt(200 * 100 / (640 * 480)))
    assert skew == 0.0
    # the right edge leaned by 0.1 rad from the vertical: skew 2 x 0.1
    c2 = c.copy()
    c2[3] = c2[1] + 100 * np.array([math.sin(0.1), math.cos(0.1)])
    assert ros_parameters(c2, (2, 2), (640, 480))[3] == pytest.approx(0.2, abs=1e-9)
    # the bars: X and Y spread over 0.7, size over 0.4, skew over 0.5
    assert _ros_bars_full([[0.1, 0.1, 0.4, 0.5], [0.8, 0.8, 0.2, 0.0]])
    assert not _ros_bars_full([[0.1, 0.1, 0.3, 0.5], [0.8, 0.8, 0.2, 0.0]])


def test_projection_error_is_zero_for_the_truth():
    truth = _camera("wide")
    assert float(projection_error(truth, truth)) == pytest.approx(0.0, abs=1e-9)
    shifted = truth.with_params(truth.params + 0.0)
    shifted.params[0, 0] += 1.0
    assert float(projection_error(truth, shifted)) > 0.05


def test_guidance_section_runs_and_reports():
    assert "guidance" in SECTIONS
    sec = run_guidance(BenchConfig.tiny(), log=lambda *_: None)
    c = sec["cameras"]["normal"]
    assert sec["trials"] == 1 and c["counts"] == [4, 6, 8]
    assert set(c["people"]) == {"guided", "ros", "random", "random_partial"}
    for name in ("ros", "random", "random_partial"):
        g, q = c["people"]["guided"]["median_frames"], c["people"][name]["median_frames"]
        assert c[f"fewer_frames_than_{name}"] == pytest.approx(1.0 - g / q)
    for p in c["people"].values():
        assert len(p["median_px"]) == 3 and all(math.isfinite(e) and 0 < e < 20 for e in p["median_px"])
    assert c["target_px"] > 0 and len(c["instructions"]) >= 3 and all(", " in s for s in c["instructions"])
    md = "\n".join(guidance_md(sec))
    assert "| normal |" in md and "| guided |" in md and "| random, partial boards |" in md
    header = next(line for line in md.splitlines() if line.startswith("| camera |"))
    row = next(line for line in md.splitlines() if line.startswith("| normal |"))
    assert "fewer than random, partial boards" in header and row.count("|") == header.count("|")


def test_random_poses_with_partial_boards():
    truth = _camera("normal")
    obj = board_object_points(*BOARD, SQUARE, dtype=torch.float64)
    whole = _project(truth, obj, *_random_stream(truth, obj, torch.Generator().manual_seed(0), 64))
    assert bool(_inside(whole, 1.0).all())
    rvec, tvec = _random_stream(truth, obj, torch.Generator().manual_seed(0), 64, min_seen=MIN_SEEN)
    seen = _inside(_project(truth, obj, rvec, tvec), 1.0).double().mean(-1)
    assert rvec.shape == (64, 3) and bool((seen >= MIN_SEEN).all())
    assert bool((seen < 1).any())  # some boards partly beyond the image's edge
