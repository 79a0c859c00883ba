"""Rendered hand-eye image sets for the command-line tests: a Panda arm's poses (known X), a single AprilTag or a
chessboard seen in every image, and the pose file written in any form."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import torch

from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.data.scenes.marker_views import render_marker_view
from ccs_kornia.data.scenes.robots import render_hand_eye
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.io.images import write_image
from ccs_kornia.modules.detection.markers.apriltag import AprilTagTarget

TAG = AprilTagTarget("36h11", 0.1, tag_id=3)


def tag_scene(setup: str, views: int, seed: int, folder: str) -> dict:
    """Tag images of a rendered robot (the tag centred where the scene's board is) and a calibrate JSON of the camera:
    ``{"scene", "X", "files", "calibration"}``."""
    s = render_hand_eye(setup, views=views, seed=seed, noise_px=0.0, joint_noise_deg=0.005)
    centre = torch.eye(4, dtype=torch.float64)
    centre[:3, 3] = s.object_points.mean(0)
    Z = s.Z @ centre
    K, dist = s.K.numpy(), np.r_[s.dist.numpy(), 0.0, 0.0, 0.0]
    os.makedirs(folder, exist_ok=True)
    files = []
    for v in range(views):
        T = s.true_poses[v]
        M = (torch.linalg.inv(T @ s.X) @ Z) if setup == "eye_in_hand" else (torch.linalg.inv(s.X) @ T @ Z)
        img, _ = render_marker_view(TAG, log_so3(M[:3, :3]).numpy(), M[:3, 3].numpy(), K, dist, (640, 480),
                                    supersample=2)
        path = os.path.join(folder, f"view_{v:02d}.png")
        cv2.imwrite(path, img)
        files.append(path)
    calib = os.path.join(folder, "..", f"camera_{seed}.json")
    with open(calib, "w", encoding="utf-8") as handle:
        json.dump({"image_size": [640, 480], "K": s.K.tolist(), "distortion": {"model": "k1k2",
                   "coeffs": [*s.dist.tolist(), 0.0, 0.0, 0.0]}}, handle)
    return {"scene": s, "X": s.X, "files": files, "calibration": os.path.abspath(calib)}


def board_scene(setup: str, views: int, seed: int, folder: str) -> dict:
    """Chessboard (9x6, 25 mm) images of a rendered robot: ``{"scene", "X", "files"}``."""
    s = render_hand_eye(setup, views=views, seed=seed, noise_px=0.0, joint_noise_deg=0.005)
    os.makedirs(folder, exist_ok=True)
    cam = torch.linalg.inv(s.true_poses @ s.X) @ s.Z if setup == "eye_in_hand" else \
        torch.linalg.inv(s.X) @ s.true_poses @ s.Z
    images, _ = render_chessboard(s.K, log_so3(cam[:, :3, :3]), cam[:, :3, 3], (9, 6), 0.025, (640, 480),
                                  dist=torch.cat([s.dist, torch.zeros(3, dtype=torch.float64)]), supersample=2)
    files = []
    for v in range(views):
        path = os.path.join(folder, f"view_{v:02d}.png")
        write_image(path, images[v, 0])
        files.append(path)
    return {"scene": s, "X": s.X, "files": files}


def write_poses(path: str, files: list[str], T: torch.Tensor, form: str = "rotvec", scale: float = 1.0,
                header: bool = True) -> str:
    """The pose file of ``files`` (their names, in the given order) with the flange poses ``T`` (metres)."""
    from scipy.spatial.transform import Rotation

    rows = ["image,pose"] if header else []
    for f, M in zip(files, T.numpy()):
        t = M[:3, 3] * scale
        r = Rotation.from_matrix(M[:3, :3])
        if form == "quat":
            values = [*t, *r.as_quat()]
        elif form == "quat-wxyz":
            values = [*t, *np.roll(r.as_quat(), 1)]
        elif form == "rotvec":
            values = [*t, *r.as_rotvec()]
        else:
            N = M.copy()
            N[:3, 3] = t
            values = list(N.ravel())
        rows.append(",".join([os.path.basename(f)] + [f"{v:.12g}" for v in values]))
    with open(path, "w", encoding="utf-8") as handle:
        handle.write("\n".join(rows) + "\n")
    return path
