"""Rendered ChArUco views with exact corners: OpenCV's board image seen by a camera with lens distortion.

Every output pixel is traced back through the lens (``cv2.undistortPoints``) to the board plane and sampled there,
on a supersampled grid then area-averaged, so the corners' true positions are ``cv2.projectPoints`` of the board's
object points.
"""

from __future__ import annotations

import cv2
import numpy as np

from ccs_kornia.modules.detection.boards import CharucoBoard

__all__ = ["K", "DIST", "POSES", "render_view"]

K = np.array([[520.0, 0.0, 318.0], [0.0, 520.0, 242.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28, 0.09, 0.0, 0.0, 0.0])
#: (rvec, tvec) in metres for a 5x7 board of 40 mm squares (0.2 x 0.28 m): whole, tilted, and cut by the frame
POSES = {
    "whole": (np.array([0.15, -0.2, 0.05]), np.array([-0.1, -0.14, 0.4])),
    "tilted": (np.array([0.6, 0.3, -0.2]), np.array([-0.1, -0.13, 0.42])),
    "left edge": (np.array([0.1, 0.35, 0.1]), np.array([-0.29, -0.14, 0.34])),
    "bottom right": (np.array([-0.3, 0.2, 0.3]), np.array([0.02, 0.0, 0.33])),
}


def render_view(board: CharucoBoard, pose: str, size: tuple[int, int] = (640, 480), supersample: int = 3,
                pixels_per_square: int = 120, inverted: bool = False, mirrored: bool = False,
                legacy: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A ``uint8`` view of ``board`` from :data:`POSES` and the true corners ``(N, 2)`` px (NaN outside the image).

    ``inverted``: a white-on-black print; ``mirrored``: the image flipped left-right (a board seen from its back).
    """
    rvec, tvec = POSES[pose]
    w, h = size
    margin = pixels_per_square
    art = board.render(pixels_per_square, margin=margin, legacy=legacy)
    f = supersample
    ys, xs = np.mgrid[0:h * f, 0:w * f].astype(np.float64)
    pix = np.stack([(xs + 0.5) / f - 0.5, (ys + 0.5) / f - 0.5], -1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pix, K, DIST, criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10))
    rays = np.concatenate([rays.reshape(-1, 2), np.ones((rays.shape[0], 1))], -1)
    rot, _ = cv2.Rodrigues(rvec)
    origin = -rot.T @ tvec
    dirs = rays @ rot  # R^T d for each ray
    s = -origin[2] / dirs[:, 2]
    plane = origin[None, :2] + s[:, None] * dirs[:, :2]
    scale = pixels_per_square / float(board.square)
    map_xy = (plane * scale + margin - 0.5).astype(np.float32).reshape(h * f, w * f, 2)
    big = cv2.remap(art, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=160)
    image = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    truth, _ = cv2.projectPoints(board.object_points().numpy(), rvec, tvec, K, DIST)
    truth = truth.reshape(-1, 2)
    outside = (truth[:, 0] < 0) | (truth[:, 0] > w - 1) | (truth[:, 1] < 0) | (truth[:, 1] > h - 1)
    truth[outside] = np.nan
    if inverted:
        image = 255 - image
    if mirrored:
        image = np.ascontiguousarray(image[:, ::-1])
        truth[:, 0] = w - 1 - truth[:, 0]
    return image, truth
