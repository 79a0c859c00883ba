"""Tests of the solver's warm starts: undistorted init corners, a previous result, fixed intrinsics."""

from __future__ import annotations

import pytest
import torch
from _calibration_views import _views

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.geometry.metrics import e_ip
from ccs_kornia.modules.calibration.solver import CalibrationSolver

SIZE = (640, 480)
OBJ = board_object_points(9, 6, 0.025, dtype=torch.float64)


def test_solver_init_corners_initial_and_fixed_intrinsics():
    K = torch.tensor([[430.0, 0.0, 322.0], [0.0, 433.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    dist = torch.tensor([-0.35, 0.12, 0.0, 0.0, -0.02], dtype=torch.float64)
    rvec, tvec = _views(K, 12, 4)
    ideal = project_points(OBJ.expand(12, -1, -1), K.expand(12, 3, 3), None, rvec, tvec)
    uv = project_points(OBJ.expand(12, -1, -1), K.expand(12, 3, 3), dist.expand(12, 5), rvec, tvec)
    valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
    solver = CalibrationSolver()
    plain = solver(uv, valid, OBJ, SIZE)
    started = solver(uv, valid, OBJ, SIZE, init_corners=ideal)
    for r in (plain, started):
        assert float(e_ip(r.K, K)) < 1e-4 and float(r.rms) < 1e-6
    warm = solver(uv, valid, OBJ, SIZE, initial=started)
    torch.testing.assert_close(warm.K, started.K)
    shifted = started.camera.params.clone()
    shifted[0, 0] += 2.0
    from dataclasses import replace

    fixed = solver(uv, valid, OBJ, SIZE, initial=replace(started, camera=started.camera.with_params(shifted)),
                   fix_intrinsics=True)
    assert float(fixed.K[0, 0]) == float(shifted[0, 0]) and float(fixed.rms) > 1e-3
    with pytest.raises(ValueError, match="fix_intrinsics"):
        solver(uv, valid, OBJ, SIZE, fix_intrinsics=True)
    with pytest.raises(ValueError, match="init_corners"):
        solver(uv, valid, OBJ, SIZE, init_corners=ideal[:3])
