"""Two cameras of a rig: :class:`StereoPair` (relative pose, essential and fundamental matrices), epipolar distances
and :func:`stereo_rectify`.

Conventions (OpenCV's ``stereoCalibrate``): ``x_j = R x_i + T``, ``E = [T]_x R``; ``F = K_j^{-T} E K_i^{-1}`` relates
*undistorted* pixels (``K`` applied to the undistorted normalized coordinates): ``p_j^T F p_i = 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.so3 import skew

__all__ = ["StereoPair", "stereo_pair", "epipolar_distances", "stereo_rectify"]


@dataclass
class StereoPair:
    """Relative pose of camera j with respect to camera i: ``x_j = R x_i + T``; ``E = [T]_x R``; ``F`` on undistorted
    pixels (``p_j^T F p_i = 0``)."""

    R: torch.Tensor  #: (3, 3)
    T: torch.Tensor  #: (3,)
    E: torch.Tensor  #: (3, 3)
    F: torch.Tensor  #: (3, 3)

    @property
    def baseline(self) -> float:
        """``|T|`` in the board's unit."""
        return float(self.T.norm())


def stereo_pair(cam_i: Camera, cam_j: Camera, R: torch.Tensor, T: torch.Tensor) -> StereoPair:
    """:class:`StereoPair` of two cameras (one each) with ``x_j = R x_i + T``.

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> cam = Camera(PINHOLE, torch.tensor([500., 500, 320, 240], dtype=torch.float64))
        >>> p = stereo_pair(cam, cam, torch.eye(3, dtype=torch.float64), torch.tensor([-0.1, 0, 0], dtype=torch.float64))
        >>> p.E[1:, 2].tolist()  # [T]_x: a horizontal baseline only relates the rows
        [0.1, 0.0]
    """
    E = skew(T) @ R
    Ki, Kj = cam_i.K[0].to(R.dtype), cam_j.K[0].to(R.dtype)
    F = torch.linalg.inv(Kj).T @ E @ torch.linalg.inv(Ki)
    return StereoPair(R=R, T=T, E=E, F=F)


def epipolar_distances(
    cam_i: Camera, cam_j: Camera, R: torch.Tensor, T: torch.Tensor, uv_i: torch.Tensor, uv_j: torch.Tensor,
    max_angle_deg: float = 80.0,
) -> torch.Tensor:
    """Symmetric epipolar distance (px) of matching observed pixels :math:`(M, 2)` of cameras i and j.

    Both are undistorted (each with its own model) to ideal pixels ``K x``; the distance is the RMS of the two
    point-to-epipolar-line distances, each in its own camera's pixels. A pixel further than ``max_angle_deg`` from
    its camera's axis (a fisheye's rim) has no meaningful undistorted pixel (it runs to infinity at 90 degrees): its
    distance is NaN. Returns :math:`(M,)`.
    """
    dtype = R.dtype
    pair = stereo_pair(cam_i, cam_j, R, T)
    cam_i, cam_j = cam_i.to(dtype=dtype), cam_j.to(dtype=dtype)
    xi = cam_i.undistort(uv_i.to(dtype)[None], P=cam_i.K)[0]
    xj = cam_j.undistort(uv_j.to(dtype)[None], P=cam_j.K)[0]
    ones = torch.ones_like(xi[..., :1])
    xi, xj = torch.cat([xi, ones], -1), torch.cat([xj, ones], -1)
    lj = xi @ pair.F.T  # lines in j
    li = xj @ pair.F  # lines in i
    alg = (xj * lj).sum(-1)
    dj = alg / lj[..., :2].norm(dim=-1).clamp_min(1e-300)
    di = alg / li[..., :2].norm(dim=-1).clamp_min(1e-300)
    d = ((dj * dj + di * di) / 2).sqrt()
    limit = math.cos(math.radians(max_angle_deg))
    for cam, uv in ((cam_i, uv_i), (cam_j, uv_j)):
        z = cam.unproject(uv.to(dtype)[None])[0, :, 2]
        d = torch.where(z > limit, d, float("nan"))
    return d


def _np(x) -> np.ndarray:
    return np.asarray(x.detach().cpu().double().numpy() if isinstance(x, torch.Tensor) else x, dtype=np.float64)


def stereo_rectify(
    cam1: Camera, cam2: Camera, image_size: tuple[int, int], R: torch.Tensor, T: torch.Tensor,
    alpha: float = 0.0,
) -> dict:
    """Rectifying rotations and projections of a stereo pair (``x_2 = R x_1 + T``).

    * two pinhole cameras: ``cv2.stereoRectify`` (``CALIB_ZERO_DISPARITY``, ``alpha``);
    * two fisheye cameras: ``cv2.fisheye.stereoRectify`` (``CALIB_ZERO_DISPARITY``, ``balance = alpha``); it has no
      valid-pixel rectangles, so ``roi1``/``roi2`` are the whole image;
    * one of each: the rectification of the two cameras with their distortion removed (``cv2.stereoRectify`` with
      zero coefficients): ``R1, R2, P1, P2, Q`` then hold for the undistorted images, so each camera is remapped with
      its own model's function (``cv2.fisheye.initUndistortRectifyMap`` for the fisheye,
      ``cv2.initUndistortRectifyMap`` for the other) from its own ``K, dist`` to ``R_k, P_k``; ``alpha`` and the
      rectangles ignore the distortion; the same where a camera has no OpenCV model (a splined one, remapped through
      its own projection).

    Args:
        cam1, cam2: the two cameras (one each).
        image_size: ``(W, H)`` of the rectified images.
        R: :math:`(3, 3)`; T: :math:`(3,)` pose of camera 2 relative to camera 1.
        alpha: free scaling (0: only valid pixels, 1: all source pixels).

    Returns:
        ``{"R1", "R2", "P1", "P2", "Q"}`` (numpy float64) and ``"roi1", "roi2"`` (``(x, y, w, h)``).

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> cam = Camera(K1K2, torch.tensor([500., 500, 320, 240, -0.1, 0.01], dtype=torch.float64))
        >>> out = stereo_rectify(cam, cam, (640, 480), torch.eye(3, dtype=torch.float64), torch.tensor([-0.1, 0, 0.]))
        >>> sorted(out), round(float(out["P2"][0, 3] / out["P2"][0, 0]), 6)
        (['P1', 'P2', 'Q', 'R1', 'R2', 'roi1', 'roi2'], -0.1)
    """
    import cv2

    size = (int(image_size[0]), int(image_size[1]))
    K1, K2, Rn, Tn = _np(cam1.K[0]), _np(cam2.K[0]), _np(R), _np(T).reshape(3, 1)
    # OpenCV's two APIs: cv2.fisheye for Kannala-Brandt lenses, cv2 for its polynomial model
    fish = (cam1.model.is_fisheye, cam2.model.is_fisheye)
    if all(fish):
        D1, D2 = (c.model.opencv_coeffs(_np(c.dist[0])).reshape(4, 1) for c in (cam1, cam2))
        R1, R2, P1, P2, Q = cv2.fisheye.stereoRectify(K1, D1, K2, D2, size, Rn, Tn, cv2.CALIB_ZERO_DISPARITY,
                                                      balance=float(alpha))
        roi1 = roi2 = (0, 0, size[0], size[1])
    else:
        if any(fish) or any(c.model.opencv_family not in ("opencv", "fisheye") for c in (cam1, cam2)):
            d1 = d2 = np.zeros(5)  # (a splined camera: the rectification of the undistorted pair, as one of each)
        else:
            d1, d2 = (c.model.opencv_coeffs(_np(c.dist[0])) for c in (cam1, cam2))
        R1, R2, P1, P2, Q, roi1, roi2 = cv2.stereoRectify(K1, d1, K2, d2, size, Rn, Tn, flags=cv2.CALIB_ZERO_DISPARITY,
                                                          alpha=float(alpha))
    return {"R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q, "roi1": tuple(int(v) for v in roi1),
            "roi2": tuple(int(v) for v in roi2)}
