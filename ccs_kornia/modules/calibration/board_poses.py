"""The board's pose in every view of a camera whose parameters are known: the start of a rig's and a hand-eye's fit.

The corners are undistorted through the camera (:meth:`~ccs_kornia.geometry.camera.Camera.undistort`), each view's
pose is read from the homography of the undistorted corners (:func:`~ccs_kornia.modules.calibration.zhang.extrinsics_from_homography`)
and refined with the camera held (:func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt`). Used by the rig's
initialisation (:mod:`ccs_kornia.modules.rig.rig_init`) and the hand-eye solver (:mod:`ccs_kornia.modules.hand_eye.solver`).
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.modules.calibration.homography import find_homographies
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.zhang import extrinsics_from_homography

__all__ = ["camera_poses"]


def camera_poses(
    cam_params: torch.Tensor,
    model: CameraModel,
    corners: torch.Tensor,
    valid: torch.Tensor,
    obj: torch.Tensor,
    min_corners: int = 6,
    rvec0: torch.Tensor | None = None,
    tvec0: torch.Tensor | None = None,
    known: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Board poses of one camera of B rigs in every frame with at least ``min_corners`` corners.

    Args:
        cam_params: :math:`(B, P)` the camera's parameters (held).
        model: its model.
        corners: :math:`(B, F, N, 2)`; valid :math:`(B, F, N)`; obj :math:`(N, 3)`.
        rvec0, tvec0, known: optional poses :math:`(B, F, 3)` to start from where ``known`` :math:`(B, F)` is True
            (elsewhere: the homography of the undistorted corners).

    Returns:
        rvec, tvec :math:`(B, F, 3)`, ok :math:`(B, F)` and the per-frame RMS :math:`(B, F)` px (NaN where not ok).
    """
    B, F, N = corners.shape[:3]
    dtype = cam_params.dtype
    enough = valid.sum(-1) >= min_corners
    norm = Camera(model, cam_params).undistort(corners.nan_to_num(0.0))
    mask = valid & enough[..., None] & norm.isfinite().all(-1)
    H, ok_h = find_homographies(obj[:, :2].expand(B, 1, N, 2), torch.where(mask[..., None], norm, 0.0), mask,
                                return_ok=True)
    eye = torch.eye(3, dtype=dtype, device=corners.device)
    rvec, tvec = extrinsics_from_homography(eye.expand(B, F, 3, 3), H)
    if known is not None:
        rvec = torch.where(known[..., None], rvec0.to(dtype), rvec)
        tvec = torch.where(known[..., None], tvec0.to(dtype), tvec)
        ok_h = ok_h | (known & enough)
    ok = enough & ok_h & rvec.isfinite().all(-1) & tvec.isfinite().all(-1)
    w = (valid & ok[..., None]).to(dtype)
    m = model
    res = levenberg_marquardt(m, cam_params, rvec.nan_to_num(0.0), tvec.nan_to_num(1.0), obj, corners, w,
                              free=[False] * m.num_params, max_iters=50)
    ok = ok & res.view_rms.isfinite()
    return res.rvec, res.tvec, ok, res.view_rms.masked_fill(~ok, float("nan"))
