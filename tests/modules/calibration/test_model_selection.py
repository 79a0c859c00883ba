"""Model choice by cross-validation (``model=ModelChoice()``): the rule, the module, mixed-model batches."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera, project_points
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, RATIONAL
from ccs_kornia.modules.calibration.model_selection import (
    AUTO_MODELS,
    FLEXIBLE_MODELS,
    MAX_CANCELLATION,
    ModelChoice,
    ModelSelection,
    choose_models,
    narrow_ranking,
    radial_cancellation,
    rank_models,
    tied_with_best,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.pipeline.result import select_result

F64 = torch.float64
OBJ = board_object_points(9, 6, 0.03, dtype=F64)
NAN = math.nan


def test_rank_models_rule():
    # held-out alone would pick opencv5; within 5 % the halves' agreement picks k1k2
    assert rank_models([0.200, 0.195, 0.197, 0.3], [1.0, 9.0, 50.0, 2.0]) == [0, 1, 2, 3]
    # a model far worse on held-out views loses whatever its halves say
    assert rank_models([0.5, 0.2], [0.1, 30.0]) == [1, 0]
    # halves not computed: held-out error decides among the contenders; NaN models are left out
    assert rank_models([0.2, 0.201, NAN], [NAN, NAN, 1.0]) == [0, 1]
    assert rank_models([NAN, NAN], [1.0, 2.0]) == []


def test_a_rational_model_whose_terms_cancel_goes_after_the_tied_models():
    # opencv_left without one view: opencv5 and rational tie, rational's halves agree clearly better
    heldout, halves = [0.1710, 0.1797, 0.1795, 0.1697], [5.81, 0.89, 3.63, 0.79]
    assert rank_models(heldout, halves) == [3, 0, 2, 1]
    assert rank_models(heldout, halves, cancels=[False, False, False, True]) == [0, 3, 2, 1]


def _radii(largest: float) -> torch.Tensor:
    return torch.linspace(0.0, largest, 50, dtype=F64).pow(2)[None]


@pytest.mark.parametrize("coeffs, largest, cancels", [
    # fitted to opencv_left without one view: large terms, a mild barrel lens
    ([-12.626, 59.863, 0.0011738, 2.2646e-05, 5.9447, -12.347, 56.31, 23.221], 0.57, True),
    # a GoPro's wide lens and a fisheye lens, fitted on their sets: the denominator does the work
    ([0.034653, 0.013262, -0.00043324, 0.00011306, 0.0059849, 0.30048, -0.02394, 0.017221], 1.82, False),
    ([0.31937, -0.0056291, 0.00042133, -0.00013659, -0.00039647, 0.68146, 0.038437, -0.0028262], 3.84, False),
    ([-0.28, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.6, False),  # no denominator
])
def test_radial_cancellation_tells_cancelling_terms_from_a_lens(coeffs, largest, cancels):
    value = float(radial_cancellation(torch.tensor([coeffs], dtype=F64), _radii(largest))[0])
    assert (value > MAX_CANCELLATION) == cancels
    seen = torch.zeros(1, 50, dtype=torch.bool)
    assert math.isnan(float(radial_cancellation(torch.tensor([coeffs], dtype=F64), _radii(largest), seen)[0]))


def test_choose_models_batched_and_exceptions():
    heldout = torch.tensor([[0.2, NAN], [0.3, NAN]])
    halves = torch.tensor([[1.0, 1.0], [0.5, 1.0]])
    assert choose_models(heldout, halves).tolist() == [0, -1]
    with pytest.raises(ValueError, match="heldout"):
        choose_models(heldout, halves[:1])


def _views(V=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    rv = 0.8 * (torch.rand(V, 3, generator=g, dtype=F64) - 0.5)
    tv = torch.stack([-0.12 + 0.15 * torch.randn(V, generator=g, dtype=F64),
                      -0.08 + 0.1 * torch.randn(V, generator=g, dtype=F64),
                      0.22 + 0.1 * torch.rand(V, generator=g, dtype=F64)], -1)
    return rv, tv, g


def _two_cameras():
    """A fisheye camera (190 degrees across) and a pinhole camera with radial distortion, 12 noisy views each."""
    rv, tv, g = _views()
    K = torch.tensor([[150.0, 0, 321], [0, 151, 239], [0, 0, 1]], dtype=F64)
    D = torch.tensor([0.03, -0.01, 0.004, -0.001], dtype=F64)
    fish = Camera.from_opencv(FISHEYE, K, D).project(OBJ.expand(1, 12, -1, -1), rv[None], tv[None])[0]
    K2 = torch.tensor([[520.0, 0, 322], [0, 522, 241], [0, 0, 1]], dtype=F64)
    rv2, tv2, _ = _views(seed=1)
    tv2 = tv2 * torch.tensor([1.0, 1.0, 2.0], dtype=F64)
    dist = torch.tensor([-0.25, 0.08, 0, 0, 0], dtype=F64)
    pin = project_points(OBJ.expand(12, -1, -1), K2.expand(12, 3, 3), dist, rv2, tv2)
    uv = torch.stack([fish, pin]) + 0.1 * torch.randn(2, 12, 54, 2, generator=g, dtype=F64)
    return uv, K, K2


def test_module_picks_fisheye_for_a_fisheye_and_a_polynomial_model_for_a_pinhole_lens():
    uv, K, K2 = _two_cameras()
    valid = torch.ones(2, 12, 54, dtype=torch.bool) & uv.isfinite().all(-1)
    select = ModelSelection([CalibrationSolver(model=m) for m in AUTO_MODELS])
    results, chosen, table = select(uv, valid, OBJ, (640, 480))
    assert chosen[0] == FISHEYE and chosen[1] in (K1K2, OPENCV5)
    names = {str(m) for m in AUTO_MODELS}
    assert set(results) == set(AUTO_MODELS) and table[0]["chosen"] == "fisheye"
    assert table[1]["runner_up"] in names and table[1]["runner_up"] != str(chosen[1])
    assert set(table[0]["heldout_rms_px"]) == names
    with pytest.raises(ValueError, match=r"corners must be \(C, V, N, 2\), got \(\d+, \d+, 2\)"):
        select(uv[0], valid[0], OBJ, (640, 480))
    with pytest.raises(ValueError, match="at least one"):
        ModelSelection([])
    with pytest.raises(ValueError, match="one solver per model"):
        ModelSelection([CalibrationSolver(model=K1K2), CalibrationSolver(model=K1K2)])


def test_narrow_ranking():
    # boards too narrow: the first tied model that is not flexible goes first, the others keep their order
    assert narrow_ranking([RATIONAL, OPENCV5, K1K2], [RATIONAL, OPENCV5, K1K2]) == [OPENCV5, RATIONAL, K1K2]
    assert narrow_ranking([FISHEYE, RATIONAL, K1K2], [FISHEYE, RATIONAL, K1K2])[0] == K1K2
    # no other model ties (a fisheye lens), or the first is not flexible: unchanged
    assert narrow_ranking([FISHEYE, OPENCV5], [FISHEYE]) == [FISHEYE, OPENCV5]
    assert narrow_ranking([OPENCV5, RATIONAL], [OPENCV5, RATIONAL]) == [OPENCV5, RATIONAL]
    assert narrow_ranking([], []) == [] and set(FLEXIBLE_MODELS) == {RATIONAL, FISHEYE}


def test_flexible_coverage_keeps_the_models_a_lens_needs():
    uv, K, K2 = _two_cameras()
    valid = torch.ones(2, 12, 54, dtype=torch.bool) & uv.isfinite().all(-1)
    # every camera counts as narrow: the fisheye lens keeps fisheye (no other model predicts its views as well)
    select = ModelSelection([CalibrationSolver(model=m) for m in AUTO_MODELS], flexible_coverage=1.01)
    _, chosen, table = select(uv, valid, OBJ, (640, 480))
    assert chosen[0] == FISHEYE and chosen[1] not in FLEXIBLE_MODELS
    for row in table:
        assert 0.0 < row["coverage"] <= 1.0 and row["flexible_coverage"] == 1.01
        assert "only where the boards cover at least 101 %" in row["rule"]
    plain = ModelSelection([CalibrationSolver(model=m) for m in AUTO_MODELS])(uv, valid, OBJ, (640, 480))[2]
    assert "coverage" not in plain[0]


def test_models_solved_elsewhere_give_the_same_choice():
    """``map_models`` (the pipeline's worker processes) only moves where each model's solve runs; it is handed the
    costliest model first (two processes then finish together)."""
    from ccs_kornia.pipeline.workers import worker_pool

    uv, _, _ = _two_cameras()
    valid = torch.ones(2, 12, 54, dtype=torch.bool) & uv.isfinite().all(-1)
    select = ModelSelection([CalibrationSolver(model=m) for m in (K1K2, FISHEYE)])
    results, chosen, table = select(uv, valid, OBJ, (640, 480))
    asked = []

    def in_workers(fn, names):
        asked.extend(names)
        with worker_pool(fn, 2) as run:
            return list(run(names))

    results2, chosen2, table2 = select(uv, valid, OBJ, (640, 480), map_models=in_workers)
    assert asked == [FISHEYE, K1K2] and chosen2 == chosen and table2 == table
    assert list(results2) == list(results) == [K1K2, FISHEYE]  # the results in the solvers' order
    for name in results:
        assert torch.equal(results[name].K, results2[name].K) and torch.equal(results[name].rms, results2[name].rms)


def test_pipeline_auto_mixed_models_in_one_batch():
    """Two cameras, two models: one batched result, each camera's own width of coefficients when selected."""
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
    from ccs_kornia.pipeline.solve import solve_group
    from ccs_kornia.pipeline.solver_input import SolverInput

    uv, K, K2 = _two_cameras()
    pipe = CalibrationPipeline("opencv", model=ModelChoice(), distortion_correction=False)
    inputs = SolverInput.from_views(uv, torch.ones(2, 12, dtype=torch.bool), pipe.solving.object_points((9, 6), 0.03))
    calib, _, _, table = solve_group(pipe.solving, inputs, (9, 6), 0.03, (640, 480), None, None)
    models = calib.camera.models
    assert models[0] == FISHEYE and str(models[1]) == table[1]["chosen"] and calib.dist.shape == (2, 5)
    one, two = select_result(calib, 0), select_result(calib, 1)
    assert one.camera.model == FISHEYE and one.dist.shape == (4,) and one.cov_camera.shape == (8, 8)
    assert two.dist.shape == (5,) and bool((one.K - K).abs().max() < 2) and bool((two.K - K2).abs().max() < 5)
    # the stage alone gives the same as the composition
    alone = pipe.calibrate(uv[1], torch.ones(12, dtype=torch.bool), (9, 6), 0.03, (640, 480))
    assert alone.camera.model == two.camera.model and torch.allclose(alone.K, two.K)


def test_the_preferred_of_the_models_the_held_out_views_cannot_tell_apart():
    # lists in order of preference: opencv5, k1k2, fisheye, rational
    # a normal lens: every model within a hair (per-view errors mixed): opencv5, whatever the others' halves say short
    # of "clearly better"
    views = [[0.028, 0.030, 0.028, 0.029, 0.026, 0.030, 0.027], [0.029, 0.031, 0.027, 0.030, 0.026, 0.032, 0.028],
             [0.029, 0.030, 0.028, 0.030, 0.026, 0.031, 0.027], [0.028, 0.031, 0.027, 0.029, 0.025, 0.031, 0.028]]
    held = [math.sqrt(sum(v) / len(v)) for v in views]
    assert rank_models(held, [1.9, 1.2, 1.5, 0.9], view_mse=views)[0] == 0
    # opencv5 over-fits a small board (its halves disagree far more): k1k2
    assert rank_models(held, [17.3, 2.05, 22.7, 110.0], view_mse=views)[0] == 1
    # fisheye and rational tie on a fisheye lens, the pinhole models are worse in every view: fisheye
    worse = [0.10, 0.12, 0.09, 0.11, 0.13, 0.10, 0.12]
    tie_a = [0.020, 0.022, 0.019, 0.021, 0.023, 0.020, 0.022]
    tie_b = [0.021, 0.021, 0.020, 0.020, 0.024, 0.019, 0.022]
    views = [[x * 0.8 for x in worse], worse, tie_a, tie_b]
    held = [math.sqrt(sum(v) / len(v)) for v in views]
    assert rank_models(held, [25.0, 30.0, 8.0, 600.0], view_mse=views)[:2] == [2, 3]
    # a later model wins the tie only with clearly better halves (under a quarter and a pixel less)
    views = [tie_b, tie_a]
    held = [math.sqrt(sum(v) / len(v)) for v in views]
    assert rank_models(held, [12.0, 2.0], view_mse=views)[0] == 1
    assert rank_models(held, [4.0, 2.0], view_mse=views)[0] == 0
    assert rank_models(held, [1.0, 0.1], view_mse=views)[0] == 0  # a quarter, but not a pixel apart
    assert rank_models(held, [12.0, 2.0], view_mse=views, halves_clear_px=20.0)[0] == 0  # the pixel floor scales


def test_a_model_worse_in_every_held_out_view_does_not_tie():
    good = [0.020, 0.022, 0.019, 0.021, 0.023, 0.020, 0.022, 0.021]
    bad = [x * 1.15 for x in good]  # 7 % worse in RMS, consistently
    held = [math.sqrt(sum(v) / len(v)) for v in (bad, good)]
    assert tied_with_best(held, [bad, good]) == [False, True]
    assert rank_models(held, [1.0, 5.0], view_mse=[bad, good]) == [1, 0]
    # one view far off and the rest equal: a single view does not make a model worse
    spike = good[:-1] + [0.2]
    held = [math.sqrt(sum(v) / len(v)) for v in (good, spike)]
    assert tied_with_best(held, [good, spike]) == [True, True]
    # too few views held out by both: the relative tolerance decides
    assert tied_with_best([0.204, 0.200], [[0.04] * 3, [0.04] * 3]) == [True, True]
    assert tied_with_best([0.300, 0.200], [[0.09] * 3, [0.04] * 3]) == [False, True]


def test_choose_models_with_per_view_errors():
    views = torch.tensor([[[0.10, 0.12, 0.09, 0.11, 0.13, 0.10, 0.12]], [[0.020, 0.022, 0.019, 0.021, 0.023, 0.020,
                                                                         0.022]]], dtype=F64)
    held = views.mean(-1).sqrt()
    assert choose_models(held, torch.ones_like(held), view_mse=views).tolist() == [1]
    assert choose_models(held, torch.ones_like(held)).tolist() == [1]
    with pytest.raises(ValueError, match="view_mse"):
        choose_models(held, torch.ones_like(held), view_mse=views[0])


def test_rendered_opencv_lenses_keep_an_opencv_model():
    """Noisy corners (0.3 px) of an OpenCV five-coefficient lens: auto keeps the OpenCV model or one the halves show
    to be clearly more stable, never ``rational`` by a hair."""
    K = torch.tensor([[520.0, 0, 322], [0, 522, 241], [0, 0, 1]], dtype=F64)
    dist = torch.tensor([-0.28, 0.12, 0.001, -0.001, -0.03], dtype=F64)
    rv, tv, g = _views(V=15, seed=11)
    tv = tv * torch.tensor([1.0, 1.0, 2.0], dtype=F64)
    uv = project_points(OBJ.expand(15, -1, -1), K.expand(15, 3, 3), dist, rv, tv)
    uv = (uv + 0.3 * torch.randn(uv.shape, generator=g, dtype=F64))[None]
    select = ModelSelection([CalibrationSolver(model=m) for m in AUTO_MODELS])
    results, chosen, table = select(uv, uv.isfinite().all(-1), OBJ, (640, 480))
    assert chosen[0] == OPENCV5, table[0]
    assert table[0]["tied"][0] == "opencv5" and "rule" in table[0]
