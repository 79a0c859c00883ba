"""Joint refinement of intrinsics, OpenCV distortion and every pose on the one LM core (:mod:`.lm`).

:func:`joint_refinement` takes and returns the camera in OpenCV's terms (``K``, coefficients in OpenCV order),
with the options :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` needs (fixed aspect ratio,
principal point, intrinsics or distortion); the core does the work with
:class:`~ccs_kornia.geometry.models.opencv.OpenCVModel`, batched over cameras, and gives the full
covariance of the camera (``cov_camera``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.geometry.models.opencv import OpenCVModel
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["RefinementResult", "joint_refinement", "JointRefinement", "camera_covariance"]


def _opencv_variant(model: CameraModel) -> OpenCVModel:
    if not isinstance(model, OpenCVModel):
        raise ValueError(f"The joint refinement takes one of OpenCV's models (ccs_kornia.geometry.models.PINHOLE, "
                         f"K1K2, OPENCV5, RATIONAL), got {model!r}.")
    return model


@dataclass
class RefinementResult:
    """Output of :func:`joint_refinement` (C cameras, V views, D coefficients)."""

    K: torch.Tensor  #: (C, 3, 3)
    dist: torch.Tensor  #: (C, D) OpenCV order
    rvec: torch.Tensor  #: (C, V, 3)
    tvec: torch.Tensor  #: (C, V, 3)
    view_rms: torch.Tensor  #: (C, V) RMS reprojection error per view in px, NaN for unused views
    rms: torch.Tensor  #: (C,) sqrt(sum squared error / number of points), as cv2.calibrateCamera
    std_intrinsics: torch.Tensor  #: (C, 4) standard deviations of fx, fy, cx, cy (0 where fixed)
    std_dist: torch.Tensor  #: (C, D) standard deviations of the coefficients (0 where fixed)
    status: torch.Tensor  #: (C,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus` of each camera
    iterations: torch.Tensor  #: (C,) LM iterations used
    num_points: torch.Tensor  #: (C,) corners used
    #: (C, 4 + D, 4 + D) covariance of (fx, fy, cx, cy, dist) (zero rows/columns for fixed parameters)
    cov_camera: torch.Tensor | None = None
    #: (C, 2) the board's sag (mrcal's ``calobject_warp``) where it was estimated, else None
    warp: torch.Tensor | None = None
    #: (C, 2, 2) its covariance, else None
    warp_covariance: torch.Tensor | None = None


def camera_covariance(model: CameraModel, param_covariance: torch.Tensor) -> torch.Tensor:
    """Covariance :math:`(C, 4 + D, 4 + D)` of ``(fx, fy, cx, cy, dist[:D])`` in OpenCV's storage (``D`` the model's
    :attr:`~ccs_kornia.geometry.models.base.CameraModel.num_coeffs`) from that of the model's parameters
    :math:`(C, P, P)`: a selection, zero rows and columns for stored coefficients outside the model (``k1k2``
    stores ``p1 = p2 = k3 = 0``).

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> camera_covariance(K1K2, torch.eye(6)[None]).shape
        torch.Size([1, 9, 9])
    """
    index = model.coeff_index
    D = model.num_coeffs
    if len(index) == D:  # every stored coefficient is a parameter, in order
        return param_covariance
    rows = torch.tensor([0, 1, 2, 3, *(4 + j for j in index)], device=param_covariance.device)
    out = param_covariance.new_zeros(*param_covariance.shape[:-2], 4 + D, 4 + D)
    out[..., rows[:, None], rows] = param_covariance
    return out


def _k_matrix(params: torch.Tensor) -> torch.Tensor:
    z, o = torch.zeros_like(params[:, :1]), torch.ones_like(params[:, :1])
    return torch.cat([params[:, 0:1], z, params[:, 2:3], z, params[:, 1:2], params[:, 3:4], z, z, o], -1).view(-1, 3, 3)


def _batch(corners, valid, object_points, K, rvec, tvec, dist, view_mask):
    """Add the camera dim to unbatched inputs and check shapes."""
    unbatched = corners.dim() == 3
    if unbatched:
        corners, valid, rvec, tvec = corners[None], valid[None], rvec[None], tvec[None]
        K = K[None] if K.dim() == 2 else K
        dist = dist[None] if dist is not None and dist.dim() == 1 else dist
        view_mask = None if view_mask is None else view_mask[None]
        object_points = object_points[None] if object_points.dim() == 3 else object_points
    check_tensor(corners, "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
    C, V, N = corners.shape[:3]
    check_tensor(valid, "valid", [C, V, N])
    check_tensor(K, "K", [C, 3, 3])
    if view_mask is not None:
        check_tensor(view_mask, "view_mask", [C, V])
    return corners, valid, object_points, K, rvec, tvec, dist, view_mask, unbatched


def joint_refinement(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    K: torch.Tensor,
    rvec: torch.Tensor,
    tvec: torch.Tensor,
    dist: torch.Tensor | None = None,
    view_mask: torch.Tensor | None = None,
    model: OpenCVModel = OPENCV5,
    fix_aspect_ratio: bool = False,
    fix_principal_point: bool = False,
    max_iters: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    lambda_init: float = 1e-3,
    dtype: torch.dtype = torch.float64,
    fix_intrinsics: bool = False,
    fix_distortion: bool = False,
    weights: torch.Tensor | None = None,
    stall_tol: float = 0.0,
    board_warp: torch.Tensor | None = None,
) -> RefinementResult:
    r"""Levenberg–Marquardt over intrinsics, OpenCV distortion and poses (the LM core with the OpenCV model).

    Args:
        corners: :math:`(C, V, N, 2)` observed pixels (or :math:`(V, N, 2)`); invalid entries may be NaN.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)`.
        K: :math:`(C, 3, 3)` initial camera matrices (zero skew).
        rvec, tvec: :math:`(C, V, 3)` initial poses.
        dist: :math:`(C, D')` initial OpenCV coefficients (default zeros).
        view_mask: :math:`(C, V)` views to use (default: views with a valid corner).
        model: one of OpenCV's models (:data:`~ccs_kornia.geometry.models.PINHOLE`, ``K1K2``, ``OPENCV5``,
            ``RATIONAL``).
        fix_aspect_ratio, fix_principal_point, fix_intrinsics, fix_distortion: keep those at their initial values.
        max_iters, ftol, xtol, lambda_init, dtype, stall_tol: see
            :func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt`.
        weights: optional :math:`(C, V, N)` per-corner inverse variances (multiplied by ``valid``).
        board_warp: :math:`(C, 2)` the board's sag to start from, estimated with the rest
            (:mod:`~ccs_kornia.geometry.board_warp`); ``None``: a flat board.

    Returns:
        :class:`RefinementResult` (no camera dim for unbatched input), with the covariance of the model's
        ``fx, fy, cx, cy`` and coefficients.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> obj = board_object_points(4, 3, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rvec = torch.tensor([[0.2, 0.1, 0.0], [-0.2, 0.3, 0.1], [0.1, -0.3, 0.2]], dtype=torch.float64)
        >>> tvec = torch.tensor([[-0.1, -0.1, 1.0]], dtype=torch.float64).expand(3, 3)
        >>> uv = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), None, rvec, tvec)
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> res = joint_refinement(uv, torch.ones(3, 12, dtype=torch.bool), obj, K * 1.01, rvec, tvec, model=PINHOLE)
        >>> bool(res.rms < 1e-6)
        True
    """
    cam = _opencv_variant(model)
    corners, valid, object_points, K, rvec, tvec, dist, view_mask, unbatched = _batch(
        corners, valid, object_points, K, rvec, tvec, dist, view_mask
    )
    C, V, N = corners.shape[:3]
    params = cam.params_from(K.to(device=corners.device, dtype=dtype), None if dist is None else dist.to(corners.device))
    w = valid.bool() & (valid.bool().any(-1, keepdim=True) if view_mask is None else view_mask.bool()[..., None])
    w = w.to(dtype) if weights is None else w.to(dtype) * weights.to(dtype)
    free = [not fix_intrinsics] * 2 + [not (fix_intrinsics or fix_principal_point)] * 2
    free += [not fix_distortion] * (cam.num_params - 4)
    res = levenberg_marquardt(
        cam, params, rvec, tvec, object_points, corners, w, free=free,
        fix_aspect_ratio=fix_aspect_ratio and not fix_intrinsics, max_iters=max_iters, ftol=ftol, xtol=xtol,
        lambda_init=lambda_init, dtype=dtype, stall_tol=stall_tol,
        board_warp=None if board_warp is None else (board_warp[None] if unbatched else board_warp),
    )
    D = cam.num_coeffs
    cov = camera_covariance(cam, res.param_covariance)
    std = cov.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
    out = RefinementResult(
        K=_k_matrix(res.params), dist=cam.dist8(res.params)[:, :D], rvec=res.rvec, tvec=res.tvec,
        view_rms=res.view_rms, rms=res.rms, std_intrinsics=std[:, :4], std_dist=std[:, 4:],
        status=res.status, iterations=res.iterations, num_points=res.num_points, cov_camera=cov, warp=res.warp,
        warp_covariance=res.warp_covariance,
    )
    if unbatched:
        out = RefinementResult(**{k: None if v is None else v[0] for k, v in out.__dict__.items()})
    return out


class JointRefinement(nn.Module):
    """Module form of :func:`joint_refinement` (options fixed at construction).

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> JointRefinement(model=K1K2).model
        OpenCVModel('k1k2')
    """

    def __init__(self, model: OpenCVModel = OPENCV5, fix_aspect_ratio: bool = False, fix_principal_point: bool = False,
                 max_iters: int = 100, ftol: float = 1e-12, xtol: float = 1e-12, dtype: torch.dtype = torch.float64) -> None:
        super().__init__()
        self.model, self.fix_aspect_ratio, self.fix_principal_point = _opencv_variant(model), fix_aspect_ratio, fix_principal_point
        self.max_iters, self.ftol, self.xtol, self.dtype = max_iters, ftol, xtol, dtype

    def forward(self, corners, valid, object_points, K, rvec, tvec, dist=None, view_mask=None) -> RefinementResult:
        return joint_refinement(
            corners, valid, object_points, K, rvec, tvec, dist, view_mask, model=self.model,
            fix_aspect_ratio=self.fix_aspect_ratio, fix_principal_point=self.fix_principal_point,
            max_iters=self.max_iters, ftol=self.ftol, xtol=self.xtol, dtype=self.dtype,
        )

