"""Held-out errors of a calibration: the board corners of frames it did not use, posed anew and projected.

* :func:`heldout_errors`: per held-out frame, the board's pose fitted to its corners with the camera held fixed
  (``cv2.solvePnP`` then Levenberg-Marquardt; ``cv2.fisheye`` for a fisheye camera through its undistorted points), and
  the squared distances between the corners and their projections: a camera whose lens is wrong leaves errors the pose
  cannot absorb.
* :func:`transfer_errors`: a rig's held-out instants: the board posed in one camera, carried into another through
  the rig's extrinsics and projected there, against that camera's own corners.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from ccs_kornia.geometry.camera import Camera

__all__ = ["MIN_CORNERS", "heldout_errors", "pose_board", "project", "rms", "transfer_errors"]

#: a held-out view is posed from at least this many corners
MIN_CORNERS = 6


def _opencv(camera: Camera) -> tuple[np.ndarray, np.ndarray, bool]:
    """One camera as OpenCV takes it: ``K``, its coefficients (float64) and whether ``cv2.fisheye``'s functions do."""
    return camera.K[0].double().numpy(), camera.coeffs(0).double().numpy(), camera.model.is_fisheye


def pose_board(camera: Camera, obj: np.ndarray, img: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(rvec, tvec)`` of the board (object points ``obj`` :math:`(N, 3)`) seen at ``img`` :math:`(N, 2)` by ``camera``
    (one camera; ``None``: fewer than :data:`MIN_CORNERS` corners, or no pose)."""
    ok = np.isfinite(img).all(-1)
    if ok.sum() < MIN_CORNERS:
        return None
    K, dist, fisheye = _opencv(camera)
    o, p = obj[ok].astype(np.float64), img[ok].astype(np.float64)
    if fisheye:
        und = cv2.fisheye.undistortPoints(p[:, None], K, dist[:4]).reshape(-1, 2)
        Kn, dn = np.eye(3), np.zeros(5)
    else:
        und, Kn, dn = p, K, dist
    good, rvec, tvec = cv2.solvePnP(o, und, Kn, dn, flags=cv2.SOLVEPNP_ITERATIVE)
    if not good:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(o, und, Kn, dn, rvec, tvec)
    if fisheye:  # refine on the image itself, as the calibration measures it
        rvec, tvec = _refine_fisheye(K, dist, o, p, rvec, tvec)
    return rvec.reshape(3), tvec.reshape(3)


def _refine_fisheye(K, dist, obj, img, rvec, tvec, iters: int = 10):
    """Gauss-Newton on the pose through ``cv2.fisheye.projectPoints``' Jacobian."""
    x = np.concatenate([rvec.reshape(3), tvec.reshape(3)])
    for _ in range(iters):
        p, J = cv2.fisheye.projectPoints(obj[:, None], x[:3], x[3:], K, dist[:4])
        r = (p.reshape(-1, 2) - img).reshape(-1)
        Jp = J[:, 8:14] if J.shape[1] >= 14 else J[:, -6:]
        step = np.linalg.lstsq(Jp, -r, rcond=None)[0]
        x = x + step
        if np.abs(step).max() < 1e-10:
            break
    return x[:3], x[3:]


def project(camera: Camera, obj: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """Pixels :math:`(N, 2)` of the object points ``obj`` at pose ``(rvec, tvec)`` seen by ``camera`` (one camera;
    OpenCV's projection, as OpenCV's pose)."""
    K, dist, fisheye = _opencv(camera)
    if fisheye:
        p, _ = cv2.fisheye.projectPoints(obj[:, None].astype(np.float64), rvec, tvec, K, dist[:4])
    else:
        p, _ = cv2.projectPoints(obj.astype(np.float64), rvec, tvec, K, dist)
    return p.reshape(-1, 2)


def heldout_errors(camera: Camera, obj: np.ndarray, frames: Sequence[np.ndarray]) -> np.ndarray:
    """Squared reprojection errors (px²) of every corner of the held-out ``frames`` (each :math:`(N, 2)`, NaN where
    not seen), each frame posed anew with ``camera`` (one camera) fixed; frames that cannot be posed are left out."""
    out = []
    for img in frames:
        pose = pose_board(camera, obj, img)
        if pose is None:
            continue
        ok = np.isfinite(img).all(-1)
        p = project(camera, obj[ok], *pose)
        out.append(((p - img[ok]) ** 2).sum(-1))
    return np.concatenate(out) if out else np.zeros(0)


def transfer_errors(cameras: Camera, R: Sequence[np.ndarray], T: Sequence[np.ndarray], obj: np.ndarray,
                    frames: Sequence[Sequence[np.ndarray | None]]) -> np.ndarray:
    """Squared errors (px²) of a rig's held-out instants carried from camera to camera.

    Args:
        cameras: the rig's ``C`` cameras (any models).
        R, T: per camera its pose from camera 0 (``x_c = R_c x_0 + T_c``).
        obj: :math:`(N, 3)` the board's corners.
        frames: per instant, per camera, its corners :math:`(N, 2)` (NaN where not seen; ``None``: no frame).

    Returns:
        Every corner of every ordered pair of cameras that both pose the board at an instant: the board posed in the
        first, projected into the second, against the second's corners.
    """
    out = []
    for views in frames:
        poses = {}
        for c, img in enumerate(views):
            if img is not None:
                pose = pose_board(cameras[c], obj, img)
                if pose is not None:
                    poses[c] = pose
        for i, (rv, tv) in poses.items():
            Ri = cv2.Rodrigues(rv)[0]
            for j in poses:
                if j == i:
                    continue
                # board -> camera i -> camera 0 -> camera j
                R0 = R[i].T @ Ri
                t0 = R[i].T @ (tv - T[i])
                Rj, tj = R[j] @ R0, R[j] @ t0 + T[j]
                img = views[j]
                ok = np.isfinite(img).all(-1)
                p = project(cameras[j], obj[ok], cv2.Rodrigues(Rj)[0].reshape(3), tj)
                out.append(((p - img[ok]) ** 2).sum(-1))
    return np.concatenate(out) if out else np.zeros(0)


def rms(squared: np.ndarray) -> float | None:
    """The root mean of squared errors (``None`` when there are none)."""
    return float(math.sqrt(squared.mean())) if squared.size else None
