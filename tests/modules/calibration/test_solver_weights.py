"""Per-corner weights in the solver (inverse variances from the detector's corner precision)."""

from __future__ import annotations

import pytest
import torch
from _board_views import all_valid, synthetic

from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5
from ccs_kornia.modules.calibration.model_selection import ModelSelection
from ccs_kornia.modules.calibration.quality.diagnostics import cross_validation
from ccs_kornia.modules.calibration.solver import CalibrationSolver


def _noisy_views(seed: int = 3):
    """Views with a little noise everywhere and a few corners off by a pixel (a hard, e.g. shaded, part)."""
    K, obj, uv, _, _ = synthetic(C=1, V=12, noise=0.05, seed=seed)
    g = torch.Generator().manual_seed(seed)
    bad = torch.rand(uv.shape[:-1], generator=g) < 0.08
    uv = uv + bad[..., None] * 1.0 * torch.randn(uv.shape, generator=g, dtype=uv.dtype)
    return K, obj, uv, bad


@pytest.mark.parametrize("model", [OPENCV5, FISHEYE])
def test_uniform_weights_change_nothing(model):
    K, obj, uv, _ = _noisy_views()
    solver = CalibrationSolver(model=model, use_ransac=False)
    plain = solver(uv, all_valid(uv), obj, (640, 480))
    ones = solver(uv, all_valid(uv), obj, (640, 480), weights=torch.ones(uv.shape[:-1], dtype=torch.float64))
    assert bool(plain.success.all()) and bool(ones.success.all())
    torch.testing.assert_close(ones.K, plain.K, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(ones.rms, plain.rms, rtol=1e-9, atol=1e-9)


def test_down_weighted_corners_spoil_the_camera_less():
    K, obj, uv, bad = _noisy_views()
    solver = CalibrationSolver(model=OPENCV5, use_ransac=False)
    plain = solver(uv, all_valid(uv), obj, (640, 480))
    w = torch.where(bad, 0.01, 1.0).to(torch.float64)
    weighted = solver(uv, all_valid(uv), obj, (640, 480), weights=w)
    dropped = solver(uv, ~bad, obj, (640, 480))  # the hard corners left out altogether
    err = lambda r: float((r.K[0] - K[0]).abs().max())  # noqa: E731
    assert err(weighted) < 0.6 * err(plain)
    assert float((weighted.K - dropped.K).abs().max()) < 0.1 * err(plain), "nearly as if they were left out"
    # the RMS stays the plain pixel figure: the weighted fit's is higher (it is not what the fit minimises)
    assert float(weighted.rms[0]) >= float(plain.rms[0]) - 1e-9


def test_weights_reach_model_selection_and_cross_validation():
    K, obj, uv, bad = _noisy_views()
    w = torch.where(bad, 0.01, 1.0).to(torch.float64)
    solvers = {m: CalibrationSolver(model=m, use_ransac=False) for m in (K1K2, OPENCV5)}
    results, chosen, _ = ModelSelection(list(solvers.values()))(uv, all_valid(uv), obj, (640, 480), weights=w)
    direct = solvers[OPENCV5](uv, all_valid(uv), obj, (640, 480), weights=w)
    torch.testing.assert_close(results[OPENCV5].K, direct.K)
    plain = cross_validation(solvers[OPENCV5], uv, all_valid(uv), obj, (640, 480), direct)
    weighted = cross_validation(solvers[OPENCV5], uv, all_valid(uv), obj, (640, 480), direct, weights=w)
    assert not torch.equal(plain["heldout_rms_px"], weighted["heldout_rms_px"]), "the subsets are solved weighted"


def test_weights_shape_is_checked():
    _, obj, uv, _ = _noisy_views()
    with pytest.raises(ValueError, match="weights"):
        CalibrationSolver()(uv, all_valid(uv), obj, (640, 480), weights=torch.ones(3, 4))
