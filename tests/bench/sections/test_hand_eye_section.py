"""The ``hand_eye`` benchmark section: rendered robots, our fit and OpenCV's methods on the same corners, the
summary, the sigma's coverage and the markdown."""

from __future__ import annotations

import math

import numpy as np
import torch

from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.hand_eye import (
    KINEMATIC_SEED,
    OPENCV_METHODS,
    SEED,
    hand_eye_md,
    opencv_hand_eye,
    run_hand_eye,
)
from ccs_kornia.data.scenes.robots import render_hand_eye


def test_hand_eye_section_runs_and_reports():
    assert "hand_eye" in SECTIONS
    sec = run_hand_eye(BenchConfig.tiny(), log=lambda *_: None)
    assert sec["trials_per_setup"] == 1 and sec["seed"] == SEED and len(sec["rows"]) == 2
    assert {r["setup"] for r in sec["rows"]} == {"eye_in_hand", "eye_to_hand"} and sec["real_skipped"] == "not asked"
    ours = sec["summary"]["ours"]
    assert ours["failures"] == 0 and ours["t_mm_max"] < 3.0 and math.isfinite(ours["heldout_px_mean"])
    assert 0.0 <= ours["coverage_axes"] <= 1.0
    assert set(sec["summary"]) == {"ours", *OPENCV_METHODS}
    md = "\n".join(hand_eye_md(sec))
    assert "| ccs_kornia joint fit | 0/2 |" in md and "| OpenCV Tsai |" in md and "Honesty of our 1-sigma" in md
    assert "kinematic" not in sec and "kinematic errors" not in md  # the tiny preset renders no such arm
    # the arms with kinematic errors report as the rendered robots do (their rows here: the tiny run's)
    sec["kinematic"] = {"trials_per_setup": 1, "seed": KINEMATIC_SEED, "rows": sec["rows"], "summary": sec["summary"]}
    md = "\n".join(hand_eye_md(sec))
    assert "Rendered arms with kinematic errors (1 scenes per set-up" in md
    assert md.count("| ccs_kornia joint fit | 0/2 |") == 2
    assert "another model of the robot's error than the estimated noise term on 0 of 2 scenes" in md


def test_opencv_recipe_matches_the_conventions():
    # exact board poses: every OpenCV method gives the true X in the package's convention, both set-ups
    for setup in ("eye_in_hand", "eye_to_hand"):
        s = render_hand_eye(setup, views=8, seed=SEED + 7, noise_px=0.0, joint_noise_deg=0.0)
        T = s.robot_poses.numpy()
        A = np.linalg.inv(T) if setup == "eye_in_hand" else T
        M = np.linalg.inv(s.X.numpy()) @ A @ s.Z.numpy()
        for name in ("park", "rw_shah"):
            X, Z = opencv_hand_eye(setup, T, M, name)
            np.testing.assert_allclose(X, s.X.numpy(), atol=1e-6)
            np.testing.assert_allclose(Z, s.Z.numpy(), atol=1e-6)
    assert torch.is_tensor(s.X)
