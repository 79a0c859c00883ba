"""Whether a model fits: the residuals' structure over the image and the solver's model-fit flag, on rendered views of
a lens the model can follow and of one it cannot."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.geometry.models import OPENCV5, PINHOLE
from ccs_kornia.modules.calibration.quality.residual_structure import (
    ModelFit,
    board_runs,
    residual_structure,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver


def _views(noise=0.05, V=20, seed=0):
    obj = board_object_points(9, 6, 0.03, dtype=torch.float64)
    K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
    dist = torch.tensor([-0.3, 0.1, 0, 0, 0], dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    rvec = 0.8 * (torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.12, -0.08, 0.35], dtype=torch.float64) + 0.1 * (
        torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5)
    uv = project_points(obj.expand(V, -1, -1), K.expand(V, 3, 3), dist.expand(V, 5), rvec, tvec)
    return obj, uv + noise * torch.randn(uv.shape, generator=g, dtype=torch.float64)


def test_a_model_that_cannot_follow_the_lens_is_flagged():
    obj, uv = _views()
    good = CalibrationSolver(model=OPENCV5)(uv, None, obj, (640, 480))
    bad = CalibrationSolver(model=PINHOLE)(uv, None, obj, (640, 480))
    assert bool(good.success) and int(good.model_fit) == ModelFit.FITS
    assert bool(bad.success) and int(bad.model_fit) == ModelFit.DOES_NOT_FIT  # success alone does not say it
    record = bad.residual_structure()
    assert record["model_fit"] == "does not fit" and record["noise_ratio"] > 8
    assert record["cells_significant"] > record["cells"] // 2 and record["rms_cell_means_px"] > 1.0
    fine = good.residual_structure()
    assert fine["noise_ratio"] < 2 and fine["cells_significant"] <= 3 and fine["rms_cell_means_px"] < 0.05
    # the corners' noise measured on the board is the rendered noise (0.05 px per coordinate: 0.059 typical length)
    assert 0.04 < fine["corner_noise_px"] < 0.08


def test_an_exact_fit_is_not_structure():
    obj, uv = _views(noise=0.0)
    res = CalibrationSolver(model=OPENCV5)(uv, None, obj, (640, 480))
    assert int(res.model_fit) == ModelFit.FITS and float(res.structure_rms) < 1e-6


def test_cells_and_runs():
    obj = board_object_points(4, 3, 1.0, dtype=torch.float64)
    assert len(board_runs(obj)) == 3  # one per row of 4, none along columns of 3
    corners = torch.tensor([[[[10.0, 10.0], [590.0, 390.0]]]], dtype=torch.float64).expand(1, 30, 2, 2)
    residuals = torch.tensor([[[[1.0, 0.0], [0.0, 0.0]]]], dtype=torch.float64).expand(1, 30, 2, 2).clone()
    residuals = residuals + 0.01 * torch.randn(residuals.shape, generator=torch.Generator().manual_seed(1),
                                               dtype=torch.float64)
    s = residual_structure(residuals, corners, torch.ones(1, 30, 2, dtype=torch.bool), (600, 400))
    assert int(s.cells) == 2 and int(s.significant) == 1 and abs(float(s.worst) - 1.0) < 0.01
