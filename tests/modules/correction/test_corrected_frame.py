"""Tests of the corrected-frame helpers (the calibration itself is tested end to end in tests/test_pipeline.py)."""

from __future__ import annotations

import torch

from ccs_kornia.camera import board_object_points, project_points
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.correction.corrected_frame import correction_zoom, select_cameras, with_fields
from ccs_kornia.modules.correction.radial_warp import corrected_radius


def test_correction_zoom_keeps_the_farthest_corner_in_the_frame(device):
    size = (640, 480)
    identity = torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]], device=device)
    assert float(correction_zoom(identity, size)) == 1.0
    barrel = torch.tensor([[1.0, 0.0, 0.3, 0.0, 0.0], [1.0, 0.0, 0.1, 0.0, 0.0]], device=device)
    zoom = float(correction_zoom(barrel, size))
    r = 0.5 * (639**2 + 479**2) ** 0.5 / 640
    # the strongest correction sets the zoom: its corrected corner radius, zoomed, is the original one
    g = float(corrected_radius(torch.tensor([[r]], dtype=torch.float64), barrel[:1].cpu().double()))
    assert 0.5 <= zoom < 1.0 and abs(zoom * g - r) < 1e-6


def test_select_cameras_and_with_fields():
    obj = board_object_points(5, 4, 0.1, dtype=torch.float64)
    K = torch.tensor([[600.0, 0, 330], [0, 610, 230], [0, 0, 1]], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    rvec = 0.4 * (torch.rand(2, 6, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.2, -0.15, 1.5], dtype=torch.float64).expand(2, 6, 3)
    uv = project_points(obj.expand(2, 6, -1, -1), K.expand(2, 6, 3, 3), None, rvec, tvec)
    valid = torch.ones(2, 6, 20, dtype=torch.bool)
    a = CalibrationSolver(model="none")(uv, valid, obj, (640, 480))
    b = with_fields(a, K=a.K + 1.0, rms=a.rms + 1.0)
    assert torch.equal(b.K, a.K + 1.0) and torch.equal(b.rvec, a.rvec) and b.model == a.model
    mixed = select_cameras(torch.tensor([True, False]), a, b)
    assert torch.equal(mixed.K[0], a.K[0]) and torch.equal(mixed.K[1], b.K[1])
    assert torch.equal(mixed.rms, torch.stack([a.rms[0], b.rms[1]]))
    assert torch.equal(mixed.rvec, a.rvec)  # fields that agree stay as they are
