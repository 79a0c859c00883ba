"""Is this calibration good? Projection uncertainty, cross-validation, held-out error and a verdict.

Reprojection RMS alone does not answer it (four copies of one photo fit to 0.14 px). Following mrcal, this
module reports, per camera (batched like the solver):

* **projection uncertainty** (:func:`projection_uncertainty`): the covariance of the camera parameters
  (intrinsics and distortion jointly, ``CalibrationResult.cov_camera``) propagated through the projection of
  a fixed ray, in px, at the image centre, the corners and over a grid;
* **cross-validation** (:func:`cross_validation`): two calibrations from disjoint halves of the views (solved
  as extra cameras of one solver call) and the difference of their projections across the image, in px,
  with the difference their covariances predict;
* **held-out error**: ``k``-fold, each fold's views reprojected by the camera fitted on the other folds
  (their poses fitted with the camera fixed), RMS in px;
* **degeneracy checks** (:mod:`~ccs_kornia.modules.calibration.quality.degeneracy`, run by the solver);
* a **verdict** (:func:`verdict`) ``good`` / ``usable`` / ``not reliable`` with its reasons and advice.

:func:`diagnose` returns all of it as a JSON-able dict per camera (keys in its docstring). The thresholds of
:class:`VerdictThresholds` are measured choices; the measurements are in ``docs/diagnostics.md``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import torch
from torch import nn

from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.quality.coverage import covered_pixels
from ccs_kornia.modules.calibration.quality.degeneracy import (
    CHECKS,
    issues_from_tensors,
)
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    projection_difference,
    projection_uncertainty,
)
from ccs_kornia.modules.calibration.quality.verdict import Findings
from ccs_kornia.modules.calibration.subset_solutions import (
    SubsetSolutions,
    solve_subsets,
)

__all__ = ["HALVES_DISAGREE", "image_points", "projection_uncertainty", "projection_difference", "split_views", "cross_validation",
           "VerdictThresholds", "verdict", "diagnose", "CalibrationDiagnostics"]


def _nanrms(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    return x.pow(2).nanmean(dim).sqrt()


def _nanmax(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    m = x.nan_to_num(float("-inf")).amax(dim)
    return torch.where(m == float("-inf"), torch.full_like(m, float("nan")), m)


def split_views(used: torch.Tensor, parts: int) -> torch.Tensor:
    r"""Deal the used views of each camera round-robin into ``parts`` disjoint subsets.

    Args:
        used: :math:`(C, V)` bool.
        parts: number of subsets.

    Returns:
        :math:`(C, parts, V)` bool; subset ``p`` holds the used views of rank ``p, p + parts, ...``.

    Example:
        >>> split_views(torch.tensor([[True, False, True, True, True]]), 2).int().tolist()
        [[[1, 0, 0, 1, 0], [0, 0, 1, 0, 1]]]
    """
    rank = used.long().cumsum(-1) - 1
    p = torch.arange(parts, device=used.device)[None, :, None]
    return used[:, None] & (rank[:, None] % parts == p)


def cross_validation(
    solver: nn.Module,
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    result,
    folds: int = 5,
    grid: tuple[int, int] = (16, 12),
    fit: torch.Tensor | None = None,
    weights: torch.Tensor | None = None,
    solutions: SubsetSolutions | None = None,
) -> dict[str, torch.Tensor]:
    r"""Split-half cross-validation and k-fold held-out reprojection error, in one batched solver call.

    Args:
        solver: the :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` that made ``result`` (its options
            are reused; any callable ``(corners, valid, object_points, image_size) -> result`` works).
        corners: :math:`(C, V, N, 2)` px, as given to the solver.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)`.
        image_size: ``(W, H)``.
        result: the solver's batched result (``K``, ``dist``, ``rvec``, ``tvec``, ``used``, ``rms``).
        folds: folds of the held-out error (at most the number of used views).
        grid: pixels of the comparison grid.
        fit: :math:`(C, G)` bool, grid pixels over which the rotation between the halves is fitted (``None``: all;
            :func:`diagnose` passes where the boards were, so a wide lens's extrapolated rim does not set it).
        weights: optional :math:`(C, V, N)` per-corner weights the solver was given (the subsets get theirs).
        solutions: where the subsets' solutions are kept (:class:`~.subset_solutions.SubsetSolutions`): the solver
            call is skipped when one for the same inputs is there, and this one is added otherwise.

    Returns:
        dict of :math:`(C,)` tensors (NaN where a half or fold could not be calibrated): ``cv_rms_px`` and
        ``cv_max_px`` (difference of the two halves' projections over the grid, the best-aligning rotation
        fitted out), ``cv_expected_rms_px`` (the RMS difference their covariances predict), ``heldout_rms_px``,
        ``heldout_views``; per view :math:`(C, V)` ``heldout_view_mse_px2`` (mean squared held-out error of each
        view's corners, NaN for views not held out); and per grid pixel :math:`(C, G)` ``cv_grid_px`` and ``cv_expected_grid_px`` (RMS
        predicted), with ``grid_pixels`` :math:`(G, 2)`.
    """
    C, V, N = valid.shape
    used = result.used.bool()
    n_used = int(used.sum(-1).max()) if used.numel() else 0
    k = max(2, min(int(folds), n_used))
    halves = split_views(used, 2)
    fold = split_views(used, k)
    train = used[:, None] & ~fold
    subsets = torch.cat([halves, train], 1)  # (C, 2 + k, V)
    warm = torch.arange(2 + k, device=corners.device) >= 2  # the k-fold training sets, not the halves
    key = None if solutions is None else solutions.key(solver, corners, valid, object_points, image_size, result,
                                                       folds, weights)
    sub = None if key is None else solutions.get(key)
    if sub is None:
        sub = solve_subsets(solver, corners, valid, object_points, image_size, subsets, result, warm, weights)
        if key is not None:
            solutions.put(key, sub)
    S = 2 + k
    D = sub.dist.shape[-1]
    ok = sub.success.reshape(C, S)
    px = image_points(image_size, grid).to(corners.device)
    first = torch.arange(C, device=corners.device) * S  # camera c's subset s is at c * S + s

    # split halves
    cam_a, cam_b = sub.camera[first].nan_to_num(), sub.camera[first + 1].nan_to_num()
    fit = torch.ones(px.shape[0], dtype=torch.bool, device=px.device) if fit is None else fit.to(px.device)
    diff = projection_difference(cam_a, cam_b, px, compensate_rotation=fit)
    halves_ok = ok[:, 0] & ok[:, 1]
    nan = torch.full_like(diff[:, 0], float("nan"))
    cv_rms = torch.where(halves_ok, _nanrms(diff), nan)
    cv_max = torch.where(halves_ok, _nanmax(diff), nan)
    expected, expected_grid = nan, torch.full_like(diff, float("nan"))
    if sub.cov_camera is not None:
        cov = sub.cov_camera.reshape(C, S, 4 + D, 4 + D)
        ua = projection_uncertainty(cam_a, cov[:, 0].nan_to_num(0.0), px, worst=False, compensate_rotation=fit)
        ub = projection_uncertainty(cam_b, cov[:, 1].nan_to_num(0.0), px, worst=False, compensate_rotation=fit)
        expected_grid = torch.where(halves_ok[:, None], (2 * (ua**2 + ub**2)).sqrt(), expected_grid)
        expected = torch.where(halves_ok, _nanrms((2 * (ua**2 + ub**2)).sqrt()), nan)

    # held-out views: poses fitted with each fold's camera fixed, started from the full solution's poses
    folds_camera = sub.camera[(first[:, None] + torch.arange(2, S, device=first.device)).reshape(-1)].nan_to_num()
    okf = ok[:, 2:].reshape(C * k)
    held = fold.reshape(C * k, V) & okf[:, None]

    def rep(x: torch.Tensor) -> torch.Tensor:
        """(C, ...) -> (C * k, ...): each camera's tensor once per fold."""
        return x[:, None].expand(C, k, *x.shape[1:]).reshape(C * k, *x.shape[1:])

    obj = object_points if object_points.dim() == 2 else rep(object_points)
    # the poses alone on the LM core, every camera parameter held at its fold's
    model = folds_camera.model
    dtype = folds_camera.dtype
    pose = levenberg_marquardt(
        model, folds_camera.params, rep(result.rvec).nan_to_num(0.0), rep(result.tvec).nan_to_num(0.0), obj,
        rep(corners), (rep(valid) & held[..., None]).to(dtype), free=[False] * model.num_params, dtype=dtype,
    )
    npts = (rep(valid) & held[..., None]).sum(-1).to(dtype)
    sq = torch.where(held, pose.view_rms.nan_to_num(0.0) ** 2 * npts, torch.zeros_like(npts))
    # each used view is held out in exactly one fold: its squared error summed over the folds is its own
    view_sq, view_n = sq.reshape(C, k, V).sum(1), npts.reshape(C, k, V).sum(1)
    sq, npts = view_sq.sum(-1), view_n.sum(-1)
    all_folds = okf.reshape(C, k).all(-1)
    heldout = torch.where(all_folds & (npts > 0), (sq / npts.clamp_min(1)).sqrt(), nan)
    view_mse = torch.where(all_folds[:, None] & (view_n > 0), view_sq / view_n.clamp_min(1), nan[:, None])
    return {
        "cv_rms_px": cv_rms, "cv_max_px": cv_max, "cv_expected_rms_px": expected, "heldout_rms_px": heldout,
        "heldout_view_mse_px2": view_mse,
        "heldout_views": torch.where(all_folds, fold.any(1).sum(-1), torch.zeros_like(all_folds, dtype=torch.long)),
        "cv_grid_px": torch.where(halves_ok[:, None], diff, torch.full_like(diff, float("nan"))), "grid_pixels": px,
        "cv_expected_grid_px": expected_grid,
    }


#: the image diagonal (px) for which the verdict's pixel thresholds are written (640x480)
REFERENCE_DIAGONAL_PX = 800.0
#: the words of the verdict's reasons on the split-half difference (the command's verdict line repeats them)
HALVES_DISAGREE = "two halves of the views disagree"


def pixel_scale(image_size: tuple[int, int]) -> float:
    """Factor on pixel thresholds for an image of ``image_size = (W, H)``: its diagonal over
    :data:`REFERENCE_DIAGONAL_PX`, at least 1.

    The errors the thresholds judge (a lens the model does not fit, poor coverage, a wrong corner) scale with the
    image: the same camera photographed at twice the resolution shows them twice as large in px. The corner noise
    floor (about 0.05-0.1 px) does not, so images smaller than 640x480 keep the thresholds as written.

    Example:
        >>> pixel_scale((640, 480)), pixel_scale((2560, 1920)), pixel_scale((320, 240))
        (1.0, 4.0, 1.0)
    """
    W, H = image_size
    return max(1.0, math.hypot(float(W), float(H)) / REFERENCE_DIAGONAL_PX)


@dataclass
class VerdictThresholds:
    """Limits of the verdict, in px for a 640x480 image (measurements in ``docs/diagnostics.md``); :func:`diagnose`
    scales them with the image (:meth:`scaled`, :func:`pixel_scale`), the ratios stay as they are.

    "Covered" is the part of the image inside some board: there the figures say how good the calibration is;
    outside it the distortion is extrapolated, which the verdict reports as a weakness, not a failure.

    Attributes:
        good_uncertainty_px / usable_uncertainty_px: worst projection uncertainty over the covered image.
        extrapolation_px: worst projection uncertainty over the whole image above which the uncovered parts
            (usually the corners) are reported; a failure when the ``image_coverage`` check flagged the set too.
        cv_ratio: split-half difference over the difference the covariances predict (whole image) above which
            the model does not explain the data (lens not fitting the model, wrong corners); counts only when
            the difference over the covered image also exceeds ``cv_min_px``.
        cv_min_px: see ``cv_ratio``.
        halves_px: split-half difference over the whole image above which the verdict says that the views do not
            determine the distortion outside the boards (a weakness, whatever the covariances predict); for a
            runner-up model the held-out views cannot tell from the chosen one, a note (the camera outside the
            boards may depend on the choice; the chosen model is graded on its own figures).
        heldout_ratio: held-out RMS over the fit RMS above which the fit does not generalise (twice: failure).
        good_rms_px / usable_rms_px: reprojection RMS above which the corners or the model are suspect / wrong.
    """

    good_uncertainty_px: float = 0.5
    usable_uncertainty_px: float = 2.0
    extrapolation_px: float = 2.0
    cv_ratio: float = 3.0
    cv_min_px: float = 0.5
    halves_px: float = 10.0
    heldout_ratio: float = 1.5
    good_rms_px: float = 1.0
    usable_rms_px: float = 2.0

    def scaled(self, factor: float) -> "VerdictThresholds":
        """The same thresholds with every pixel limit multiplied by ``factor`` (ratios unchanged)."""
        return replace(self, **{f.name: getattr(self, f.name) * factor for f in fields(self) if f.name.endswith("_px")})


def verdict(figures: dict, issues: list[dict], thresholds: VerdictThresholds | None = None) -> tuple[str, list[str]]:
    """``("good" | "usable" | "not reliable: <advice>", reasons)`` for one camera.

    Args:
        figures: one camera's figures as in :func:`diagnose` (``rms_px``, ``uncertainty_covered_px``,
            ``uncertainty_max_px``, ``cv_rms_px``, ``cv_covered_rms_px``, ``cv_expected_rms_px``,
            ``cv_covered_expected_rms_px``, ``heldout_rms_px``, ``runner_up``; missing or None allowed).
        issues: that camera's degeneracy issues (``CalibrationResult.issues()[c]``).
        thresholds: :class:`VerdictThresholds`.

    Example:
        >>> verdict({"rms_px": 0.2, "uncertainty_covered_px": 0.2, "uncertainty_max_px": 0.6, "cv_rms_px": 0.3,
        ...          "cv_covered_rms_px": 0.2, "cv_expected_rms_px": 0.3, "heldout_rms_px": 0.21}, [])
        ('good', [])
        >>> verdict({"rms_px": 0.2, "uncertainty_covered_px": 3.1}, [])[0]
        'not reliable: add views tilted in different directions (20-45 deg) and filling more of the image'
        >>> verdict({"rms_px": 0.2, "uncertainty_covered_px": 0.2, "cv_rms_px": 20.5, "cv_covered_rms_px": 0.1,
        ...          "cv_expected_rms_px": 30.0, "heldout_rms_px": 0.21}, [])[1]
        ['two halves of the views disagree by 20.5 px RMS over the image (0.10 px where the boards were): outside the boards these views do not determine the distortion']
    """
    t = thresholds or VerdictThresholds()
    found = Findings()
    for i in issues:
        if i["severity"] == "error":
            found.fail(i["message"], i.get("advice") or i["message"])
        else:
            found.warn(i["message"])

    def num(key):
        v = figures.get(key)
        return None if v is None or not math.isfinite(v) else float(v)

    rms, held = num("rms_px"), num("heldout_rms_px")
    unc_cov, unc_max = num("uncertainty_covered_px"), num("uncertainty_max_px")
    cv, cv_cov, cv_exp = num("cv_rms_px"), num("cv_covered_rms_px"), num("cv_expected_rms_px")
    cv_cov_exp = num("cv_covered_expected_rms_px")
    if rms is None:
        reasons = "; ".join(dict.fromkeys(found.advice)) or "the calibration failed"
        return "not reliable: " + reasons, found.bad or ["no calibration"]
    structure = figures.get("residual_structure") or {}
    if structure.get("model_fit") == "does not fit":
        ratio = structure.get("noise_ratio") or math.nan
        found.fail(f"the model does not fit the lens: the residuals are {ratio:.1f}x the corners' noise, "
                   f"{structure['rms_cell_means_px']:.2f} px RMS of the mean residual over "
                   f"{structure['cells_significant']} of {structure['cells']} image cells",
                   "choose a distortion model that fits the lens (--model auto, rational or fisheye)")
    found.grade(rms, t.good_rms_px, t.usable_rms_px,
                f"reprojection RMS {rms:.2f} px: the corners or the lens model are off",
                "check the corner detections in the report, or choose a distortion model that fits the lens",
                f"reprojection RMS {rms:.2f} px is high: check the corners or try another distortion model")
    if unc_cov is None:
        found.warn("projection uncertainty unavailable")
    else:
        found.grade(unc_cov, t.good_uncertainty_px, t.usable_uncertainty_px,
                    f"projection uncertainty up to {unc_cov:.2f} px where the boards were",
                    "add views tilted in different directions (20-45 deg) and filling more of the image")
    fold = num("unprojectable_fraction")
    if fold:
        text = (f"the distortion model has no inverse over {100 * fold:.0f} % of the image (it folds before reaching "
                "those pixels)")
        if figures.get("unprojectable_covered"):
            found.fail(text + ", also where the boards were",
                       "use a distortion model that fits the lens (wide or fisheye lenses need a richer one)")
        else:
            found.warn(text + ": use a distortion model that fits the lens there")
    if unc_max is not None and unc_max > t.extrapolation_px:
        text = (f"projection uncertainty up to {unc_max:.1f} px outside the boards (distortion extrapolated): "
                "add views with the board near the image corners")
        if any(i["check"] == "image_coverage" for i in issues):  # small coverage and a wild extrapolation
            found.fail(text, "add views with the board near the image corners and edges")
        else:
            found.warn(text)
    if cv is None:
        found.warn("no cross-validation (too few views for two independent halves)")
    elif cv_exp:
        ratio = cv / cv_exp
        if cv_cov is not None and cv_cov_exp:  # where the boards were, if that is the worse
            ratio = max(ratio, cv_cov / cv_cov_exp)
        text = (f"{HALVES_DISAGREE} by {cv:.2f} px RMS over the image ({cv_cov or 0:.2f} px where "
                f"the boards were), {ratio:.1f}x what the corner noise explains")
        if ratio > t.cv_ratio and (cv_cov or 0.0) > t.cv_min_px:
            found.fail(text, "the lens does not fit the distortion model or some corners are wrong: try another "
                             "model and check the views with the largest error")
        elif ratio > t.cv_ratio:
            found.warn(text)
        elif cv > t.halves_px:
            found.warn(f"{HALVES_DISAGREE} by {cv:.1f} px RMS over the image ({cv_cov or 0:.2f} px where the boards "
                       "were): outside the boards these views do not determine the distortion")
    runner = figures.get("runner_up") or {}
    other = runner.get("halves_rms_px")
    if runner.get("tied") and other is not None and math.isfinite(other) and other > t.halves_px:
        found.note(f"the runner-up model {runner['model']} predicts the held-out views as well, and its "
                   f"{HALVES_DISAGREE} by {other:.1f} px RMS over the image: outside the boards the camera depends on "
                   "the model chosen")
    if held is not None and rms > 0:
        found.grade(held / rms, t.heldout_ratio, 2 * t.heldout_ratio,
                    f"held-out views reproject at {held:.2f} px RMS vs {rms:.2f} px on the fitted views",
                    "add views (the model overfits), or use a distortion model with fewer coefficients")
    return found.outcome()


def _f(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def diagnose(
    result,
    corners: torch.Tensor,
    valid: torch.Tensor | None,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    solver: nn.Module | None = None,
    folds: int = 5,
    grid: tuple[int, int] = (16, 12),
    thresholds: VerdictThresholds | None = None,
    weights: torch.Tensor | None = None,
    solutions: SubsetSolutions | None = None,
    runner_up: list[dict | None] | None = None,
) -> list[dict]:
    r"""Quality figures and verdict of a calibration, one JSON-able dict per camera.

    Args:
        result: the solver's ``CalibrationResult`` (batched or not) for ``corners``.
        corners: :math:`(C, V, N, 2)` / :math:`(V, N, 2)` px, as given to the solver.
        valid: matching bool mask (None: finite corners).
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)`.
        image_size: ``(W, H)``.
        solver: the solver that made ``result``, for cross-validation and held-out error (skipped if None).
        folds: folds of the held-out error.
        grid: ``(across, down)`` pixels of the uncertainty / cross-validation grids.
        weights: the per-corner weights the solver was given, if any (its cross-validation subsets get them too).
        thresholds: :class:`VerdictThresholds` (pixel limits for a 640x480 image, scaled by
            :func:`pixel_scale` of ``image_size``).
        solutions: the cross-validation's solved subsets kept by an earlier one (:func:`cross_validation`).
        runner_up: per camera, the model choice's runner-up (``{"model", "halves_rms_px", "tied"}``: its split-half
            difference over the image, whether the held-out views tie it with the chosen model; ``None``: none),
            kept in the figures for the verdict.

    Returns:
        per camera a dict with the keys:

        - ``success`` (bool), ``rms_px``: the solver's;
        - ``errors`` / ``warnings``: lists of ``{"check", "severity", "message", "advice", "views"}`` (degeneracy
          checks, views numbered as in ``corners``);
        - ``checks``: ``{name: measured value}`` of every check of :data:`~.degeneracy.CHECKS`;
        - ``std``: ``{"fx", "fy", "cx", "cy"}`` px and ``"dist"`` (list) standard deviations;
        - ``uncertainty_centre_px``, ``uncertainty_corners_px`` (top-left, top-right, bottom-left,
          bottom-right), ``uncertainty_max_px`` over the grid, ``uncertainty_grid_px`` (``down`` lists of
          ``across`` values): worst-direction standard deviation of the projection of a fixed ray, with the camera
          rotation the data cannot tell from a principal-point shift fitted out where boards were (mrcal-style, see
          :func:`projection_uncertainty`);
        - ``uncertainty_fixed_ray_px``: ``{"centre", "corners"}``, the same without that compensation (includes
          the principal point's uncertainty in full);
        - ``uncertainty_covered_px``: the worst of ``uncertainty_grid_px`` where some board was
          (``covered_fraction`` of the grid): where the calibration is measured rather than extrapolated;
        - ``unprojectable_fraction``: fraction of the grid where the distortion model has no inverse (it folds
          before reaching those pixels; their figures are None and left out of the maxima and RMS);
          ``unprojectable_covered``: some of them lie where boards were;
        - ``cv_rms_px``, ``cv_max_px``: difference of two calibrations from disjoint halves of the views, RMS and
          max over the grid (the best-aligning rotation fitted out); ``cv_covered_rms_px``: RMS where some board
          was; ``cv_expected_rms_px`` / ``cv_covered_expected_rms_px``: what the halves' covariances predict for
          ``cv_rms_px`` / ``cv_covered_rms_px``;
        - ``heldout_rms_px``: k-fold held-out reprojection RMS; ``heldout_views``;
        - ``residual_structure``: the residuals' structure over the image and whether the model fits
          (:meth:`~ccs_kornia.modules.calibration.result.CalibrationResult.residual_structure`; where the result has
          it): a model that does not fit makes the verdict ``not reliable``;
        - ``runner_up``: as given (where given);
        - ``verdict``: ``"good"``, ``"usable"`` or ``"not reliable: <advice>"``; ``reasons``: list of str.

        Figures that cannot be computed are None.
    """
    limits = (thresholds or VerdictThresholds()).scaled(pixel_scale(image_size))
    unbatched = corners.dim() == 3
    if valid is None:
        valid = corners.isfinite().all(-1)
    if unbatched:
        corners, valid = corners[None], valid[None]
        weights = None if weights is None else weights[None]
        result = result.map_tensors(lambda t: t[None])
    C = corners.shape[0]
    dtype = result.K.dtype
    corners = corners.to(dtype)
    valid = valid.bool() & corners.isfinite().all(-1)
    ok = result.success.bool()
    camera = result.camera.nan_to_num()
    gpx = image_points(image_size, grid).to(corners.device)
    covered = covered_pixels(corners, valid, object_points, result.used & ok[:, None], gpx)  # (C, G)
    unc5 = unc_grid = unc_fixed = None
    if result.cov_camera is not None:
        cov = result.cov_camera.nan_to_num(0.0)
        five = image_points(image_size).to(corners.device)
        px = torch.cat([gpx, five])
        # the rotation is fitted where boards were (all the grid when none was): the extrapolated rest of a wide
        # lens's image, often tens of px uncertain, would otherwise set the rotation and spoil the centre's figure
        on_boards = torch.where(covered.any(-1, keepdim=True), covered, torch.ones_like(covered))
        fit = torch.cat([on_boards, torch.zeros_like(on_boards[:, :5])], -1)
        unc = projection_uncertainty(camera, cov, px, compensate_rotation=fit)
        unc_grid, unc5 = unc[:, :-5], unc[:, -5:]
        unc_fixed = projection_uncertainty(camera, cov, five)
    cv = None
    if solver is not None and bool(ok.any()):
        on_grid = torch.where(covered.any(-1, keepdim=True), covered, torch.ones_like(covered))
        cv = cross_validation(solver, corners, valid, object_points, image_size, result, folds, grid, fit=on_grid,
                              weights=weights, solutions=solutions)
    if result.check_severity is not None:
        issues = issues_from_tensors(result.check_severity, result.check_value, result.check_views)
    else:
        issues = [[] for _ in range(C)]
    out = []
    for c in range(C):
        good = bool(ok[c])
        fig: dict = {"success": good, "rms_px": _f(result.rms[c]) if good else None}
        fig["errors"] = [i for i in issues[c] if i["severity"] == "error"]
        fig["warnings"] = [i for i in issues[c] if i["severity"] == "warning"]
        if result.check_value is not None:
            fig["checks"] = {n: _f(v) for n, v in zip(CHECKS, result.check_value[c].tolist())}
        s = result.std_intrinsics[c].tolist()
        fig["std"] = {"fx": _f(s[0]), "fy": _f(s[1]), "cx": _f(s[2]), "cy": _f(s[3]),
                      "dist": [_f(x) for x in result.std_dist[c].tolist()]}
        g = (int(grid[1]), int(grid[0]))
        if unc5 is not None and good:
            fig["uncertainty_centre_px"] = _f(unc5[c, 0])
            fig["uncertainty_corners_px"] = [_f(x) for x in unc5[c, 1:].tolist()]
            fig["uncertainty_max_px"] = _f(_nanmax(unc_grid[c]))
            fig["uncertainty_covered_px"] = _f(_nanmax(unc_grid[c][covered[c]])) if bool(covered[c].any()) else None
            no_ray = unc_grid[c].isnan()
            fig["unprojectable_fraction"] = _f(no_ray.double().mean())
            fig["unprojectable_covered"] = bool((no_ray & covered[c]).any())
            fig["uncertainty_grid_px"] = [[_f(x) for x in row] for row in unc_grid[c].reshape(g).tolist()]
            fig["uncertainty_fixed_ray_px"] = {"centre": _f(unc_fixed[c, 0]),
                                               "corners": [_f(x) for x in unc_fixed[c, 1:].tolist()]}
        else:
            fig.update(uncertainty_centre_px=None, uncertainty_corners_px=None, uncertainty_max_px=None,
                       uncertainty_covered_px=None, uncertainty_grid_px=None, uncertainty_fixed_ray_px=None,
                       unprojectable_fraction=None, unprojectable_covered=None)
        for key in ("cv_rms_px", "cv_max_px", "cv_expected_rms_px", "heldout_rms_px"):
            fig[key] = _f(cv[key][c]) if cv is not None and good else None
        fig["cv_covered_rms_px"] = fig["cv_covered_expected_rms_px"] = None
        if cv is not None and good and bool(covered[c].any()):
            fig["cv_covered_rms_px"] = _f(_nanrms(cv["cv_grid_px"][c][covered[c]]))
            fig["cv_covered_expected_rms_px"] = _f(_nanrms(cv["cv_expected_grid_px"][c][covered[c]]))
        fig["heldout_views"] = int(cv["heldout_views"][c]) if cv is not None and good else 0
        fig["covered_fraction"] = _f(covered[c].double().mean())
        if result.model_fit is not None and good:
            fig["residual_structure"] = result.residual_structure(c)
        if runner_up is not None and runner_up[c] is not None:
            fig["runner_up"] = dict(runner_up[c])
        fig["verdict"], fig["reasons"] = verdict(fig, issues[c], limits)
        out.append(fig)
    return out


class CalibrationDiagnostics(nn.Module):
    r"""Module form of :func:`diagnose`: the solver and the options fixed at construction.

    Args:
        solver: the calibration solver (for cross-validation and held-out error; None skips them).
        folds: folds of the held-out error.
        grid: ``(across, down)`` pixels of the grids.
        thresholds: :class:`VerdictThresholds`.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> from ccs_kornia.modules.calibration.solver import CalibrationSolver
        >>> obj = board_object_points(9, 6, 0.025, dtype=torch.float64)
        >>> K = torch.tensor([[600., 0, 320], [0, 600, 240], [0, 0, 1]], dtype=torch.float64)
        >>> g = torch.Generator().manual_seed(0)
        >>> rv = 0.8 * (torch.rand(12, 3, generator=g, dtype=torch.float64) - 0.5)
        >>> tv = torch.tensor([-0.1, -0.06, 0.45], dtype=torch.float64).expand(12, 3)
        >>> uv = project_points(obj.expand(12, -1, -1), K.expand(12, 3, 3), None, rv, tv)
        >>> uv = uv + 0.2 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
        >>> from ccs_kornia.geometry.models import K1K2
        >>> solver = CalibrationSolver(model=K1K2)
        >>> res = solver(uv, None, obj, (640, 480))
        >>> fig = CalibrationDiagnostics(solver)(res, uv, None, obj, (640, 480))[0]
        >>> fig["verdict"] in ("good", "usable"), fig["uncertainty_centre_px"] < 1.0
        (True, True)
    """

    def __init__(self, solver: nn.Module | None = None, folds: int = 5, grid: tuple[int, int] = (16, 12),
                 thresholds: VerdictThresholds | None = None) -> None:
        super().__init__()
        self.solver = solver
        self.folds = folds
        self.grid = grid
        self.thresholds = thresholds or VerdictThresholds()

    def forward(self, result, corners, valid, object_points, image_size, weights=None) -> list[dict]:
        return diagnose(result, corners, valid, object_points, image_size, self.solver, self.folds, self.grid,
                        self.thresholds, weights)

    def extra_repr(self) -> str:
        return f"folds={self.folds}, grid={self.grid}, thresholds={asdict(self.thresholds)}"
