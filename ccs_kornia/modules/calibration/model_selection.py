"""Automatic choice of the camera model by cross-validation (``--model auto``), batched over cameras.

Every candidate model calibrates every camera; each calibration is then judged on views it did not see, and the
preferred model among those that predict them as well as the best one is kept:

1. **held-out reprojection error** (k-fold: each fold's views reprojected with the camera fitted to the other
   views, their poses fitted with that camera held) — a model that over-fits the fitted views does worse here;
2. **which models the data cannot tell apart**: a model ties with the best when its held-out error is within
   :data:`TIE_FLOOR` (relative) of the best, or when its per-view excess over the best (paired over the views both
   held out) is not significant (Wilcoxon's signed-rank test, :data:`TIE_SIGMAS`) — the tolerance comes from the
   held-out error's own spread across the views, not from a fixed percentage;
3. among the tied models the first of :data:`PREFERENCE` (``opencv5``, ``k1k2``, ``fisheye``, ``rational``) whose
   distortion maps the whole image one to one wins (an OpenCV model that folds inside the image, two rays onto one
   pixel, has extrapolated where no pinhole lens does: ``opencv5``'s k3 on two real sets), unless another tied
   model's two **disjoint halves** of the views agree clearly better (their projections over
   the image differ by less than :data:`HALVES_CLEAR_RATIO` of the preferred model's difference, and by
   :data:`HALVES_CLEAR_PX` px less; the best-aligning rotation fitted out; mrcal's cross-validation diff): a model
   that fits as well but extrapolates differently from each half is not kept;
4. a ``rational`` model whose numerator and denominator **cancel** (:func:`radial_cancellation`: over the board
   points its views saw, each of the radial factor's numerator :math:`1 + k_1 r^2 + k_2 r^4 + k_3 r^6` and
   denominator :math:`1 + k_4 r^2 + k_5 r^4 + k_6 r^6` departs from 1 more than :data:`MAX_CANCELLATION` times as far
   as their ratio does) counts as a folding one: it goes after the tied models that do not. Such coefficients are
   not determined by the views: large terms that the other half of the fraction takes back, whose two halves of the
   views may agree because both land on the same ridge of the fit, not because the lens is known; their agreement
   is no reason to prefer the model.

With ``flexible_coverage`` (rig cameras: :class:`~ccs_kornia.pipeline.rig_pipeline.RigPipeline`), the models of
:data:`FLEXIBLE_MODELS` are chosen only for a camera whose boards cover at least that fraction of the image
(:func:`~ccs_kornia.modules.calibration.quality.coverage.image_coverage`), or where no other model ties with the best:
where the boards cover a few percent of an ordinary webcam's image, every model predicts the held-out views alike and
the fold and halves rules judge the extrapolation, where the richer models' extra freedom is unconstrained.

Why this order: a richer model's held-out error comes out a hair lower by chance on noisy corners while its extra
coefficients extrapolate wildly outside the boards, so ``rational`` comes last; ``opencv5`` costs nothing measurable
on a ``k1k2`` lens while ``k1k2`` can double the error of an OpenCV lens, so ``opencv5`` comes first; on fisheye lenses
``fisheye`` and ``rational`` tie on held-out views and only the Kannala-Brandt model extrapolates. The figures:
``docs/measurements.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import torch
from torch import nn

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import (
    CAMERA_MODELS,
    FISHEYE,
    K1K2,
    OPENCV5,
    RATIONAL,
)
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.quality.coverage import image_coverage
from ccs_kornia.modules.calibration.quality.diagnostics import (
    cross_validation,
    pixel_scale,
)
from ccs_kornia.modules.calibration.quality.uncertainty import unprojectable_fraction
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.subset_solutions import SubsetSolutions
from ccs_kornia.runtime.checks import check_same_shape, check_tensor

__all__ = [
    "AUTO_MODELS", "ModelChoice", "model_or_choice", "FLEXIBLE_MODELS", "HALVES_CLEAR_PX", "HALVES_CLEAR_RATIO", "MAX_CANCELLATION",
    "MIN_PAIRED_VIEWS", "ModelSelection", "PREFERENCE", "SOLVE_COST_RANK", "SPLINED", "TIE_FLOOR",
    "TIE_SIGMAS", "choose_models", "narrow_ranking", "radial_cancellation", "rank_models", "tied_with_best",
]

#: the name of the choice that ends every camera splined (``--model splined``, :class:`ModelChoice`'s ``splined``)
SPLINED = "splined"
#: the candidates of the automatic model choice (``--model auto``)
AUTO_MODELS: tuple[CameraModel, ...] = (K1K2, OPENCV5, RATIONAL, FISHEYE)
#: among models the held-out views cannot tell apart, the earliest wins (see the module doc for the order's reasons)
PREFERENCE: tuple[CameraModel, ...] = (OPENCV5, K1K2, FISHEYE, RATIONAL)
#: held-out errors within this fraction of the best always tie (a difference of no practical meaning)
TIE_FLOOR = 0.01
#: a model ties with the best unless its per-view held-out errors exceed the best's by more than this many standard
#: deviations of Wilcoxon's signed-rank statistic (one-sided, about 2 %; robust to one view with a large error)
TIE_SIGMAS = 2.0
#: fewer views held out by both models than this: the relative ``tolerance`` decides the tie
MIN_PAIRED_VIEWS = 6
#: a later tied model replaces an earlier one (in order of preference) only where its halves differ by less than
#: this fraction of the earlier one's ...
HALVES_CLEAR_RATIO = 0.25
#: ... and by at least this many px less (scaled with the image as the verdict's thresholds)
HALVES_CLEAR_PX = 1.0
#: models whose freedom beyond the boards only a wide coverage of the image constrains (``flexible_coverage``): the
#: fisheye model and the OpenCV models of more than five coefficients (``rational``)
FLEXIBLE_MODELS: tuple[CameraModel, ...] = tuple(m for m in AUTO_MODELS if m.is_fisheye or m.num_coeffs > 5)
#: a rational model whose radial numerator and denominator each depart from 1 more than this many times as far as
#: their ratio (over the board points seen) cancel (:func:`radial_cancellation`; the figures on the real sets:
#: ``docs/diagnostics.md``)
MAX_CANCELLATION = 5.0
#: kept for callers of the former rule's keyword: models within this fraction of the best tie when the per-view
#: errors are unknown (fewer than three views held out by both models)
HELDOUT_TOLERANCE = 0.05


def _signed_rank_z(d: list[float]) -> float:
    """Wilcoxon's signed-rank statistic of the differences ``d`` as a z-score (normal approximation; zeros dropped,
    tied magnitudes share their mean rank): large and positive when the differences are mostly positive."""
    d = [x for x in d if x != 0.0]
    n = len(d)
    if n == 0:
        return 0.0
    order = sorted(range(n), key=lambda i: abs(d[i]))
    ranks = [0.0] * n
    i = 0
    while i < n:
        j = i
        while j + 1 < n and abs(d[order[j + 1]]) == abs(d[order[i]]):
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2.0 + 1.0
        i = j + 1
    w = sum(r for r, x in zip(ranks, d) if x > 0)
    mean, var = n * (n + 1) / 4.0, n * (n + 1) * (2 * n + 1) / 24.0
    return (w - mean) / math.sqrt(var)


def tied_with_best(heldout: list[float], view_mse: list[list[float]] | None = None,
                   tolerance: float = HELDOUT_TOLERANCE) -> list[bool]:
    """Per model: does its held-out error tie with the best model's (see the module doc, step 2)?

    Args:
        heldout: held-out RMS per model (px; NaN: not judged).
        view_mse: per model, the per-view held-out mean squared errors (px^2; NaN for views not held out), or
            ``None``: the relative ``tolerance`` decides.
        tolerance: relative band used where fewer than :data:`MIN_PAIRED_VIEWS` views were held out by both
            models.

    Example:
        >>> tied_with_best([0.170, 0.167, 0.168], [[0.03, 0.025, 0.033, 0.02, 0.03, 0.028]] * 3)
        [True, True, True]
        >>> worse = [[0.10, 0.09, 0.08, 0.11, 0.07, 0.09], [0.04, 0.04, 0.04, 0.04, 0.05, 0.03]]
        >>> tied_with_best([0.30, 0.20], worse)
        [False, True]
    """
    finite = [k for k, h in enumerate(heldout) if math.isfinite(h)]
    if not finite:
        return [False] * len(heldout)
    best = min(finite, key=lambda k: (heldout[k], k))
    out = []
    for k, h in enumerate(heldout):
        if not math.isfinite(h):
            out.append(False)
        elif k == best or h <= heldout[best] * (1.0 + TIE_FLOOR):
            out.append(True)
        else:
            pairs = [] if view_mse is None else [
                (a, b) for a, b in zip(view_mse[k], view_mse[best]) if math.isfinite(a) and math.isfinite(b)]
            if len(pairs) < MIN_PAIRED_VIEWS:
                out.append(h <= heldout[best] * (1.0 + tolerance))
            else:
                out.append(_signed_rank_z([a - b for a, b in pairs]) <= TIE_SIGMAS)
    return out


def rank_models(heldout: list[float], halves: list[float], tolerance: float = HELDOUT_TOLERANCE,
                view_mse: list[list[float]] | None = None, halves_clear_px: float = HALVES_CLEAR_PX,
                folds: list[bool] | None = None, cancels: list[bool] | None = None) -> list[int]:
    """Models of one camera from best to worst (indices into the lists, which are given in order of preference).

    The models tied with the best held-out error (:func:`tied_with_best`) come first, in order of preference, except
    that a later tied model whose halves agree clearly better (:data:`HALVES_CLEAR_RATIO`, ``halves_clear_px``) at a
    held-out error within ``tolerance`` of the earlier one's is moved before it; tied models whose distortion folds
    inside the image (``folds``: no inverse over part of it, see
    :func:`~ccs_kornia.modules.calibration.quality.uncertainty.unprojectable_fraction`) or whose rational terms cancel
    (``cancels``: :func:`radial_cancellation` above :data:`MAX_CANCELLATION`) come after the tied ones that do not;
    then the rest by held-out error. Models without a finite held-out error are left out.

    Example:
        >>> rank_models([0.187, 0.181, 0.181, 0.184], [17.3, 2.05, 22.7, 110.0])  # opencv5 k1k2 fisheye rational
        [1, 0, 2, 3]
        >>> rank_models([6.49, 2.28, 0.513, 0.514], [23.1, 28.9, 8.16, 606.0])
        [2, 3, 1, 0]
    """
    finite = [k for k, h in enumerate(heldout) if math.isfinite(h)]
    if not finite:
        return []
    tied = tied_with_best(heldout, view_mse, tolerance)
    inside = [k for k in finite if tied[k]]
    outside = sorted((k for k in finite if not tied[k]), key=lambda k: (heldout[k], k))

    def clearly_better(a: int, b: int) -> bool:  # do a's halves agree clearly better than b's?
        ha = halves[a] if math.isfinite(halves[a]) else math.inf
        hb = halves[b] if math.isfinite(halves[b]) else math.inf
        if math.isinf(ha):
            return False
        return math.isinf(hb) or (ha < HALVES_CLEAR_RATIO * hb and hb - ha > halves_clear_px)

    ranked: list[int] = []
    for group in (False, True):  # the tied models that map the whole image one to one first
        rest = [k for k in sorted(inside)
                if bool((folds is not None and folds[k]) or (cancels is not None and cancels[k])) == group]
        while rest:
            pick = rest[0]
            for k in rest[1:]:  # a later model takes the pick's place only by clearly better halves, at a held-out
                if clearly_better(k, pick) and heldout[k] <= heldout[pick] * (1.0 + tolerance):  # error as good
                    pick = k
            ranked.append(pick)
            rest.remove(pick)
    return ranked + outside


def radial_cancellation(coeffs: torch.Tensor, r2: torch.Tensor, seen: torch.Tensor | None = None) -> torch.Tensor:
    r"""How far a rational model's radial numerator and denominator cancel, per camera.

    Over the points seen, ``min(max|N - 1|, max|D - 1|) / max|N / D - 1|`` for the numerator :math:`N = 1 + k_1 r^2 +
    k_2 r^4 + k_3 r^6` and the denominator :math:`D = 1 + k_4 r^2 + k_5 r^4 + k_6 r^6`: below 1 the fraction
    departs from 1 as far as its larger term does (a lens's distortion), far above 1 both terms are large and the
    fraction small (coefficients the views do not determine).

    Args:
        coeffs: :math:`(C, 8)` OpenCV's coefficients ``k1 k2 p1 p2 k3 k4 k5 k6``.
        r2: :math:`(C, M)` squared radii of the points' undistorted rays in the normalized image.
        seen: :math:`(C, M)` bool, the points that count (default all).

    Returns:
        :math:`(C,)` float64 (NaN where no point counts).

    Example:
        >>> k = torch.tensor([[-8.0, 20.0, 0, 0, 1.0, -7.8, 19.0, 2.0], [-0.3, 0.1, 0, 0, 0, 0.0, 0.0, 0.05]])
        >>> r2 = torch.linspace(0.0, 0.3, 7).expand(2, 7)
        >>> [round(x, 1) for x in radial_cancellation(k, r2).tolist()]
        [19.1, 0.0]
    """
    k, r2 = coeffs.double(), r2.double()
    seen = torch.ones_like(r2, dtype=torch.bool) if seen is None else seen.bool()

    def poly(a, b, c):
        return 1 + a[:, None] * r2 + b[:, None] * r2 ** 2 + c[:, None] * r2 ** 3

    N, D = poly(k[:, 0], k[:, 1], k[:, 4]), poly(k[:, 5], k[:, 6], k[:, 7])

    def largest(x):
        return torch.where(seen, x.abs(), torch.zeros_like(x)).amax(-1)

    out = torch.minimum(largest(N - 1), largest(D - 1)) / largest(N / D - 1).clamp_min(1e-12)
    return torch.where(seen.any(-1), out, torch.full_like(out, float("nan")))


def _cancellation(result: CalibrationResult, object_points: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """(C,) :func:`radial_cancellation` of each camera over the board points of its used views (their rays from the
    fitted poses); 0 for a model without a denominator, NaN for a failed camera."""
    model = result.camera.model
    C = result.rvec.shape[0]
    ok = result.success.cpu().bool()
    if model.is_fisheye or 5 not in getattr(model, "coeff_index", ()):
        return torch.where(ok, torch.zeros(C, dtype=torch.float64), torch.full((C,), float("nan"), dtype=torch.float64))
    R = exp_so3(result.rvec.double().cpu())  # (C, V, 3, 3)
    obj = object_points.double().cpu()
    obj = obj.expand(C, -1, -1) if obj.dim() == 2 else obj
    X = torch.einsum("cvij,cnj->cvni", R, obj) + result.tvec.double().cpu()[:, :, None]
    r2 = (X[..., :2] / X[..., 2:]).pow(2).sum(-1).flatten(1)  # (C, V * N)
    seen = (valid.cpu().bool() & result.used.cpu().bool()[..., None] & (X[..., 2] > 0)).flatten(1)
    out = radial_cancellation(model.dist8(result.camera.params.double().cpu()), r2.nan_to_num(0.0), seen)
    return torch.where(ok, out, torch.full_like(out, float("nan")))


def narrow_ranking(ranking: list[CameraModel], tied: list[CameraModel]) -> list[CameraModel]:
    """The ranking of a camera whose boards cover too little of the image for :data:`FLEXIBLE_MODELS`: the first
    tied model that is not one of them goes first (the ranking as it is when the first is not flexible, or when no
    other model ties).

    Example:
        >>> from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, RATIONAL
        >>> [str(m) for m in narrow_ranking([FISHEYE, K1K2, OPENCV5, RATIONAL], [OPENCV5, K1K2, FISHEYE])]
        ['k1k2', 'fisheye', 'opencv5', 'rational']
        >>> [str(m) for m in narrow_ranking([FISHEYE, K1K2], [FISHEYE])]  # a fisheye lens: nothing else predicts as well
        ['fisheye', 'k1k2']
    """
    supported = [n for n in ranking if n in tied and n not in FLEXIBLE_MODELS]
    if not ranking or ranking[0] not in FLEXIBLE_MODELS or not supported:
        return list(ranking)
    return [supported[0]] + [n for n in ranking if n != supported[0]]


def choose_models(heldout: torch.Tensor, halves: torch.Tensor, tolerance: float = HELDOUT_TOLERANCE,
                  view_mse: torch.Tensor | None = None) -> torch.Tensor:
    r"""Index of the chosen model per camera from the cross-validation figures (see :func:`rank_models`).

    Args:
        heldout: :math:`(M, C)` held-out reprojection RMS (px; NaN: the model could not be judged / failed).
        halves: :math:`(M, C)` RMS difference of the two halves' calibrations (px; NaN: not computed, e.g. too few
            views for two halves: the held-out error alone decides).
        tolerance: relative tie band where the per-view errors are unknown.
        view_mse: optional :math:`(M, C, V)` per-view held-out mean squared errors (px^2, NaN: not held out).

    Returns:
        :math:`(C,)` long, ``-1`` where no model has a finite held-out error.

    Example:
        >>> heldout = torch.tensor([[0.187], [0.181], [0.181], [0.184]])  # opencv5, k1k2, fisheye, rational
        >>> halves = torch.tensor([[17.3], [2.05], [22.7], [110.0]])
        >>> choose_models(heldout, halves).tolist()
        [1]
    """
    check_tensor(heldout, "heldout", ["M", "C"])
    check_same_shape(halves, "halves", heldout, "heldout")
    if view_mse is not None:
        check_tensor(view_mse, "view_mse", ["M", "C", "V"], M=heldout.shape[0], C=heldout.shape[1])
    H, S = heldout.double().cpu().T.tolist(), halves.double().cpu().T.tolist()
    E = None if view_mse is None else view_mse.double().cpu().permute(1, 0, 2).tolist()
    ranks = [rank_models(h, s, tolerance, None if E is None else E[c]) for c, (h, s) in enumerate(zip(H, S))]
    return torch.tensor([r[0] if r else -1 for r in ranks], dtype=torch.long, device=heldout.device)


@dataclass(frozen=True)
class ModelChoice:
    """A choice of model per camera among ``candidates``, by cross-validation (:class:`ModelSelection`): what a
    calibration asks for where it does not name a model (``--model auto``); a selection, not a model.

    Args:
        candidates: some of :data:`AUTO_MODELS` (default all), e.g. without ``RATIONAL`` for a camera whose calibration
            goes to a format that cannot hold it (Kalibr's camchain).
        splined: every calibrated camera ends splined (``--model splined``): the choice among ``candidates`` is the
            spline's start, and the spline is fitted whatever held-out views say (``auto`` tries it only where the
            chosen model's residuals have structure and keeps it where held-out views prefer it).

    Example:
        >>> from ccs_kornia.geometry.models import RATIONAL
        >>> [str(m) for m in ModelChoice(tuple(m for m in AUTO_MODELS if m != RATIONAL)).candidates], str(ModelChoice())
        (['k1k2', 'opencv5', 'fisheye'], 'auto')
        >>> str(ModelChoice(splined=True))
        'splined'
    """

    candidates: tuple[CameraModel, ...] = AUTO_MODELS
    splined: bool = False

    def __post_init__(self) -> None:
        candidates = tuple(dict.fromkeys(self.candidates))
        if not candidates or any(m not in AUTO_MODELS for m in candidates):
            raise ValueError(f"a model choice's candidates must be some of {', '.join(map(str, AUTO_MODELS))}, got "
                             f"{', '.join(map(str, self.candidates)) or 'none'}.")
        object.__setattr__(self, "candidates", candidates)

    @property
    def first(self) -> CameraModel:
        """The candidate the pipeline's stage alone solves with (``OPENCV5`` where it is one)."""
        return OPENCV5 if OPENCV5 in self.candidates else self.candidates[0]

    def __str__(self) -> str:
        return SPLINED if self.splined else "auto"


def model_or_choice(name: str) -> CameraModel | ModelChoice:
    """The model a name stands for, or ``"auto"``'s (``"splined"``'s) :class:`ModelChoice` (where files and the command
    line name one).

    Example:
        >>> model_or_choice("auto"), model_or_choice("k1k2")
        (ModelChoice(candidates=(OpenCVModel('k1k2'), OpenCVModel('opencv5'), OpenCVModel('rational'), KannalaBrandtModel('fisheye')), splined=False), OpenCVModel('k1k2'))
        >>> model_or_choice("splined").splined
        True
    """
    if name == str(ModelChoice()):
        return ModelChoice()
    if name == SPLINED:
        return ModelChoice(splined=True)
    if name not in CAMERA_MODELS:
        raise ValueError(f"unknown model {name!r} (choose from auto, {SPLINED}, {', '.join(CAMERA_MODELS)})")
    return CAMERA_MODELS[name]


#: the models' usual cost (solve and cross-validation) in ascending order, as measured on the real sets;
#: :class:`ModelSelection` hands them to ``map_models`` costliest first: in two worker processes the longest first ends
#: the selection sooner (``docs/measurements.md``)
SOLVE_COST_RANK: dict[CameraModel, int] = {K1K2: 0, OPENCV5: 1, RATIONAL: 2, FISHEYE: 3}


class ModelSelection(nn.Module):
    r"""Calibrate with every candidate model and choose one per camera by cross-validation.

    Args:
        solvers: one solver per candidate model (each with its ``model``), e.g.
            :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` per model of :data:`AUTO_MODELS`.
        folds: folds of the held-out error.
        tolerance: see :func:`choose_models`.
        flexible_coverage: a camera whose boards cover less than this fraction of the image gets a model of
            :data:`FLEXIBLE_MODELS` only where no other model ties with the best (``None``: no such rule).

    Shape:
        corners :math:`(C, V, N, 2)`, valid :math:`(C, V, N)`, object_points :math:`(N, 3)`, image_size ``(W, H)``
        -> ``(results, chosen, table)``: ``{model: CalibrationResult}`` of every model, the chosen model per camera
        (``None`` where no model calibrated it) and per camera the figures by the models' names, as files carry them:
        ``{"chosen", "runner_up", "views" (with a board), "heldout_rms_px": {name: px}, "halves_rms_px": {name: px},
        "tied", "folds_in_image", "cancellation" (:func:`radial_cancellation` of the rational models), "cancels",
        "rule"}``.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> from ccs_kornia.modules.calibration.solver import CalibrationSolver
        >>> obj = board_object_points(7, 5, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[600., 0, 330], [0, 610, 230], [0, 0, 1]], dtype=torch.float64)
        >>> g = torch.Generator().manual_seed(0)
        >>> rv = 0.5 * (torch.rand(10, 3, generator=g, dtype=torch.float64) - 0.5)
        >>> tv = torch.tensor([-0.3, -0.2, 1.5], dtype=torch.float64).expand(10, 3)
        >>> d = torch.tensor([-0.2, 0.05, 0, 0, 0], dtype=torch.float64)
        >>> uv = project_points(obj.expand(10, -1, -1), K.expand(10, 3, 3), d, rv, tv)
        >>> uv = uv + 0.1 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
        >>> from ccs_kornia.geometry.models import K1K2, RATIONAL
        >>> select = ModelSelection([CalibrationSolver(model=m) for m in (K1K2, RATIONAL)])
        >>> _, chosen, table = select(uv[None], torch.ones(1, 10, 35, dtype=torch.bool), obj, (640, 480))
        >>> chosen, table[0]["runner_up"]
        ([OpenCVModel('k1k2')], 'rational')
    """

    def __init__(self, solvers: list[nn.Module], folds: int = 5, tolerance: float = HELDOUT_TOLERANCE,
                 flexible_coverage: float | None = None) -> None:
        super().__init__()
        if not solvers:
            raise ValueError("ModelSelection needs at least one solver.")
        models = [s.model for s in solvers]
        if len(set(models)) != len(models):
            raise ValueError(f"ModelSelection needs one solver per model, got {', '.join(map(str, models))}.")
        self.solvers = nn.ModuleList(solvers)
        self.folds, self.tolerance = int(folds), float(tolerance)
        self.flexible_coverage = None if flexible_coverage is None else float(flexible_coverage)

    def forward(self, corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
                image_size: tuple[int, int], weights: torch.Tensor | None = None,
                map_models: Callable[[Callable, list[CameraModel]], list] | None = None,
                solutions: SubsetSolutions | None = None,
                ) -> tuple[dict[CameraModel, CalibrationResult], list[CameraModel | None], list[dict]]:
        """``map_models(fn, models)``: ``[fn(model) for model in models]`` computed elsewhere (e.g. by worker processes;
        each model's solve and cross-validation are independent); default here, one after the other. ``solutions``
        (:class:`~.subset_solutions.SubsetSolutions`): where each model's solved cross-validation subsets are kept,
        for the diagnostics of the chosen one (:func:`~.diagnostics.diagnose`)."""
        check_tensor(corners, "corners", ["C", "V", "N", "2"])
        check_tensor(valid, "valid", corners.shape[:-1])
        by_model = {s.model: s for s in self.solvers}
        names = list(by_model)

        def solve(name: CameraModel) -> tuple[CalibrationResult, dict | None, Any]:
            solver = by_model[name]
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
        results, heldout, halves, view_mse = {}, [], [], []
        for name in names:
            res, cv, subsets = solved[name]
            if solutions is not None and subsets is not None:
                solutions.put(solutions.key(by_model[name], corners, valid, object_points, image_size, res,
                                            self.folds, weights), subsets)
            results[name] = res
            nan = torch.full(res.success.shape, float("nan"), dtype=torch.float64, device=corners.device)
            if cv is not None:
                ok = res.success.to(nan.device)
                heldout.append(torch.where(ok, cv["heldout_rms_px"].to(nan), nan))
                halves.append(torch.where(ok, cv["cv_rms_px"].to(nan), nan))
                view_mse.append(torch.where(ok[:, None], cv["heldout_view_mse_px2"].to(nan), nan[:, None]))
            else:
                heldout.append(nan)
                halves.append(nan)
                view_mse.append(nan[:, None].expand(-1, corners.shape[1]))
        H, S, E = torch.stack(heldout), torch.stack(halves), torch.stack(view_mse)
        fold = torch.stack([self._folds(results[n], image_size) for n in names])  # (M, C)
        cancel = torch.stack([_cancellation(results[n], object_points, valid) for n in names])  # (M, C)
        # ranked in order of preference: the candidates in PREFERENCE order, any other after them in the order given
        simple = sorted(range(len(names)), key=lambda i: (PREFERENCE.index(names[i]) if names[i] in PREFERENCE
                                                          else len(PREFERENCE), i))
        clear_px = HALVES_CLEAR_PX * pixel_scale(image_size)
        views = valid.any(-1).sum(-1).tolist()
        coverage = self._coverage(results, corners, valid, object_points, image_size)
        chosen: list[CameraModel | None] = []
        table = []
        for c in range(H.shape[1]):
            h, hv, e = H[simple, c].tolist(), S[simple, c].tolist(), E[simple, c].tolist()
            f = fold[simple, c].tolist()
            cancels = (cancel[simple, c] > MAX_CANCELLATION).tolist()
            ranking = [names[simple[k]] for k in rank_models(h, hv, self.tolerance, e, clear_px, f, cancels)]
            tied = [names[simple[k]] for k, t in enumerate(tied_with_best(h, e, self.tolerance)) if t]
            # no model could be judged on held-out views (too few views for the folds): the first that calibrated
            ranking = ranking or [names[i] for i in simple if bool(results[names[i]].success[c])]
            if coverage is not None and float(coverage[c]) < self.flexible_coverage:
                ranking = narrow_ranking(ranking, tied)
            name = ranking[0] if ranking else None
            chosen.append(name)
            table.append({
                "chosen": _name(name), "runner_up": _name(ranking[1]) if len(ranking) > 1 else None,
                "views": int(views[c]),
                "heldout_rms_px": {str(n): _num(H[i, c]) for i, n in enumerate(names)},
                "halves_rms_px": {str(n): _num(S[i, c]) for i, n in enumerate(names)},
                "tied": [str(n) for n in tied], "folds_in_image": [str(n) for i, n in enumerate(names) if bool(fold[i, c])],
                "cancellation": {str(n): _num(cancel[i, c]) for i, n in enumerate(names) if cancel[i, c] != 0},
                "cancels": [str(n) for i, n in enumerate(names) if bool(cancel[i, c] > MAX_CANCELLATION)],
                **({} if coverage is None else {"coverage": float(coverage[c]),
                                                "flexible_coverage": self.flexible_coverage}),
                "rule": f"the first of {', '.join(map(str, PREFERENCE))} whose held-out reprojection error the views cannot tell from the best "
                        f"(within {100 * TIE_FLOOR:g} %, or a per-view excess below {TIE_SIGMAS:g} sigma of a signed-rank test) "
                        "and whose distortion does not fold inside the image (nor its rational terms cancel: "
                        f"numerator and denominator each more than {MAX_CANCELLATION:g}x as far from 1 as their ratio), "
                        "unless another's two halves agree "
                        "clearly better" + ("" if coverage is None else
                                            f"; {' and '.join(map(str, FLEXIBLE_MODELS))} only where the boards cover at least "
                                            f"{100 * self.flexible_coverage:g} % of the image, or no other model ties"),
            })
        return results, chosen, table

    def _coverage(self, results: dict[CameraModel, CalibrationResult], corners: torch.Tensor, valid: torch.Tensor,
                  object_points: torch.Tensor, image_size: tuple[int, int]) -> torch.Tensor | None:
        """(C,) fraction of the image the boards of the views with a board cover (``None`` without
        ``flexible_coverage``)."""
        if self.flexible_coverage is None:
            return None
        seen = valid.sum(-1) >= 4
        return image_coverage(corners.nan_to_num(0.0), valid, object_points, seen, image_size)[:, 0]


    @staticmethod
    def _folds(result: CalibrationResult, image_size: tuple[int, int]) -> torch.Tensor:
        """(C,) bool: the camera's polynomial (OpenCV) distortion has no inverse over part of the image (False where
        it failed). A pinhole lens images the whole sensor, so an OpenCV model that folds inside it has
        extrapolated wrongly; a fisheye lens's image circle may end inside the image, where the Kannala-Brandt
        model legitimately has no inverse: it is never counted as folding."""
        ok = result.success.bool()
        model = result.camera.model
        if model.is_fisheye or not model.num_coeffs:
            return torch.zeros_like(ok)
        return (unprojectable_fraction(result.camera.nan_to_num().to(dtype=torch.float64), image_size) > 0) & ok


def _name(model: CameraModel | None) -> str | None:
    return None if model is None else str(model)


def _num(x: torch.Tensor) -> float | None:
    v = float(x)
    return v if math.isfinite(v) else None
