"""Tests of the corrected-frame helpers (the calibration itself is tested end to end in tests/test_pipeline.py)."""

from __future__ import annotations

from dataclasses import replace

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.geometry.models import OPENCV5, PINHOLE
from ccs_kornia.modules.calibration.corrected_frame import (
    select_cameras,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver


def test_select_cameras():
    obj = board_object_points(5, 4, 0.1, dtype=torch.float64)
    K = torch.tensor([[600.0, 0, 330], [0, 610, 230], [0, 0, 1]], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    rvec = 0.4 * (torch.rand(2, 6, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.2, -0.15, 1.5], dtype=torch.float64).expand(2, 6, 3)
    uv = project_points(obj.expand(2, 6, -1, -1), K.expand(2, 6, 3, 3), None, rvec, tvec)
    valid = torch.ones(2, 6, 20, dtype=torch.bool)
    a = CalibrationSolver(model=PINHOLE)(uv, valid, obj, (640, 480))
    shifted = a.camera.params.clone()
    shifted[:, :4] += 1.0
    b = replace(a, camera=a.camera.with_params(shifted), rms=a.rms + 1.0)
    mixed = select_cameras(torch.tensor([True, False]), a, b)
    assert torch.equal(mixed.K[0], a.K[0]) and torch.equal(mixed.K[1], b.K[1])
    assert torch.equal(mixed.rms, torch.stack([a.rms[0], b.rms[1]]))
    assert torch.equal(mixed.rvec, a.rvec)  # fields that agree stay as they are


def test_calibrate_corrected_reports_the_joint_covariance():
    """The final fit holds the intrinsics; its covariance still has intrinsics rows (from the joint radial
    refinement) and a distortion block at least as wide as the fit's own (the intrinsics' share added)."""
    from ccs_kornia.modules.calibration.centred_radial import centred_radial_distort
    from ccs_kornia.modules.calibration.corrected_frame import calibrate_corrected

    size, board, square = (640, 480), (9, 6), 0.025
    obj = board_object_points(*board, square, dtype=torch.float64)
    K = torch.tensor([[430.0, 0.0, 326.0], [0.0, 433.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    g = torch.Generator().manual_seed(3)
    V = 12
    rvec = 0.6 * (torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.stack([0.1 * (torch.rand(V, generator=g, dtype=torch.float64) - 0.5) - 0.1,
                        0.1 * (torch.rand(V, generator=g, dtype=torch.float64) - 0.5) - 0.06,
                        0.35 + 0.1 * torch.rand(V, generator=g, dtype=torch.float64)], -1)
    ideal = project_points(obj.expand(V, -1, -1), K.expand(V, 3, 3), None, rvec, tvec)
    uv = centred_radial_distort(ideal.reshape(1, -1, 2), torch.tensor([[-0.3, 0.08, 0.0]], dtype=torch.float64), size,
                                torch.tensor([[6.0, -4.0]], dtype=torch.float64)).reshape(1, V, -1, 2)
    uv = uv + 0.1 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
    found = torch.ones(1, V, dtype=torch.bool)
    solver = CalibrationSolver(model=OPENCV5)
    out, _, model_rms = calibrate_corrected(solver, uv, found, torch.tensor([[1.0, 0, 0, 0, 0]]), board, square, size)
    assert bool(out.success[0]) and float(model_rms[0]) < 0.15
    cov = out.cov_camera[0]
    std = cov.diagonal().sqrt()
    assert cov.shape == (9, 9) and bool((std[:4] > 0).all()) and float(std[0] / out.K[0, 0, 0]) < 0.02
    torch.testing.assert_close(std[:4], out.std_intrinsics[0])
    torch.testing.assert_close(std[4:], out.std_dist[0])
    torch.testing.assert_close(cov, cov.T)
    assert float(torch.linalg.eigvalsh(cov / torch.outer(std, std)).min()) > -1e-9  # a covariance (PSD)
    # the distortion given the intrinsics alone (the final fit's own covariance) is narrower
    held = solver(uv, found[..., None].expand(1, V, 54), obj, size, initial=out, fix_intrinsics=True)
    assert bool((held.cov_camera[0, :4].abs().sum() == 0)) and bool((std[4:] >= held.std_dist[0] * (1 - 1e-6)).all())
