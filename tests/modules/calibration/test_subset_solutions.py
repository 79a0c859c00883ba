"""The cross-validation's solved subsets kept from the model selection for the diagnostics of the same calibration."""

from __future__ import annotations

import pytest
import torch
from test_model_selection import OBJ, _two_cameras

from ccs_kornia.geometry.models import K1K2, OPENCV5
from ccs_kornia.modules.calibration.model_selection import ModelSelection
from ccs_kornia.modules.calibration.quality.diagnostics import (
    cross_validation,
    diagnose,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.pipeline.workers import worker_pool

SIZE = (640, 480)


class CountingSolver(CalibrationSolver):
    calls = 0

    def forward(self, *args, **kwargs):
        CountingSolver.calls += 1
        return super().forward(*args, **kwargs)


def _pinhole():
    uv = _two_cameras()[0][1:]
    return uv, torch.ones(1, 12, 54, dtype=torch.bool) & uv.isfinite().all(-1)


def test_a_second_cross_validation_reuses_the_subsets_and_gives_the_same_figures():
    uv, valid = _pinhole()
    solver = CountingSolver(model=OPENCV5)
    res = solver(uv, valid, OBJ, SIZE)
    kept = SubsetSolutions()
    CountingSolver.calls = 0
    first = cross_validation(solver, uv, valid, OBJ, SIZE, res, solutions=kept)
    assert CountingSolver.calls == 1
    again = cross_validation(solver, uv.clone(), valid.clone(), OBJ, SIZE, res, solutions=kept)
    assert CountingSolver.calls == 1  # the subsets were not solved again
    plain = cross_validation(solver, uv, valid, OBJ, SIZE, res)
    for key, value in plain.items():
        torch.testing.assert_close(first[key], value, rtol=0, atol=0, equal_nan=True)
        torch.testing.assert_close(again[key], value, rtol=0, atol=0, equal_nan=True)


@pytest.mark.parametrize("change", ["corners", "weights", "folds", "solver", "calibration", "mask"])
def test_other_inputs_are_solved_again(change):
    uv, valid = _pinhole()
    solver = CountingSolver(model=OPENCV5)
    res = solver(uv, valid, OBJ, SIZE)
    kept = SubsetSolutions()
    cross_validation(solver, uv, valid, OBJ, SIZE, res, solutions=kept)
    args = {"solver": solver, "corners": uv, "valid": valid, "result": res, "folds": 5, "weights": None}
    if change == "corners":
        args["corners"] = uv + 1e-9
    elif change == "weights":
        args["weights"] = torch.ones(1, 12, 54, dtype=torch.float64)
    elif change == "folds":
        args["folds"] = 4
    elif change == "solver":
        args["solver"] = CountingSolver(model=OPENCV5)
    elif change == "calibration":
        args["result"] = solver(uv[:, :11], valid[:, :11], OBJ, SIZE)
        args["corners"], args["valid"] = uv[:, :11], valid[:, :11]
    else:
        args["valid"] = valid.clone()
        args["valid"][0, 3, :5] = False
    CountingSolver.calls = 0
    cross_validation(args["solver"], args["corners"], args["valid"], OBJ, SIZE, args["result"], args["folds"],
                     weights=args["weights"], solutions=kept)
    assert CountingSolver.calls == 1


def test_model_selection_keeps_the_subsets_for_the_diagnostics():
    """The selection's subsets (solved in worker processes) reach ``diagnose``: the same figures, no solve."""
    uv, valid = _pinhole()
    solvers = {m: CountingSolver(model=m) for m in (K1K2, OPENCV5)}
    kept = SubsetSolutions()

    def in_workers(fn, names):
        with worker_pool(fn, 2) as run:
            return list(run(names))

    results, chosen, _ = ModelSelection(list(solvers.values()))(uv, valid, OBJ, SIZE, map_models=in_workers, solutions=kept)
    res = results[chosen[0]]
    CountingSolver.calls = 0
    figures = diagnose(res, uv, valid, OBJ, SIZE, solver=solvers[chosen[0]], solutions=kept)
    assert CountingSolver.calls == 0
    assert figures == diagnose(res, uv, valid, OBJ, SIZE, solver=solvers[chosen[0]])
    assert CountingSolver.calls == 1
