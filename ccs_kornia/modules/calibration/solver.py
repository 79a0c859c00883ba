"""The calibration solver: homographies -> Zhang -> image RANSAC -> joint LM -> outlier check -> LM.

Batched over cameras (C) and views (V); views without a usable board are padded and masked. Every stage is
a module of its own (``homography.py``, ``zhang.py``, ``ransac.py``, ``refinement.py`` on the one LM core
``lm.py``, ``degeneracy.py`` in ``ccs_kornia/modules/calibration/``); this one only composes them and keeps the
bookkeeping of which view was used and why not.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import nn

from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.camera import Camera, intrinsics_params
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import CAMERA_MODELS, FISHEYE, OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.geometry.models.splined import SplinedStereographicModel
from ccs_kornia.modules.calibration.duplicates import duplicate_views, view_differences
from ccs_kornia.modules.calibration.fisheye_calibration import calibrate_fisheye
from ccs_kornia.modules.calibration.homography import (
    MIN_HOMOGRAPHY_POINTS,
    find_homographies,
)
from ccs_kornia.modules.calibration.implicit import implicit_solution
from ccs_kornia.modules.calibration.lm import parameter_basis
from ccs_kornia.modules.calibration.outliers import drop_outliers
from ccs_kornia.modules.calibration.quality.degeneracy import (
    DegeneracyThresholds,
    check_degeneracy,
)
from ccs_kornia.modules.calibration.quality.residual_structure import (
    board_runs,
    model_fit,
    residual_structure,
)
from ccs_kornia.modules.calibration.ransac import ImageRansac
from ccs_kornia.modules.calibration.refinement import (
    RefinementResult,
    joint_refinement,
)
from ccs_kornia.modules.calibration.result import CalibrationResult, ViewReason
from ccs_kornia.modules.calibration.splined import calibrate_splined
from ccs_kornia.modules.calibration.zhang import (
    extrinsics_from_homography,
    zhang_intrinsics,
)
from ccs_kornia.runtime.checks import check_same_shape, check_tensor
from ccs_kornia.runtime.threads import small_problem_threads

__all__ = ["CalibrationSolver", "calibrate"]


def _check_inputs(corners, valid, object_points, image_size):
    check_tensor(corners, "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
    if valid is None:
        valid = corners.isfinite().all(-1)
    check_tensor(valid, "valid", corners.shape[:-1])
    N = corners.shape[-2]
    C = corners.shape[0] if corners.dim() == 4 else 1
    check_tensor(object_points, "object_points", [N, 3], [1, N, 3], [C, N, 3])
    if len(image_size) != 2 or min(int(image_size[0]), int(image_size[1])) <= 0:
        raise ValueError(f"image_size must be (W, H) with positive entries, got {image_size!r}.")
    if N < MIN_HOMOGRAPHY_POINTS:
        raise ValueError(f"A board needs at least {MIN_HOMOGRAPHY_POINTS} points, got N={N}.")
    return valid


class CalibrationSolver(nn.Module):
    r"""Intrinsic calibration from planar-board corners, batched over cameras.

    Args:
        model: the camera model: :data:`~ccs_kornia.geometry.models.PINHOLE`, ``K1K2``, ``OPENCV5``, ``RATIONAL``
            (OpenCV's, coefficients in its order) or ``FISHEYE`` (Kannala-Brandt ``k1..k4`` as ``cv2.fisheye``, solved by
            :func:`~ccs_kornia.modules.calibration.fisheye_calibration.calibrate_fisheye` on the same LM core:
            its own guess-free initialisation replaces Zhang and RANSAC; the copies and degeneracy checks are
            the same).
        use_ransac: run the image-level RANSAC before the refinement.
        ransac_iters: RANSAC hypotheses per camera.
        seed: RANSAC seed (results are deterministic).
        fix_aspect_ratio: ``fx == fy``.
        dtype: solve precision.
        fix_principal_point: principal point at the image centre ``((W-1)/2, (H-1)/2)``.
        min_corners: views with fewer valid corners are not used.
        min_views: cameras with fewer usable views fail (``success = False``, values NaN).
        ransac_sample_size: views per RANSAC subset.
        ransac_abs_threshold / ransac_rel_threshold: RANSAC inlier threshold ``max(abs, rel * median)`` (px).
        reject_outliers: after LM, re-evaluate every view under the full model (distortion included) and
            refine again without views whose RMS exceeds ``max(outlier_abs_threshold,
            outlier_rel_threshold * median view RMS)``; this also re-admits views RANSAC rejected only
            because of un-modelled distortion.
        max_outlier_rounds: rounds of that check.
        max_iters: LM iterations at most.
        lambda_init: initial damping of the LM core (relative to the diagonal): Zhang's closed form is a good
            start, so little damping saves iterations, at the same optimum (``docs/measurements.md``).
        ftol: the LM stops when an accepted step lowers the cost by less than ``ftol`` times the cost. 1e-10 (the
            cost settled to 10 digits) reaches the optimum of tighter tolerances in fewer iterations, which decides
            whether one camera calibrates faster than with ``cv2.calibrateCamera`` (``docs/measurements.md``).
        stall_tol: the LM also stops where 10 iterations lowered the cost by at most this fraction (RMS by half of
            it). A model that fits converges long before; the rational model on a narrow lens and an OpenCV model on
            a fisheye crawl along directions the views do not determine, each step still passing ``ftol``, for RMS
            changes in the fifth digit, while a weakly determined fit that is still converging lowers its cost by far
            more than this fraction (``docs/measurements.md``).
        checks: run the degeneracy checks of :mod:`~ccs_kornia.modules.calibration.quality.degeneracy`: copies of a view
            are dropped before the solve (:attr:`ViewReason.DUPLICATE`), a camera failing a check with severity
            ``error`` gets ``success = False``, and every result carries ``check_*`` tensors (see
            ``CalibrationResult.issues``).
        thresholds: :class:`~ccs_kornia.modules.calibration.quality.degeneracy.DegeneracyThresholds` of those checks.
        A :class:`~ccs_kornia.geometry.models.splined.SplinedStereographicModel` is fitted from this solver's rational
        fit (:mod:`~ccs_kornia.modules.calibration.splined`), or from ``initial`` where that is of the same grid.
        board_warp: estimate the board's sag jointly with the camera and poses (mrcal's two parameters,
            :mod:`~ccs_kornia.geometry.board_warp`; the OpenCV and fisheye models): the result's ``board_warp`` and
            ``std_board_warp``. Whether it is worth keeping is decided on held-out views
            (:func:`~ccs_kornia.modules.calibration.board_flatness.choose_board_warp`), not here.

    Gradients: when ``corners``, ``weights`` or ``object_points`` require grad, ``K``, ``dist``, ``rvec`` and ``tvec``
    carry gradients by implicit differentiation at the final LM optimum
    (:mod:`~ccs_kornia.modules.calibration.implicit`; no unrolled iterations, the values unchanged). The discrete
    decisions (initialisation, RANSAC, duplicates, the outlier check, which views and corners are used) and the tie
    of ``fix_aspect_ratio`` are constants of the backward pass; fixed parameters have zero gradient; ``rms``,
    ``view_rms`` and the covariances carry none. See ``docs/gradients.md``.

    Shape:
        corners :math:`(C, V, N, 2)` px, valid :math:`(C, V, N)` bool, object_points :math:`(N, 3)` or
        :math:`(C, N, 3)`, image_size ``(W, H)`` -> :class:`CalibrationResult`. Unbatched :math:`(V, N, 2)`
        input gives results without the C dim.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> obj = board_object_points(6, 5, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[600., 0, 330], [0, 610, 230], [0, 0, 1]], dtype=torch.float64)
        >>> g = torch.Generator().manual_seed(0)
        >>> rvec = 0.4 * (torch.rand(8, 3, generator=g, dtype=torch.float64) - 0.5)
        >>> tvec = torch.tensor([-0.25, -0.2, 1.5], dtype=torch.float64).expand(8, 3)
        >>> uv = project_points(obj.expand(8, -1, -1), K.expand(8, 3, 3), None, rvec, tvec)
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> res = CalibrationSolver(model=PINHOLE)(uv, torch.ones(8, 30, dtype=torch.bool), obj, (640, 480))
        >>> bool((res.K - K).abs().max() < 1e-6), bool(res.success)
        (True, True)
        >>> c = uv.clone().requires_grad_()  # gradients of the camera with respect to the corners
        >>> CalibrationSolver(model=PINHOLE)(c, None, obj, (640, 480)).K[0, 0].backward()
        >>> c.grad.shape
        torch.Size([8, 30, 2])
    """

    def __init__(
        self,
        model: CameraModel = OPENCV5,
        use_ransac: bool = True,
        ransac_iters: int = 32,
        seed: int = 0,
        fix_aspect_ratio: bool = False,
        dtype: torch.dtype = torch.float64,
        fix_principal_point: bool = False,
        min_corners: int = 4,
        min_views: int = 3,
        ransac_sample_size: int = 4,
        ransac_abs_threshold: float = 3.0,
        ransac_rel_threshold: float = 5.0,
        reject_outliers: bool = True,
        outlier_abs_threshold: float = 2.0,
        outlier_rel_threshold: float = 5.0,
        max_outlier_rounds: int = 2,
        max_iters: int = 100,
        lambda_init: float = 1e-5,
        ftol: float = 1e-10,
        stall_tol: float = 1e-4,
        checks: bool = True,
        thresholds: DegeneracyThresholds | None = None,
        board_warp: bool = False,
    ) -> None:
        super().__init__()
        self.board_warp = bool(board_warp)
        self.checks = checks
        self.thresholds = thresholds or DegeneracyThresholds(min_views=max(int(min_views), 1))
        if model not in CAMERA_MODELS.values() and not isinstance(model, SplinedStereographicModel):
            raise ValueError(f"CalibrationSolver's model must be one of the models {', '.join(CAMERA_MODELS)} or a "
                             f"SplinedStereographicModel (ccs_kornia.geometry.models), got {model!r}.")
        self.model = model
        self.use_ransac = use_ransac
        self.fix_aspect_ratio = fix_aspect_ratio
        self.fix_principal_point = fix_principal_point
        self.dtype = dtype
        self.min_corners = max(int(min_corners), MIN_HOMOGRAPHY_POINTS)
        self.min_views = max(int(min_views), 1)
        self.reject_outliers = reject_outliers
        self.outlier_abs_threshold = outlier_abs_threshold
        self.outlier_rel_threshold = outlier_rel_threshold
        self.max_outlier_rounds = max_outlier_rounds
        self.max_iters = max_iters
        self.lambda_init = lambda_init
        self.ftol = ftol
        self.stall_tol = stall_tol
        self.ransac = ImageRansac(
            num_hypotheses=ransac_iters, sample_size=ransac_sample_size, abs_threshold=ransac_abs_threshold,
            rel_threshold=ransac_rel_threshold, min_views=self.min_views, seed=seed,
        )

    def _refine(self, corners, valid, obj, K, rvec, tvec, dist, view_mask, fix_intrinsics: bool = False,
                poses_only: bool = False, model=None, weights=None, warp=None):
        """The joint LM; with ``board_warp`` the board's sag is estimated from ``warp`` (default flat), or held at
        ``warp`` when only the poses move."""
        start = None
        if self.board_warp and model is None:
            if poses_only:
                obj = warped_board(obj, warp)
            else:
                start = warp if warp is not None else obj.new_zeros(corners.shape[0], 2)
        return joint_refinement(
            corners, valid, obj, K, rvec, tvec, dist, view_mask, model=model or self.model,
            fix_aspect_ratio=self.fix_aspect_ratio, fix_principal_point=self.fix_principal_point,
            max_iters=self.max_iters, ftol=self.ftol, lambda_init=self.lambda_init, dtype=self.dtype,
            fix_intrinsics=poses_only or fix_intrinsics, fix_distortion=poses_only, weights=weights,
            stall_tol=self.stall_tol, board_warp=start,
        )

    def forward(
        self,
        corners: torch.Tensor,
        valid: torch.Tensor | None,
        object_points: torch.Tensor,
        image_size: tuple[int, int],
        init_corners: torch.Tensor | None = None,
        initial: CalibrationResult | None = None,
        fix_intrinsics: bool = False,
        weights: torch.Tensor | None = None,
    ) -> CalibrationResult:
        """Calibrate.

        Args:
            corners: :math:`(C, V, N, 2)` / :math:`(V, N, 2)` observed (distorted) pixels.
            valid: matching bool mask (or ``None``: all finite corners).
            object_points: :math:`(N, 3)` / :math:`(C, N, 3)`.
            image_size: ``(W, H)``.
            init_corners: optional corners of the same views with the lens distortion (mostly) removed, e.g. by
                the distortion CNN. Homographies, Zhang and RANSAC then run on them (the closed form assumes a
                pinhole camera), a distortion-free refinement on them gives the initial camera and poses, and the
                initial distortion is fitted in closed form from those ideal projections to ``corners``
                (:meth:`~ccs_kornia.geometry.models.opencv.OpenCVModel.fit_coeffs`). The final refinement always uses ``corners``.
            initial: a previous result for the same views (warm start: no RANSAC, its camera, distortion, poses
                and used views), e.g. after the corners were refined again.
            fix_intrinsics: with ``initial``, keep its ``fx, fy, cx, cy`` and refine distortion and poses only.
            weights: optional per-corner inverse variances, shaped as ``valid`` (e.g.
                :func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_weights`): the refinements minimise the
                weighted reprojection error (homographies, the closed form and RANSAC stay unweighted); the RMS figures
                stay plain pixels.
        """
        if fix_intrinsics and initial is None:
            raise ValueError("fix_intrinsics needs an initial result to take the intrinsics from.")
        # no autograd through the solver (LM, closed forms): inference mode spares the dispatcher's autograd and
        # version-counter work on every small op; the results are cloned out as ordinary tensors, and gradients, where
        # an input requires them, are attached at the optimum by implicit differentiation
        with torch.inference_mode(), small_problem_threads(corners.shape[:-1].numel(), corners.device):
            out = self._solve(corners, valid, object_points, image_size, init_corners, initial, bool(fix_intrinsics),
                              weights)
        if torch.is_inference_mode_enabled():
            return out
        out = out.map_tensors(torch.Tensor.clone, Camera.clone)
        if torch.is_grad_enabled() and any(
            isinstance(t, torch.Tensor) and t.requires_grad for t in (corners, object_points, weights)
        ):
            out = self._attach_gradients(out, corners, valid, object_points, weights, bool(fix_intrinsics))
        return out

    def _attach_gradients(self, out, corners, valid, object_points, weights, fix_intrinsics) -> CalibrationResult:
        """``out`` with ``K``, ``dist``, ``rvec`` and ``tvec`` (used views) differentiable with respect to ``corners``,
        ``weights`` and ``object_points`` by implicit differentiation at the final LM optimum
        (:mod:`~ccs_kornia.modules.calibration.implicit`): the same values, the views, corners and fixed or tied
        parameters of that final solve held as they were decided."""
        unbatched = corners.dim() == 3
        res = out
        if unbatched:
            res = out.map_tensors(lambda t: t[None])
            corners = corners[None]
            valid = None if valid is None else valid[None]
            weights = None if weights is None else weights[None]
        C, V, N = corners.shape[:3]
        dtype, device = self.dtype, corners.device
        c = corners.to(dtype)
        ok = c.detach().isfinite().all(-1) & res.used.to(device)[..., None]
        ok = ok if valid is None else ok & valid.to(device).bool()
        w = ok.to(dtype) if weights is None else torch.where(ok, weights.to(device=device, dtype=dtype), 0.0)
        obj = object_points.to(device=device, dtype=dtype)
        obj = obj.expand(C, N, 3) if obj.dim() == 2 or obj.shape[0] == 1 else obj
        obj = obj.reshape(C, N, 3)
        if res.board_warp is not None:  # the sag is held as solved (a constant of the backward pass)
            obj = warped_board(obj, res.board_warp.to(obj).nan_to_num(0.0))
        cam = self.model
        params = res.camera.params.to(dtype)
        if cam.is_fisheye:  # as calibrate_fisheye's final solve: no tied aspect ratio
            free = [not (self.fix_principal_point and n in ("cx", "cy")) for n in cam.param_names]
            tie = False
        else:  # as joint_refinement's
            free = [not fix_intrinsics] * 2 + [not (fix_intrinsics or self.fix_principal_point)] * 2
            free += [True] * (cam.num_params - 4)
            tie = self.fix_aspect_ratio and not fix_intrinsics
        basis = parameter_basis(cam, params.nan_to_num(1.0), free, tie)
        p, rv, tv = implicit_solution(cam, basis, params, res.rvec, res.tvec, c, w, obj)
        ok_cam = res.success.to(device)
        used = res.used.to(device)[..., None]
        grads = {
            "rvec": torch.where(used, rv, res.rvec),
            "tvec": torch.where(used, tv, res.tvec),
        }
        if unbatched:
            grads = {k: v[0] for k, v in grads.items()}
        camera = res.camera.with_params(torch.where(ok_cam[:, None], p, params))
        return replace(out, camera=camera, **grads)

    def _solve(self, corners, valid, object_points, image_size, init_corners, initial, fix_intrinsics,
               weights=None) -> CalibrationResult:
        valid = _check_inputs(corners, valid, object_points, image_size)
        if weights is not None:
            check_same_shape(weights, "weights", valid, "valid")
        unbatched = corners.dim() == 3
        if init_corners is not None:
            check_same_shape(init_corners, "init_corners", corners, "corners")
        if unbatched:
            corners, valid = corners[None], valid[None]
            weights = None if weights is None else weights[None]
            init_corners = None if init_corners is None else init_corners[None]
            if initial is not None:
                initial = initial.map_tensors(lambda t: t[None])
        C, V, N = corners.shape[:3]
        image_size = (int(image_size[0]), int(image_size[1]))
        dtype, device = self.dtype, corners.device
        corners = corners.to(dtype)
        obj = object_points.to(device=device, dtype=dtype)
        obj = obj.expand(C, N, 3) if obj.dim() == 2 or obj.shape[0] == 1 else obj
        obj = obj.reshape(C, N, 3)
        valid = valid.to(device).bool() & corners.isfinite().all(-1)
        if weights is not None:
            weights = torch.where(valid, weights.to(device=device, dtype=dtype), 0.0)

        # 1. homographies
        enough = valid.sum(-1) >= self.min_corners
        H, ok_h = find_homographies(obj[:, None, :, :2], corners, valid & enough[..., None], return_ok=True)
        candidates = enough & ok_h
        reason = torch.full((C, V), ViewReason.USED, dtype=torch.long, device=device)
        reason = torch.where(~enough, ViewReason.TOO_FEW_CORNERS, torch.where(~ok_h, ViewReason.NO_HOMOGRAPHY, reason))
        duplicate_of = torch.full((C, V), -1, dtype=torch.long, device=device)
        differences = None
        if self.checks:  # copies of a view are not independent observations: drop them before anything else
            differences = view_differences(corners, valid)
            duplicate_of = duplicate_views(corners, valid, candidates, self.thresholds.duplicate_px, differences)
            candidates = candidates & (duplicate_of < 0)
            reason = torch.where(duplicate_of >= 0, ViewReason.DUPLICATE, reason)

        if isinstance(self.model, SplinedStereographicModel):
            return self._solve_splined(corners, valid, obj, image_size, initial, weights, unbatched)
        if self.model.is_fisheye:
            return self._solve_fisheye(corners, valid, obj, image_size, candidates, reason, duplicate_of,
                                       differences, H, unbatched, initial, weights)

        # 2. Zhang (inside RANSAC) -> inlier views; on the undistorted corners when given
        pp_mode = "centre" if self.fix_principal_point else "auto"
        dist0 = None
        if initial is not None:
            warm = initial.used.to(device) & candidates & initial.K.flatten(1).isfinite().all(-1)[:, None]
            inliers = torch.where((warm.sum(-1) >= self.min_views)[:, None], warm, candidates)
            K0 = initial.K.to(device=device, dtype=dtype)
            f0 = float(max(image_size))  # a failed (NaN) initial camera gets a finite stand-in (it fails again below)
            K_fb = torch.tensor([[f0, 0, (image_size[0] - 1) / 2], [0, f0, (image_size[1] - 1) / 2], [0, 0, 1]],
                                dtype=dtype, device=device)
            init_ok = K0.flatten(1).isfinite().all(-1)
            K0 = torch.where(init_ok[:, None, None], K0, K_fb)
            rvec_h, tvec_h = extrinsics_from_homography(K0, H)
            rvec0 = torch.where(warm[..., None], initial.rvec.to(device=device, dtype=dtype), rvec_h)
            tvec0 = torch.where(warm[..., None], initial.tvec.to(device=device, dtype=dtype), tvec_h)
            dist0 = initial.dist.to(device=device, dtype=dtype).nan_to_num(0.0)
        else:
            H_init = H
            ideal_corners = corners
            if init_corners is not None:
                ideal_corners = init_corners.to(device=device, dtype=dtype)
                H_init, ok_i = find_homographies(obj[:, None, :, :2], ideal_corners, valid & enough[..., None], return_ok=True)
                candidates = candidates & ok_i
            if self.use_ransac:
                inliers, K0 = self.ransac(H_init, ideal_corners, valid, obj, candidates, image_size)
            else:
                inliers = candidates
            if not self.use_ransac or self.fix_aspect_ratio or self.fix_principal_point:
                K0 = zhang_intrinsics(H_init, inliers, image_size, pp_mode, self.fix_aspect_ratio)
            rvec0, tvec0 = extrinsics_from_homography(K0, H_init)
            if init_corners is not None:
                pin = self._refine(ideal_corners, valid, obj, K0, rvec0, tvec0, None, inliers, model=PINHOLE)
                ok_pin = pin.K.flatten(1).isfinite().all(-1)
                K0 = torch.where(ok_pin[:, None, None], pin.K, K0)
                rvec0 = torch.where(ok_pin[:, None, None], pin.rvec, rvec0)
                tvec0 = torch.where(ok_pin[:, None, None], pin.tvec, tvec0)
                if self.model.num_coeffs:
                    ideal = Camera(PINHOLE, intrinsics_params(K0)).project(obj[:, None].expand(C, V, N, 3), rvec0, tvec0)
                    w_fit = (valid & inliers[..., None]).reshape(C, V * N)
                    dist0 = self.model.fit_coeffs(
                        ideal.reshape(C, V * N, 2).nan_to_num(0.0), corners.reshape(C, V * N, 2).nan_to_num(0.0), K0,
                        mask=w_fit,
                    )
                    dist0 = torch.where(dist0.isfinite().all(-1, keepdim=True), dist0, torch.zeros_like(dist0))
        reason = torch.where(candidates & ~inliers, ViewReason.RANSAC_REJECTED, reason)

        # 3. joint LM from the closed form
        warp0 = None if initial is None or initial.board_warp is None else \
            initial.board_warp.to(device=device, dtype=dtype).nan_to_num(0.0)
        res = self._refine(corners, valid, obj, K0, rvec0, tvec0, dist0, inliers, fix_intrinsics, weights=weights,
                           warp=warp0)
        used = inliers & res.view_rms.isfinite()
        cand_rms = res.view_rms

        # 4. outlier check under the full model, refine again
        if self.reject_outliers:
            for _ in range(self.max_outlier_rounds):
                cand_rms, rvec_all, tvec_all = self._evaluate_all(res, corners, valid, obj, H, candidates, used)
                new_used = drop_outliers(cand_rms, used, candidates, self.outlier_abs_threshold,
                                         self.outlier_rel_threshold, self.min_views)
                if bool((new_used == used).all()):
                    break
                res = self._refine(corners, valid, obj, res.K, rvec_all, tvec_all, res.dist, new_used, fix_intrinsics,
                                   weights=weights, warp=res.warp)
                used = new_used & res.view_rms.isfinite()
            cand_rms = torch.where(used, res.view_rms, cand_rms)
            reason = torch.where(candidates & ~used & inliers, ViewReason.OUTLIER, reason)
        reason = torch.where(used, ViewReason.USED,
                             torch.where((reason == ViewReason.USED) & ~used, ViewReason.RANSAC_REJECTED, reason))

        success = (used.sum(-1) >= self.min_views) & res.rms.isfinite() & res.K.flatten(1).isfinite().all(-1)
        success = success & (res.K[:, 0, 0] > 0) & (res.K[:, 1, 1] > 0)
        if initial is not None and fix_intrinsics:  # intrinsics held at a failed (NaN) initial camera
            success = success & init_ok
        report = None
        if self.checks:
            report = check_degeneracy(
                corners, valid, obj, image_size, used, res.rvec, res.K, res.std_intrinsics, self.model,
                self.fix_aspect_ratio, self.fix_principal_point, duplicate_of, self.thresholds, differences, H,
            )
            success = success & ~report.errors
        nan = float("nan")

        def fail_nan(x: torch.Tensor) -> torch.Tensor:
            return torch.where(success.view(C, *([1] * (x.dim() - 1))), x, torch.full_like(x, nan))

        out = CalibrationResult(
            camera=Camera(self.model, fail_nan(self.model.params_from(res.K, res.dist)), image_size),
            rvec=res.rvec,
            tvec=res.tvec,
            view_rms=torch.where(used, res.view_rms, torch.full_like(res.view_rms, nan)),
            used=used,
            rms=fail_nan(res.rms),
            std_intrinsics=fail_nan(res.std_intrinsics),
            std_dist=fail_nan(res.std_dist),
            success=success,
            view_reason=reason,
            lm_status=res.status,
            candidate_rms=torch.where(candidates, cand_rms, torch.full_like(cand_rms, nan)),
            cov_camera=fail_nan(res.cov_camera),
            check_severity=None if report is None else report.severity,
            check_value=None if report is None else report.value,
            check_views=None if report is None else report.views,
            board_warp=None if res.warp is None else fail_nan(res.warp),
            std_board_warp=None if res.warp is None else fail_nan(
                res.warp_covariance.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()),
        )
        out = with_residual_structure(out, corners, valid, obj, image_size)
        if unbatched:
            out = out.map_tensors(lambda t: t[0])
        return out

    def _solve_fisheye(self, corners, valid, obj, image_size, candidates, reason, duplicate_of, differences, H,
                       unbatched, initial=None, weights=None) -> CalibrationResult:
        """Kannala-Brandt cameras from the candidate views (the pinhole closed form does not hold for them; with
        ``initial``, its camera and poses replace the focal-length hypotheses)."""
        C, V = corners.shape[:2]
        if not bool((obj == obj[:1]).all()):
            raise ValueError("The fisheye model needs one board for every camera of the batch.")
        warm = None
        if initial is not None:
            if set(initial.camera.models) != {FISHEYE}:
                raise ValueError(f"A fisheye solver's initial result must be a fisheye calibration, got "
                                 f"{initial.camera!r}.")
            device = corners.device
            warm = (initial.K.to(device), initial.dist.to(device), initial.rvec.to(device), initial.tvec.to(device),
                    initial.used.to(device))
        warp0 = None
        if self.board_warp:  # the sag from the initial result's, else from a flat board
            start = None if initial is None else initial.board_warp
            warp0 = obj.new_zeros(C, 2) if start is None else start.to(obj).nan_to_num(0.0)
        fish = calibrate_fisheye(
            corners, valid & candidates[..., None], obj[0], image_size, min_corners=self.min_corners,
            min_views=self.min_views, outlier_abs_threshold=self.outlier_abs_threshold,
            outlier_rel_threshold=self.outlier_rel_threshold, max_iters=self.max_iters,
            fix=(("cx", "cy") if self.fix_principal_point else ()), initial=warm, weights=weights,
            stall_tol=self.stall_tol, board_warp=warp0,
        )
        used = fish.used & candidates
        reason = torch.where(used, ViewReason.USED, torch.where(reason == ViewReason.USED, ViewReason.OUTLIER, reason))
        success = fish.success
        report = None
        if self.checks:
            report = check_degeneracy(
                corners, valid, obj, image_size, used, fish.rvec, fish.K.nan_to_num(1.0), fish.std_intrinsics,
                self.model, self.fix_aspect_ratio, self.fix_principal_point, duplicate_of, self.thresholds,
                differences, H,
            )
            success = success & ~report.errors

        def fail_nan(x: torch.Tensor) -> torch.Tensor:
            return torch.where(success.view(C, *([1] * (x.dim() - 1))), x, torch.full_like(x, float("nan")))

        out = CalibrationResult(
            camera=Camera(FISHEYE, fail_nan(FISHEYE.params_from(fish.K, fish.D)), image_size),
            rvec=fish.rvec, tvec=fish.tvec,
            view_rms=fish.view_rms, used=used, rms=fail_nan(fish.rms), std_intrinsics=fail_nan(fish.std_intrinsics),
            std_dist=fail_nan(fish.std_dist), success=success, view_reason=reason,
            lm_status=fish.lm_status, candidate_rms=fish.candidate_rms, cov_camera=fail_nan(fish.covariance),
            check_severity=None if report is None else report.severity,
            check_value=None if report is None else report.value,
            check_views=None if report is None else report.views,
            board_warp=None if fish.warp is None else fail_nan(fish.warp),
            std_board_warp=None if fish.warp_std is None else fail_nan(fish.warp_std),
        )
        out = with_residual_structure(out, corners, valid, obj, image_size)
        if unbatched:
            out = out.map_tensors(lambda t: t[0])
        return out

    def _solve_splined(self, corners, valid, obj, image_size, initial, weights, unbatched) -> CalibrationResult:
        """A splined camera (:mod:`~ccs_kornia.modules.calibration.splined`): from ``initial`` where it is one of the
        same grid, else from this solver's fit with the rational model (the fisheye model where that fails), the
        views, outliers and checks of that start kept."""
        spline = self.model
        start = initial
        if start is None or set(start.camera.models) != {spline}:
            options = {k: getattr(self, k) for k in ("use_ransac", "fix_aspect_ratio", "dtype", "fix_principal_point",
                                                     "reject_outliers", "outlier_abs_threshold",
                                                     "outlier_rel_threshold", "max_outlier_rounds", "max_iters",
                                                     "lambda_init", "ftol", "stall_tol", "checks", "thresholds",
                                                     "min_views", "min_corners")}
            rational = CalibrationSolver(model=RATIONAL, board_warp=self.board_warp, **options)
            warm = initial if initial is not None and set(initial.camera.models) == {RATIONAL} else None
            start = rational._solve(corners, valid, obj, image_size, None, warm, False, weights)
            if not bool(start.success.all()):
                fish = CalibrationSolver(model=FISHEYE, **options)._solve(corners, valid, obj, image_size, None, None,
                                                                           False, weights)
                start = fish if bool(fish.success.sum() > start.success.sum()) else start
        out = calibrate_splined(start, corners, valid, obj, image_size, spline, weights)
        out = with_residual_structure(out, corners, valid, obj, image_size)
        if unbatched:
            out = out.map_tensors(lambda t: t[0])
        return out

    def _evaluate_all(self, res: RefinementResult, corners, valid, obj, H, candidates, used):
        """Per-view RMS of every candidate view under the refined camera (poses re-fitted for unused views)."""
        if bool((candidates == used).all()):
            return res.view_rms, res.rvec, res.tvec
        rvec_h, tvec_h = extrinsics_from_homography(res.K, H)
        rvec0 = torch.where(used[..., None], res.rvec, rvec_h)
        tvec0 = torch.where(used[..., None], res.tvec, tvec_h)
        poses = self._refine(corners, valid, obj, res.K, rvec0, tvec0, res.dist, candidates, poses_only=True,
                             warp=res.warp)
        return poses.view_rms, poses.rvec, poses.tvec


def with_residual_structure(out: CalibrationResult, corners: torch.Tensor, valid: torch.Tensor, obj: torch.Tensor,
                            image_size: tuple[int, int]) -> CalibrationResult:
    """``out`` (batched) with its residuals' structure over the image and the model-fit flag
    (:mod:`~ccs_kornia.modules.calibration.quality.residual_structure`), from its used views' corners."""
    C, V, N = corners.shape[:3]
    board = obj if out.board_warp is None else warped_board(obj, out.board_warp.to(obj).nan_to_num(0.0))
    board = board.expand(C, N, 3) if board.dim() == 2 else board
    uv = out.camera.project(board[:, None].expand(C, V, N, 3), out.rvec.to(board), out.tvec.to(board))
    mask = valid & out.used[..., None] & out.success[:, None, None]
    structure = residual_structure(uv - corners, corners, mask, image_size, runs=board_runs(obj.reshape(-1, N, 3)[0]))
    return replace(out, model_fit=model_fit(structure), structure_cells=structure.cells,
                   structure_rms=structure.rms_cell_means, structure_significant=structure.significant,
                   structure_worst=structure.worst, structure_median=structure.median, structure_noise=structure.noise)


def calibrate(
    corners: torch.Tensor,
    valid: torch.Tensor | None,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    **kwargs,
) -> CalibrationResult:
    """Functional form of :class:`CalibrationSolver` (``kwargs`` go to its constructor)."""
    return CalibrationSolver(**kwargs)(corners, valid, object_points, image_size)
