"""Automatic choice of the camera model by cross-validation (``--model auto``), batched over cameras.

Every candidate model calibrates every camera; each calibration is then judged on views it did not see:

1. **held-out reprojection error** (k-fold: each fold's views reprojected with the camera fitted to the other
   views, their poses fitted with that camera held) — a model that over-fits the fitted views does worse here;
2. among the models within ``tolerance`` (relative) of the best held-out error, the one whose calibrations from
   two **disjoint halves** of the views agree best (RMS difference of their projections over the image, the
   best-aligning rotation fitted out; mrcal's cross-validation diff). Equally good fits are told apart by how
   stable they are where the boards were not: an over-parameterised model extrapolates differently from each
   half.

Measured on the real sets (``docs/benchmarks.md``): held-out error alone picks ``opencv5`` for the 24-corner
Sony board (fx 707 against the published 701) and cannot tell ``rational`` from ``fisheye`` on the ROS fisheye
set (0.514 vs 0.513 px); with the halves' agreement (17 vs 2 px; 606 vs 8 px) both go right.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import torch
from torch import nn

from ccs_kornia.modules.calibration.diagnostics import cross_validation
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions

__all__ = ["AUTO_MODELS", "HELDOUT_TOLERANCE", "ModelSelection", "SOLVE_COST_RANK", "choose_models", "rank_models"]

#: the candidates of ``model="auto"``, simplest first (ties go to the earlier one)
AUTO_MODELS: tuple[str, ...] = ("k1k2", "opencv5", "rational", "fisheye")
#: models whose held-out error is within this fraction of the best are compared by the halves' agreement
HELDOUT_TOLERANCE = 0.05


def rank_models(heldout: list[float], halves: list[float], tolerance: float = HELDOUT_TOLERANCE) -> list[int]:
    """Models of one camera from best to worst: those within ``tolerance`` of the best held-out error by the halves'
    disagreement (then held-out error, then order), the rest by held-out error; models without a finite held-out
    error are left out."""
    finite = [k for k, h in enumerate(heldout) if math.isfinite(h)]
    if not finite:
        return []
    best = min(heldout[k] for k in finite)
    inside = [k for k in finite if heldout[k] <= best * (1.0 + tolerance)]
    outside = [k for k in finite if k not in inside]

    def agreement(k: int) -> tuple[float, float, int]:
        return (halves[k] if math.isfinite(halves[k]) else math.inf, heldout[k], k)

    return sorted(inside, key=agreement) + sorted(outside, key=lambda k: (heldout[k], k))


def choose_models(heldout: torch.Tensor, halves: torch.Tensor, tolerance: float = HELDOUT_TOLERANCE) -> torch.Tensor:
    r"""Index of the chosen model per camera from the cross-validation figures (see :func:`rank_models`).

    Args:
        heldout: :math:`(M, C)` held-out reprojection RMS (px; NaN: the model could not be judged / failed).
        halves: :math:`(M, C)` RMS difference of the two halves' calibrations (px; NaN: not computed, e.g. too few
            views for two halves: the held-out error alone decides).
        tolerance: relative band above the best held-out error within which models compete on ``halves``.

    Returns:
        :math:`(C,)` long, ``-1`` where no model has a finite held-out error.

    Example:
        >>> heldout = torch.tensor([[0.181], [0.187], [0.184], [0.181]])  # k1k2, opencv5, rational, fisheye
        >>> halves = torch.tensor([[2.05], [17.3], [110.0], [22.7]])
        >>> choose_models(heldout, halves).tolist()
        [0]
    """
    if heldout.shape != halves.shape or heldout.dim() != 2:
        raise ValueError(f"heldout and halves must both be (M, C), got {tuple(heldout.shape)} and {tuple(halves.shape)}.")
    H, S = heldout.double().cpu().T.tolist(), halves.double().cpu().T.tolist()
    ranks = [rank_models(h, s, tolerance) for h, s in zip(H, S)]
    return torch.tensor([r[0] if r else -1 for r in ranks], dtype=torch.long, device=heldout.device)


#: the models' usual cost (solve and cross-validation) in ascending order; :class:`ModelSelection` hands them to
#: ``map_models`` costliest first. Measured on five real sets (s, one process each): fisheye 0.18-0.53, rational
#: 0.16-0.46, opencv5 0.10-0.31, k1k2 0.07-0.22; in two worker processes the longest first ends the selection
#: sooner (udacity_camera_cal 0.62 -> 0.42 s, udacity_gopro_wide 0.82 -> 0.66 s)
SOLVE_COST_RANK = {"k1k2": 0, "opencv5": 1, "rational": 2, "fisheye": 3}


class ModelSelection(nn.Module):
    r"""Calibrate with every candidate model and choose one per camera by cross-validation.

    Args:
        solvers: ``{model name: solver}``, e.g. :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`
            per model of :data:`AUTO_MODELS`.
        folds: folds of the held-out error.
        tolerance: see :func:`choose_models`.

    Shape:
        corners :math:`(C, V, N, 2)`, valid :math:`(C, V, N)`, object_points :math:`(N, 3)`, image_size ``(W, H)``
        -> ``(results, chosen, table)``: ``{name: CalibrationResult}`` of every model, the chosen name per camera
        (``None`` where no model calibrated it) and per camera ``{"chosen", "runner_up", "views" (with a board),
        "heldout_rms_px": {name: px}, "halves_rms_px": {name: px}, "rule"}``.

    Example:
        >>> from ccs_kornia.camera import board_object_points, project_points
        >>> from ccs_kornia.modules.calibration.solver import CalibrationSolver
        >>> obj = board_object_points(7, 5, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[600., 0, 330], [0, 610, 230], [0, 0, 1]], dtype=torch.float64)
        >>> g = torch.Generator().manual_seed(0)
        >>> rv = 0.5 * (torch.rand(10, 3, generator=g, dtype=torch.float64) - 0.5)
        >>> tv = torch.tensor([-0.3, -0.2, 1.5], dtype=torch.float64).expand(10, 3)
        >>> d = torch.tensor([-0.2, 0.05, 0, 0, 0], dtype=torch.float64)
        >>> uv = project_points(obj.expand(10, -1, -1), K.expand(10, 3, 3), d, rv, tv)
        >>> uv = uv + 0.1 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
        >>> select = ModelSelection({m: CalibrationSolver(model=m) for m in ("k1k2", "rational")})
        >>> _, chosen, table = select(uv[None], torch.ones(1, 10, 35, dtype=torch.bool), obj, (640, 480))
        >>> chosen, table[0]["runner_up"]
        (['k1k2'], 'rational')
    """

    def __init__(self, solvers: dict[str, nn.Module], folds: int = 5, tolerance: float = HELDOUT_TOLERANCE) -> None:
        super().__init__()
        if not solvers:
            raise ValueError("ModelSelection needs at least one solver.")
        self.solvers = nn.ModuleDict(solvers)
        self.folds, self.tolerance = int(folds), float(tolerance)

    def forward(self, corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
                image_size: tuple[int, int], weights: torch.Tensor | None = None,
                map_models: Callable[[Callable, list[str]], list] | None = None,
                solutions: SubsetSolutions | None = None,
                ) -> tuple[dict[str, CalibrationResult], list[str | None], list[dict]]:
        """``map_models(fn, names)``: ``[fn(name) for name in names]`` computed elsewhere (e.g. by worker processes;
        each model's solve and cross-validation are independent); default here, one after the other. ``solutions``
        (:class:`~.subset_solutions.SubsetSolutions`): where each model's solved cross-validation subsets are kept,
        for the diagnostics of the chosen one (:func:`~.diagnostics.diagnose`)."""
        if corners.dim() != 4 or valid.shape != corners.shape[:-1]:
            raise ValueError(f"Expected corners (C, V, N, 2) and valid (C, V, N), got {tuple(corners.shape)} and "
                             f"{tuple(valid.shape)}.")
        names = list(self.solvers.keys())

        def solve(name: str) -> tuple[CalibrationResult, dict | None, Any]:
            solver = self.solvers[name]
            res = solver(corners, valid, object_points, image_size, weights=weights)
            if not bool(res.success.any()):
                return res, None, None
            kept = SubsetSolutions(1)
            cv = cross_validation(solver, corners, valid, object_points, image_size, res, self.folds, weights=weights,
                                  solutions=kept)
            # the subsets' solution travels back with the figures (from a worker process too): ``solutions`` keeps it
            return res, cv, kept.latest()

        # costliest first, so worker processes finish together (the results do not depend on the order)
        order = sorted(names, key=lambda n: -SOLVE_COST_RANK.get(n, 0))
        solved = dict(zip(order, (map_models or (lambda fn, items: [fn(item) for item in items]))(solve, order)))
        results, heldout, halves = {}, [], []
        for name in names:
            res, cv, subsets = solved[name]
            if solutions is not None and subsets is not None:
                solutions.put(solutions.key(self.solvers[name], corners, valid, object_points, image_size, res,
                                            self.folds, weights), subsets)
            results[name] = res
            nan = torch.full(res.success.shape, float("nan"), dtype=torch.float64, device=corners.device)
            if cv is not None:
                ok = res.success.to(nan.device)
                heldout.append(torch.where(ok, cv["heldout_rms_px"].to(nan), nan))
                halves.append(torch.where(ok, cv["cv_rms_px"].to(nan), nan))
            else:
                heldout.append(nan)
                halves.append(nan)
        H, S = torch.stack(heldout), torch.stack(halves)
        views = valid.any(-1).sum(-1).tolist()
        chosen: list[str | None] = []
        table = []
        for c in range(H.shape[1]):
            ranking = [names[k] for k in rank_models(H[:, c].tolist(), S[:, c].tolist(), self.tolerance)]
            # no model could be judged on held-out views (too few views for the folds): the first that calibrated
            ranking = ranking or [n for n in names if bool(results[n].success[c])]
            name = ranking[0] if ranking else None
            chosen.append(name)
            table.append({
                "chosen": name, "runner_up": ranking[1] if len(ranking) > 1 else None, "views": int(views[c]),
                "heldout_rms_px": {n: _num(H[i, c]) for i, n in enumerate(names)},
                "halves_rms_px": {n: _num(S[i, c]) for i, n in enumerate(names)},
                "rule": f"lowest disagreement of two halves among models within {100 * self.tolerance:g} % of the "
                        "best held-out reprojection error",
            })
        return results, chosen, table


def _num(x: torch.Tensor) -> float | None:
    v = float(x)
    return v if math.isfinite(v) else None
