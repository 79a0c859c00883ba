"""Calibration in the radially corrected frame (paper Sec. III-A, and a joint refinement beyond it).

Where the distortion network's pooled correction is applied (:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline`),
the camera is calibrated in the corrected frame (:func:`calibrate_corrected`): a pinhole calibration of the
corrected corners, the correction re-fitted to it, and a joint refinement of intrinsics, correction and poses
(:func:`~ccs_kornia.modules.calibration.centred_radial.refine_centred_radial`, on the one LM core) until they stop
changing; the output OpenCV model's distortion is finally fitted with those intrinsics held, and the camera's
covariance combines both (the joint refinement's for the intrinsics, the fit's for the distortion given them,
plus what the intrinsics' uncertainty propagates into it). :func:`solve_with_correction` keeps it only where it
fits the observed corners at least as well as the usual joint calibration (a lens whose distortion is not
centred on the image keeps the usual one).
"""

from __future__ import annotations

from dataclasses import replace

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera, intrinsics_params
from ccs_kornia.geometry.models.factory import K1K2, OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.modules.calibration.centred_radial import (
    radial_from_points,
    refine_centred_radial,
)
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.refinement import camera_covariance
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.correction.correction_fit import fit_correction_to_points
from ccs_kornia.modules.correction.radial_warp import correct_points
from ccs_kornia.modules.detection.base import measured_corners
from ccs_kornia.runtime.checks import check_board_size

__all__ = ["solve_with_correction", "calibrate_corrected", "select_cameras"]


def solve_with_correction(
    solver: CalibrationSolver,
    usual: CalibrationResult,
    corners: torch.Tensor,
    found: torch.Tensor,
    correction: torch.Tensor,
    apply: torch.Tensor,
    board_size: tuple[int, int],
    square: float,
    image_size: tuple[int, int],
    joint_iters: int = 50,
    free_distortion_centre: bool = True,
    max_rms_ratio: float = 1.0,
) -> tuple[CalibrationResult, torch.Tensor, torch.Tensor]:
    """The solver stage of the corrected pipeline: the usual calibration, and for cameras in ``apply`` the
    corrected-frame one (:func:`calibrate_corrected`), kept unless it fits the observed corners clearly worse.

    Args:
        solver: the usual solver (its model is the output model).
        usual: the usual calibration of these corners by ``solver``.
        corners: :math:`(C, V, N, 2)`; found: :math:`(C, V)`; correction: :math:`(C, 5)` pooled corrections;
        apply: :math:`(C,)` bool, cameras to calibrate in the corrected frame.
        board_size, square, image_size: the board and the image size ``(W, H)``.
        joint_iters, free_distortion_centre: see :func:`calibrate_corrected`.
        max_rms_ratio: the corrected-frame calibration is kept only if its radial model's RMS on the observed
            corners is at most this times that of the usual calibration.

    Returns:
        (calibration, correction per camera (re-fitted where applied), applied :math:`(C,)`).
    """
    calib = usual
    applied = apply.to(corners.device).clone()
    correction = correction.to(corners.device)
    # the model selection below compares equal parameter counts: the radial model (k1, k2, k3 + centre) against
    # opencv5 (or the richer rational model); for k1k2 / none the usual calibration is kept
    if bool(applied.any()) and solver.model in (OPENCV5, RATIONAL):
        corrected, refined, model_rms = calibrate_corrected(solver, corners, found, correction, board_size, square,
                                                            image_size, joint_iters, free_distortion_centre)
        # model selection on the observed corners: the radial model about a free centre (the paper's) against
        # OpenCV's (radial about the principal point + tangential), same number of parameters; the better fit
        # wins
        fits = model_rms.to(calib.rms) <= max_rms_ratio * calib.rms.nan_to_num(float("inf"))
        applied = applied & corrected.success & fits
        calib = select_cameras(applied, corrected, calib)
        correction = torch.where(applied[:, None], refined, correction)
    else:
        applied = torch.zeros_like(applied)
    return calib, correction, applied


def calibrate_corrected(
    solver: CalibrationSolver,
    corners: torch.Tensor,
    found: torch.Tensor,
    correction: torch.Tensor,
    board_size: tuple[int, int],
    square: float,
    image_size: tuple[int, int],
    joint_iters: int = 50,
    free_distortion_centre: bool = True,
) -> tuple[CalibrationResult, torch.Tensor, torch.Tensor]:
    """Calibrate in the radially corrected frame, then express the camera in the OpenCV model.

    The paper's order: the correction removes the lens distortion first, so the intrinsics are estimated
    on (nearly) pinhole corners with only a small residual ``k1, k2`` to absorb what the network missed;
    estimating strong distortion and intrinsics together is where they trade off against each other.
    The correction is then re-fitted to that camera (observed corners -> their pinhole projections,
    :func:`~ccs_kornia.modules.correction.correction_fit.fit_correction_to_points`) and, beyond the paper,
    intrinsics, correction and poses are refined together
    (:func:`~ccs_kornia.modules.calibration.centred_radial.refine_centred_radial`, at most ``joint_iters`` LM
    iterations). Finally the intrinsics are held and the output model's distortion
    and the poses are refined on the observed corners (closed-form start, then LM). The result's ``cov_camera``
    (and standard deviations) take the intrinsics block from the joint refinement (from the corrected-frame
    calibration when ``joint_iters`` is 0); the distortion block is the output fit's given those intrinsics plus
    the intrinsics' uncertainty propagated through that fit (:func:`_propagated_covariance`).

    Args:
        solver: the usual solver: its model is the output model, its RANSAC and intrinsics options carry over.
        corners: :math:`(C, V, N, 2)` observed corners; found: :math:`(C, V)`.
        correction: :math:`(C, 5)` initial correction (the network's).
        board_size, square, image_size: the board and the image size ``(W, H)``.
        joint_iters: Levenberg-Marquardt iterations at most of the joint refinement (0: the pinhole calibration
            of the corrected corners as it is).
        free_distortion_centre: the joint refinement also estimates the distortion centre.

    Returns:
        (result in the OpenCV model, refined correction :math:`(C, 5)`, RMS reprojection error of the radial
        model :math:`(C,)`, before the conversion to the output model).
    """
    c, v, n = corners.shape[:3]
    dev = corners.device
    corners = corners.to(torch.float64)
    valid = measured_corners(corners, found.to(dev))
    obj = board_object_points(*check_board_size(board_size), float(square), device=dev, dtype=torch.float64)
    frame_solver = CalibrationSolver(
        model=K1K2, use_ransac=solver.use_ransac, seed=0, fix_aspect_ratio=solver.fix_aspect_ratio,
        fix_principal_point=solver.fix_principal_point,
    )
    corr = correction.to(device=dev, dtype=torch.float64)
    with torch.inference_mode():
        # 1. pinhole (+ small residual k1, k2) calibration on the network-corrected corners
        pinhole = correct_points(corners.reshape(c, v * n, 2), corr, image_size).reshape(c, v, n, 2)
        res = frame_solver(pinhole, valid, obj, image_size)
        # 2. the correction re-fitted to that camera (absorbs the residual)
        ideal = Camera(PINHOLE, res.camera.params[:, :4]).project(obj.expand(c, v, n, 3), res.rvec, res.tvec)
        use = valid & res.used[..., None]
        refit = fit_correction_to_points(corners.reshape(c, v * n, 2), ideal.reshape(c, v * n, 2), image_size,
                                         use.reshape(c, v * n))
        corr = torch.where((res.success & refit.isfinite().all(-1))[:, None], refit, corr)
        model_rms = None
        cov_k = res.cov_camera[:, :4, :4]
        if joint_iters > 0:
            # 3. intrinsics, image-centred radial distortion and poses together, on the observed corners; the
            # distortion starts from a fit to those corners (where they are: the refitted correction extrapolated
            # to the image corner can fold, and its conversion then starts the LM at k ~ 1e9, which crawls for
            # hundreds of iterations or ends in a wrong minimum: docs/measurements.md)
            radial0 = radial_from_points(ideal.reshape(c, v * n, 2), corners.reshape(c, v * n, 2), image_size,
                                         use.reshape(c, v * n))
            K1, rad1, rv1, tv1, rms1, _, _, cov1 = refine_centred_radial(
                corners, use, obj, res.K.nan_to_num(1.0), res.rvec, res.tvec, radial0, image_size,
                max_iters=joint_iters, free_centre=free_distortion_centre, covariance=True,
            )
            good = res.success & K1.flatten(1).isfinite().all(-1) & rad1.isfinite().all(-1) & rms1.isfinite()
            cov_k = torch.where(good[:, None, None], cov1[:, :4, :4], cov_k)
            model_rms = torch.where(good, rms1, torch.full_like(rms1, float("inf")))
            p = res.camera.params
            intrinsics = torch.where(good[:, None], intrinsics_params(K1), p[:, :4])
            res = replace(res, camera=res.camera.with_params(torch.cat([intrinsics, p[:, 4:]], -1)),
                          rvec=torch.where(good[:, None, None], rv1, res.rvec),
                          tvec=torch.where(good[:, None, None], tv1, res.tvec))
        ideal = Camera(PINHOLE, res.camera.params[:, :4]).project(obj.expand(c, v, n, 3), res.rvec, res.tvec)
        use = (valid & res.used[..., None]).reshape(c, v * n)
        # a refused camera has a NaN K; a finite stand-in keeps the closed form defined (the final solve refuses
        # that camera again)
        k_safe = torch.tensor([[max(image_size), 0, (image_size[0] - 1) / 2], [0, max(image_size), (image_size[1] - 1) / 2],
                               [0, 0, 1]], dtype=res.K.dtype, device=dev)
        k_safe = torch.where(res.success[:, None, None] & res.K.isfinite(), res.K, k_safe)
        dist0 = solver.model.fit_coeffs(ideal.reshape(c, v * n, 2).nan_to_num(0.0), corners.reshape(c, v * n, 2),
                                        k_safe, mask=use)
        start = replace(res, camera=Camera(solver.model, solver.model.params_from(res.K, dist0.nan_to_num(0.0)),
                                           image_size))
        out = solver(corners, valid, obj, image_size, initial=start, fix_intrinsics=True)
        # the intrinsics were estimated before the final fit held them: report their uncertainty, not a fixed 0
        cov = _propagated_covariance(solver.model, out, corners, valid, obj, cov_k.to(out.K.dtype))
        ok = out.success & cov.flatten(1).isfinite().all(-1)
        std = cov.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
        out = replace(out, cov_camera=torch.where(ok[:, None, None], cov, out.cov_camera),
                      std_intrinsics=torch.where(ok[:, None], std[:, :4], out.std_intrinsics),
                      std_dist=torch.where(ok[:, None], std[:, 4:], out.std_dist))
    return out, corr, (out.rms if model_rms is None else model_rms)


def _propagated_covariance(model, out, corners, valid, obj, cov_k):
    """Covariance :math:`(C, 4 + D, 4 + D)` of the output camera whose intrinsics were held in its last fit.

    ``cov_k`` :math:`(C, 4, 4)` is the intrinsics' covariance where they were estimated. The last fit makes the
    distortion ``d`` (and the poses) a function of the intrinsics ``k``; linearised with the information matrix
    ``S`` of the output model at the solution (poses eliminated, one evaluation of the LM core):
    ``d d / d k = A = -S_dd^-1 S_dk``, ``Cov(k, d) = cov_k A^T`` and ``Cov(d) = sigma^2 S_dd^-1 + A cov_k A^T``
    (the fit's own noise plus the intrinsics' uncertainty carried into the distortion).
    """
    cam = model
    c, v, n = corners.shape[:3]
    if cam.num_params == 4:
        return cov_k
    params = out.camera.nan_to_num().params
    w = valid & out.used[..., None]
    lm = levenberg_marquardt(cam, params, out.rvec, out.tvec, obj, corners, w, max_iters=0)
    S = lm.information
    Sdd, Sdk = S[:, 4:, 4:], S[:, 4:, :4]
    d = Sdd.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    scaled = (Sdd * d[:, :, None] * d[:, None, :]).nan_to_num(0.0)
    Sdd_inv = torch.linalg.pinv(scaled, hermitian=True) * d[:, :, None] * d[:, None, :]
    A = -Sdd_inv @ Sdk
    kd = cov_k @ A.transpose(-1, -2)
    dd = Sdd_inv * lm.sigma2[:, None, None] + A @ kd
    full = torch.cat([torch.cat([cov_k, kd], -1), torch.cat([kd.transpose(-1, -2), dd], -1)], -2)
    return camera_covariance(model, full)




def select_cameras(keep: torch.Tensor, a: CalibrationResult, b: CalibrationResult) -> CalibrationResult:
    """Per camera, ``a`` where ``keep`` else ``b`` (every tensor field has the camera dimension first; the cameras
    of both have the same models)."""
    out = {}
    for k, va in a.__dict__.items():
        vb = getattr(b, k)
        if isinstance(va, Camera):
            if va.models != vb.models:
                raise ValueError(f"select_cameras: the results' cameras differ in model ({va!r}, {vb!r}).")
            out[k] = va.with_params(torch.where(keep.to(va.device)[:, None], va.params, vb.params.to(va.params)))
        elif isinstance(va, torch.Tensor) and isinstance(vb, torch.Tensor) and va.shape == vb.shape:
            out[k] = torch.where(keep.to(va.device).view(-1, *([1] * (va.dim() - 1))), va, vb)
        else:
            out[k] = va
    return CalibrationResult(**out)
