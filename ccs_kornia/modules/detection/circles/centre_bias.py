r"""The centre of a dot's image is not the image of the dot's centre: the offset, given the camera and the board's pose.

A circle on the board seen through a pinhole images as an ellipse whose centre lies off the projection of the
circle's centre, towards the nearer side of a tilted board (Heikkila 2000, "Geometric camera calibration using
circular control points"); lens distortion moves it again. The detector measures the centre of each dot's image
(:mod:`~ccs_kornia.modules.detection.circles.dot_moments`); this module predicts, for a camera and a pose, that
centre's offset from the projected true centre: the dot's rim (:data:`RIM_POINTS` points on the circle) is projected
through the whole camera model, lens included, and the centroid of the polygon it bounds is compared with the
projection of the centre. The calibration subtracts it from the measured centres and solves again
(:func:`~ccs_kornia.pipeline.solve.solve_detections`), a fixed point that two rounds reach to well under the
detector's noise (``docs/detection.md``); with a camera given, :func:`correct_centres` does the same with each view's
pose from its own centres.
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.camera import Camera, transform_points_rt

__all__ = ["RIM_POINTS", "centre_bias", "correct_centres"]

#: points on each dot's rim (the polygon's centroid is within 1e-4 of the curve's for the tilts of a calibration)
RIM_POINTS = 64


def _polygon_centroid(pts: torch.Tensor) -> torch.Tensor:
    """Centroid :math:`(*, 2)` of closed polygons :math:`(*, M, 2)`."""
    x, y = pts[..., 0], pts[..., 1]
    xn, yn = x.roll(-1, -1), y.roll(-1, -1)
    cross = x * yn - xn * y
    area = cross.sum(-1) / 2
    cx = ((x + xn) * cross).sum(-1) / (6 * area)
    cy = ((y + yn) * cross).sum(-1) / (6 * area)
    return torch.stack([cx, cy], -1)


def centre_bias(camera: Camera, rvec: torch.Tensor, tvec: torch.Tensor, object_points: torch.Tensor,
                radii: torch.Tensor) -> torch.Tensor:
    r"""The offset :math:`(V, N, 2)` px of each dot's image's centre from the image of its centre.

    Args:
        camera: one camera.
        rvec, tvec: :math:`(V, 3)` the board's poses (world to camera, OpenCV's).
        object_points: :math:`(N, 3)` the dots' centres on the board (``z = 0``).
        radii: :math:`(N,)` the dots' radii (world units).

    Returns:
        :math:`(V, N, 2)` float64: centroid of the dot's imaged rim minus the projected centre.

    Example:
        >>> from ccs_kornia.geometry.models.factory import PINHOLE
        >>> cam = Camera.from_opencv(PINHOLE, torch.tensor([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]))
        >>> obj = torch.tensor([[0.0, 0.0, 0.0]])
        >>> flat = centre_bias(cam, torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 0.5]]), obj, torch.tensor([0.01]))
        >>> tilted = centre_bias(cam, torch.tensor([[0.0, 0.8, 0.0]]), torch.tensor([[0.1, 0.0, 0.5]]), obj,
        ...                      torch.tensor([0.01]))
        >>> float(flat.abs().max()) < 1e-9, float(tilted.abs().max()) > 0.01
        (True, True)
    """
    dtype = torch.float64
    rvec, tvec = rvec.to(dtype), tvec.to(dtype)
    obj, radii = object_points.to(dtype).to(rvec.device), radii.to(dtype).to(rvec.device)
    v, n = rvec.shape[0], obj.shape[0]
    theta = torch.arange(RIM_POINTS, dtype=dtype, device=rvec.device) * (2 * math.pi / RIM_POINTS)
    ring = torch.stack([theta.cos(), theta.sin(), torch.zeros_like(theta)], -1)  # (M, 3)
    rim = obj[:, None] + radii[:, None, None] * ring  # (N, M, 3)
    pts = torch.cat([obj[:, None], rim], 1).reshape(1, -1, 3).expand(v, -1, -1)  # (V, N * (M + 1), 3)
    cam = transform_points_rt(pts, rvec, tvec)
    uv = camera.to(dtype=dtype).project(cam.reshape(1, -1, 3)).reshape(v, n, RIM_POINTS + 1, 2)
    return _polygon_centroid(uv[:, :, 1:]) - uv[:, :, 0]


def correct_centres(corners: torch.Tensor, valid: torch.Tensor, camera: Camera, object_points: torch.Tensor,
                    radii: torch.Tensor, rounds: int = 2) -> torch.Tensor:
    r"""Measured dot centres :math:`(V, N, 2)` corrected for a given camera: each view's pose from its centres
    (``cv2.solvePnP`` on the undistorted centres), the offset of :func:`centre_bias` under it subtracted, ``rounds``
    times (views with fewer than 4 valid dots are left as they are).

    Args:
        corners: :math:`(V, N, 2)` measured centres (px); valid: :math:`(V, N)` bool.
        camera: one camera; object_points: :math:`(N, 3)`; radii: :math:`(N,)` world units.

    Returns:
        :math:`(V, N, 2)` float64, the corrected centres (unchanged where not valid).

    Example:
        >>> from ccs_kornia.geometry.models.factory import PINHOLE
        >>> cam = Camera.from_opencv(PINHOLE, torch.tensor([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]))
        >>> obj = torch.tensor([[x * 0.02, y * 0.02, 0.0] for y in range(3) for x in range(4)])
        >>> rv, tv = torch.tensor([[0.0, 0.7, 0.0]]), torch.tensor([[-0.03, -0.02, 0.3]])
        >>> true = cam.project(transform_points_rt(obj[None], rv, tv).reshape(1, -1, 3)).reshape(1, 12, 2)
        >>> radii = torch.full((12,), 0.005)
        >>> seen = true + centre_bias(cam, rv, tv, obj, radii)
        >>> fixed = correct_centres(seen, torch.ones(1, 12, dtype=torch.bool), cam, obj, radii)
        >>> float((seen - true).norm(dim=-1).max()) > 0.05, float((fixed - true).norm(dim=-1).max()) < 1e-3
        (True, True)
    """
    import cv2
    import numpy as np

    corners = corners.to(torch.float64).cpu()
    valid = valid.bool().cpu() & corners.isfinite().all(-1)
    camera = camera.to("cpu", torch.float64)
    obj = object_points.to(torch.float64).cpu()
    out = corners.clone()
    views = [v for v in range(corners.shape[0]) if int(valid[v].sum()) >= 4]
    if not views:
        return out
    for _ in range(int(rounds)):
        rvecs, tvecs = [], []
        for v in views:
            m = valid[v]
            normal = camera.undistort(out[v][m][None])[0].numpy()
            _, rv, tv = cv2.solvePnP(obj[m].numpy(), normal, np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
            rvecs.append(rv.ravel())
            tvecs.append(tv.ravel())
        bias = centre_bias(camera, torch.tensor(np.array(rvecs)), torch.tensor(np.array(tvecs)), obj, radii)
        for k, v in enumerate(views):
            m = valid[v]
            out[v][m] = corners[v][m] - bias[k][m]
    return out
