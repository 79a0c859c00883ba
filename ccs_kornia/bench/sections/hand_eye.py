r"""Hand-eye benchmark: our joint fit against OpenCV's hand-eye methods on the same corners and the same camera.

**Rendered robots** (:func:`~ccs_kornia.data.scenes.robots.render_hand_eye`): a Panda arm, eye-in-hand and eye-to-hand,
a 9x6 board, a known ``X``; 8-30 poses reached by inverse kinematics; Gaussian corner noise of 0.1-0.3 px; the
reported robot poses carry Gaussian joint-angle noise of 0-0.02 degrees (encoder error, in joint space); a third of
the trials keep the views within :data:`SMALL_TILT_DEG` degrees of the nominal one (the small rotations that break
the closed forms). Seeds start at :data:`SEED`.

* ours: :func:`~ccs_kornia.modules.hand_eye.solver.calibrate_hand_eye` (defaults: robot-pose noise estimated,
  leave-one-pose-out figures and 1-sigma);
* OpenCV, as its users run it: the board's pose per view by ``cv2.solvePnP`` with the true camera, then
  ``cv2.calibrateHandEye`` (Tsai, Park, Horaud, Andreff, Daniilidis; the board's pose in the robot as the chordal
  mean of the views') and ``cv2.calibrateRobotWorldHandEye`` (Shah, Li; its own board pose).

Per trial and method: ``X``'s error (translation mm, rotation degrees); the held-out prediction error (each pose's
corners predicted from its robot pose by the method run on the other poses, RMS px over all poses); a failure where
the method raises, returns a non-finite result, refuses, or errs by more than :data:`FAIL_MM` mm or :data:`FAIL_DEG`
degrees. For ours, the honesty of the stated 1-sigma: the fraction of the error's components (3 of rotation, 3 of
translation per trial) within their 1-sigma (about 68 % for an honest Gaussian sigma), and of the error's norms within
the sigma's norm (about 61 % in 3-D).

**Rendered arms with kinematic errors** (:data:`KINEMATIC_RANGES`): the same scenes with the true arm's joint offsets
and link lengths off the kinematics it reports with, and the reported pose lagging the image while the arm moves on;
judged as the rendered robots are.

**Real robots** (where they are in the real-data folder): the eight poses of ViSP's Franka data
(``visp_franka_eye_to_hand``), our AprilTag corners, ViSP's camera; ``X`` against ViSP's published result, the
held-out prediction error of every method on the same corners, and ours with the whole procedure held out (its choice
of the robot's error model made without the pose it predicts). ROS-Industrial's eye-in-hand circle grid
(``ric_circlegrid_eye_in_hand``, :func:`ric_circle_grid`) and eye-to-hand ChArUco board (``ric_charuco_eye_to_hand``,
:func:`ric_charuco`): the camera calibrated from their images, the held-out prediction error of every method on the
same corners.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.data.scenes.robots import render_hand_eye
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import OPENCV5, PINHOLE
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.hand_eye.closed_forms import board_in_robot
from ccs_kornia.modules.hand_eye.solver import calibrate_hand_eye

__all__ = ["FAIL_DEG", "FAIL_MM", "KINEMATIC_MOVE_S", "KINEMATIC_RANGES", "KINEMATIC_SEED", "KINEMATIC_VIEWS",
           "MIN_SEEN", "OPENCV_METHODS", "RIC_CHARUCO", "RIC_CIRCLES", "SEED", "SMALL_TILT_DEG",
           "hand_eye_md", "opencv_hand_eye", "ric_charuco", "ric_circle_grid", "run_hand_eye", "visp_franka"]

#: first seed of the trials (the tests use seeds below 1000)
SEED = 600_000
#: an X further than this from the truth (mm, degrees) counts as a failure
FAIL_MM = 5.0
FAIL_DEG = 0.5
#: the views' tilt in the small-rotation trials (degrees)
SMALL_TILT_DEG = 5.0
#: the rendered arms with kinematic errors: each drawn uniformly in its range per trial: the true arm's joint offsets
#: (sigma, degrees) and link-length errors (sigma of each DH a and d, millimetres) against the kinematics it reports
#: with, and the reported pose's lag behind the image (s) while the arm moves on
KINEMATIC_RANGES = {"joint_offset_deg": (0.02, 0.1), "link_error_mm": (0.1, 0.5), "time_offset_s": (0.0, 0.01)}
#: their arm's time from one view to the next (s), and their poses per scene (fewer: each is fitted many times)
KINEMATIC_MOVE_S = 3.0
KINEMATIC_VIEWS = (8, 16)
#: their first seed
KINEMATIC_SEED = 700_000
#: OpenCV's methods: name -> (function, flag)
OPENCV_METHODS = {
    "tsai": ("hand_eye", cv2.CALIB_HAND_EYE_TSAI), "park": ("hand_eye", cv2.CALIB_HAND_EYE_PARK),
    "horaud": ("hand_eye", cv2.CALIB_HAND_EYE_HORAUD), "andreff": ("hand_eye", cv2.CALIB_HAND_EYE_ANDREFF),
    "daniilidis": ("hand_eye", cv2.CALIB_HAND_EYE_DANIILIDIS),
    "rw_shah": ("robot_world", cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH),
    "rw_li": ("robot_world", cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI),
}
LABELS = {"ours": "ccs_kornia joint fit", "tsai": "OpenCV Tsai", "park": "OpenCV Park", "horaud": "OpenCV Horaud",
          "andreff": "OpenCV Andreff", "daniilidis": "OpenCV Daniilidis",
          "rw_shah": "OpenCV robot-world Shah", "rw_li": "OpenCV robot-world Li"}


def _pnp(obj: np.ndarray, corners: np.ndarray, K: np.ndarray, dist: np.ndarray, square_tag: bool = False) -> np.ndarray:
    """The board's pose in the camera (4x4) from one view's corners, OpenCV's way."""
    flags = cv2.SOLVEPNP_IPPE if square_tag else cv2.SOLVEPNP_ITERATIVE
    _, rv, tv = cv2.solvePnP(obj, corners, K, dist, flags=flags)
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = cv2.Rodrigues(rv)[0], tv.ravel()
    return M


def opencv_hand_eye(setup: str, T: np.ndarray, M: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(X, Z)`` of one OpenCV method from the flange poses ``T`` (V, 4, 4) and the board's poses in the camera
    ``M`` (V, 4, 4), in the package's conventions (:mod:`~ccs_kornia.modules.hand_eye.setup`). Raises ``cv2.error``
    or ``ValueError`` (non-finite result) on a failure."""
    kind, flag = OPENCV_METHODS[name]
    eye_in_hand = setup == "eye_in_hand"
    if kind == "hand_eye":
        # eye-in-hand: gripper -> base is T; eye-to-hand: its inverse (OpenCV's documented recipe)
        G = T if eye_in_hand else np.linalg.inv(T)
        R, t = cv2.calibrateHandEye(list(G[:, :3, :3]), [g.reshape(3, 1) for g in G[:, :3, 3]], list(M[:, :3, :3]),
                                    [m.reshape(3, 1) for m in M[:, :3, 3]], method=flag)
        X = np.eye(4)
        X[:3, :3], X[:3, 3] = R, t.ravel()
        A = np.linalg.inv(T) if eye_in_hand else T
        Z = board_in_robot(torch.from_numpy(A)[None], torch.from_numpy(M)[None], torch.ones(1, len(T), dtype=torch.bool),
                           torch.from_numpy(X)[None])[0].numpy()
    else:
        Bg = np.linalg.inv(T) if eye_in_hand else T  # base -> gripper (eye-to-hand: gripper -> base)
        Rw, tw, Rg, tg = cv2.calibrateRobotWorldHandEye(
            list(M[:, :3, :3]), [m.reshape(3, 1) for m in M[:, :3, 3]], list(Bg[:, :3, :3]),
            [b.reshape(3, 1) for b in Bg[:, :3, 3]], method=flag)
        Gc, W = np.eye(4), np.eye(4)
        Gc[:3, :3], Gc[:3, 3] = Rg, tg.ravel()
        W[:3, :3], W[:3, 3] = Rw, tw.ravel()
        X, Z = np.linalg.inv(Gc), np.linalg.inv(W)
    if not (np.isfinite(X).all() and np.isfinite(Z).all()):
        raise ValueError("non-finite result")
    return X, Z


def _predict_px(setup: str, X, Z, T, obj, corners, K, dist, seen=None) -> float:
    """RMS px of a view's corners (those ``seen``, default all) predicted from its flange pose ``T``."""
    if seen is not None:
        obj, corners = obj[seen], corners[seen]
    A = np.linalg.inv(T) if setup == "eye_in_hand" else T
    C = np.linalg.inv(X) @ A @ Z
    uv = cv2.projectPoints(obj, cv2.Rodrigues(C[:3, :3])[0], C[:3, 3], K, dist)[0].reshape(-1, 2)
    return float(np.sqrt(((uv - corners) ** 2).sum(-1).mean()))


def _errors(X: np.ndarray, X_true: np.ndarray) -> tuple[float, float]:
    t = 1000 * float(np.linalg.norm(X[:3, 3] - X_true[:3, 3]))
    r = float(np.degrees(np.linalg.norm(cv2.Rodrigues(X[:3, :3] @ X_true[:3, :3].T)[0])))
    return t, r


def _opencv_rows(setup, T, M, obj, corners, K, dist, X_true=None, seen=None) -> dict:
    out = {}
    V = len(T)
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # its failures are counted, not printed
    try:
        for name in OPENCV_METHODS:
            out[name] = _opencv_row(setup, T, M, obj, corners, K, dist, X_true, name, V, seen)
    finally:
        cv2.utils.logging.setLogLevel(level)
    return out


def _opencv_row(setup, T, M, obj, corners, K, dist, X_true, name, V, seen=None) -> dict:
    """One OpenCV method on a data set: its X (error against the truth where given) and its held-out figure."""
    try:
        X, _ = opencv_hand_eye(setup, T, M, name)
        held = []
        for v in range(V):
            keep = [k for k in range(V) if k != v]
            Xv, Zv = opencv_hand_eye(setup, T[keep], M[keep], name)
            held.append(_predict_px(setup, Xv, Zv, T[v], obj, corners[v], K, dist, None if seen is None else seen[v]))
    except (cv2.error, ValueError, np.linalg.LinAlgError) as err:
        return {"failed": True, "error": str(err).strip().splitlines()[-1][:200]}
    row = {"heldout_px": float(np.sqrt(np.mean(np.square(held)))), "heldout_per_pose": held}
    if X_true is not None:
        t, r = _errors(X, X_true)
        row.update(t_mm=t, r_deg=r, failed=not (t <= FAIL_MM and r <= FAIL_DEG))
    else:
        row["X"] = X.tolist()
    return row


def _trial(seed: int, setup: str, views_range: tuple[int, int] = (8, 30), kinematic: bool = False) -> dict:
    g = np.random.default_rng(seed)
    views = int(g.integers(views_range[0], views_range[1] + 1))
    small = g.random() < 1 / 3
    noise_px, joint_deg = float(g.uniform(0.1, 0.3)), float(g.uniform(0.0, 0.02))
    errors = {k: float(g.uniform(*r)) for k, r in KINEMATIC_RANGES.items()} if kinematic else {}
    scene = render_hand_eye(setup, views=views, seed=seed, noise_px=noise_px, joint_noise_deg=joint_deg,
                            max_tilt_deg=SMALL_TILT_DEG if small else 30.0,
                            **({**errors, "move_s": KINEMATIC_MOVE_S} if kinematic else {}))
    camera = scene.camera
    K, dist = camera.K[0].numpy(), camera.dist[0].numpy()
    obj = scene.object_points.numpy()
    corners = scene.corners.numpy()
    T = scene.robot_poses.numpy()
    X_true = scene.X.numpy()
    row = {"setup": setup, "views": views, "small_rotations": bool(small), "noise_px": noise_px,
           "joint_noise_deg": joint_deg, **errors}
    res = calibrate_hand_eye(scene.corners[None], scene.valid[None], scene.object_points, scene.robot_poses[None],
                             camera, setup, image_size=scene.image_size)
    if not bool(res.success[0]):
        row["ours"] = {"failed": True, "error": res.reasons[0]}
    else:
        X = res.X[0].numpy()
        t, r = _errors(X, X_true)
        e_t = (X[:3, 3] - X_true[:3, 3]) * 1000
        e_r = np.degrees(log_so3(torch.from_numpy(X[:3, :3] @ X_true[:3, :3].T)).numpy())
        s_t = res.x_translation_std[0].numpy() * 1000
        s_r = res.x_rotation_std_deg[0].numpy()
        row["ours"] = {"t_mm": t, "r_deg": r, "failed": not (t <= FAIL_MM and r <= FAIL_DEG),
                       "heldout_px": float(res.heldout_rms[0]), "sigma_t_mm": float(np.linalg.norm(s_t)),
                       "sigma_r_deg": float(np.linalg.norm(s_r)),
                       "covered_axes": int((np.abs(e_t) <= s_t).sum() + (np.abs(e_r) <= s_r).sum()),
                       "covered_t": bool(t <= np.linalg.norm(s_t)), "covered_r": bool(r <= np.linalg.norm(s_r)),
                       "start": res.start[0], "verdict": res.verdict[0], "noise_choice": res.noise_choice[0]}
    M = np.stack([_pnp(obj, corners[v], K, dist) for v in range(views)])
    row.update(_opencv_rows(setup, T, M, obj, corners, K, dist, X_true))
    return row


def _summary(rows: list[dict]) -> dict:
    out = {}
    for name in ("ours", *OPENCV_METHODS):
        ok = [r[name] for r in rows if not r[name].get("failed") and "t_mm" in r[name]]
        fails = sum(1 for r in rows if r[name].get("failed"))
        held = [r[name]["heldout_px"] for r in rows if "heldout_px" in r[name]]

        def stat(key, fn, ok=ok):
            vals = [o[key] for o in ok]
            return float(fn(vals)) if vals else float("nan")

        out[name] = {"trials": len(rows), "failures": fails,
                     "t_mm_mean": stat("t_mm", np.mean), "t_mm_max": stat("t_mm", np.max),
                     "r_deg_mean": stat("r_deg", np.mean), "r_deg_max": stat("r_deg", np.max),
                     "heldout_px_mean": float(np.mean(held)) if held else float("nan")}
        # the worst case over every trial, failures included (a failure's error where it returned one)
        every = [r[name] for r in rows if "t_mm" in r[name]]
        out[name]["t_mm_max_all"] = max((o["t_mm"] for o in every), default=float("nan"))
        out[name]["r_deg_max_all"] = max((o["r_deg"] for o in every), default=float("nan"))
    ours = [r["ours"] for r in rows if "covered_axes" in r["ours"]]
    if ours:
        out["ours"]["coverage_axes"] = sum(o["covered_axes"] for o in ours) / (6 * len(ours))
        out["ours"]["coverage_t"] = float(np.mean([o["covered_t"] for o in ours]))
        out["ours"]["coverage_r"] = float(np.mean([o["covered_r"] for o in ours]))
    return out


def _visp_yaml(path: Path) -> np.ndarray:
    values = [float(x) for x in path.read_text().split("data:")[1].replace("- [", " ").replace("]", " ").split()]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(np.array(values[3:]))[0], values[:3]
    return T


#: ViSP's published base -> camera of its Franka eye-to-hand data (SOURCE.md): translation (m), theta-u (rad)
VISP_RESULT = ((0.954036, -0.051236, 0.476220), (-1.104108, -1.112746, 1.289541))


def visp_franka(folder: Path) -> dict:
    """Ours and OpenCV's methods on ViSP's Franka eye-to-hand data (module doc)."""
    import re

    from ccs_kornia.io.images import load_image_gray
    from ccs_kornia.modules.detection.markers.apriltag import (
        AprilTagTarget,
        detect_apriltag,
    )

    text = (folder / "franka_camera.xml").read_text()
    px, py, u0, v0 = (float(re.search(f"<{k}>([^<]+)</{k}>", text).group(1)) for k in ("px", "py", "u0", "v0"))
    K = np.array([[px, 0, u0], [0, py, v0], [0, 0, 1.0]])
    n = len(list(folder.glob("franka_image-*.png")))
    images, T = [], []
    for i in range(1, n + 1):
        gray, _ = load_image_gray(folder / f"franka_image-{i}.png")
        images.append(torch.from_numpy(np.asarray(gray, dtype=np.float32))[None])
        T.append(_visp_yaml(folder / f"franka_pose_rPe_{i}.yaml"))
    T = np.stack(T)
    target = AprilTagTarget("36h11", 0.048)
    det = detect_apriltag(torch.stack(images), target)
    if not bool(det.found.all()):
        raise RuntimeError(f"the tag was not found in every image: {det.reasons}")
    obj = target.object_points()
    camera = Camera.from_opencv(PINHOLE, torch.from_numpy(K), None, (640, 480))
    res = calibrate_hand_eye(det.corners[None], torch.ones(1, n, 4, dtype=torch.bool), obj, torch.from_numpy(T)[None],
                             camera, "eye_to_hand", image_size=(640, 480))
    ref = np.eye(4)
    ref[:3, :3], ref[:3, 3] = cv2.Rodrigues(np.array(VISP_RESULT[1]))[0], VISP_RESULT[0]
    X = res.X[0].numpy()
    t, r = _errors(X, ref)
    corners = det.corners.numpy()
    M = np.stack([_pnp(obj.numpy(), corners[v], K, np.zeros(5), square_tag=True) for v in range(n)])
    # the whole procedure held out too: each pose predicted by the calibration of the others, its own choice of the
    # robot's error model (made on their held-out poses) included
    whole = []
    for v in range(n):
        keep = [k for k in range(n) if k != v]
        out = calibrate_hand_eye(det.corners[None][:, keep], torch.ones(1, n - 1, 4, dtype=torch.bool), obj,
                                 torch.from_numpy(T[keep])[None], camera, "eye_to_hand", image_size=(640, 480))
        whole.append(_predict_px("eye_to_hand", out.X[0].numpy(), out.Z[0].numpy(), T[v], obj.numpy(),
                                 det.corners[v].numpy(), K, np.zeros(5)))
    rows = {"ours": {"X": X.tolist(), "vs_visp_mm": t, "vs_visp_deg": r, "heldout_px": float(res.heldout_rms[0]),
                     "heldout_mm": 1000 * float(res.heldout_distance[0]),
                     "heldout_per_pose": res.heldout_rms_px[0].tolist(), "rms_px": float(res.rms[0]),
                     "sigma_t_mm": 1000 * float(res.X_translation_std[0]),
                     "sigma_r_deg": float(res.X_rotation_std_deg[0]), "verdict": res.verdict[0],
                     "noise_choice": res.noise_choice[0], "whole_heldout_px": float(np.sqrt(np.mean(np.square(whole)))),
                     "whole_heldout_per_pose": whole}}
    for name, row in _opencv_rows("eye_to_hand", T, M, obj.numpy(), corners, K, np.zeros(5)).items():
        if "X" in row:
            row["vs_visp_mm"], row["vs_visp_deg"] = _errors(np.array(row["X"]), ref)
        rows[name] = row
    return {"poses": n, "methods": rows}


def _csv_poses(path: Path) -> dict[str, np.ndarray]:
    """A pose file (``image,x,y,z,qx,qy,qz,qw``, metres) as flange -> base 4x4 by image name."""
    from ccs_kornia.io.robot_poses import read_robot_poses

    poses = read_robot_poses(str(path))
    return dict(zip(poses.names, poses.poses))


#: a view of a partly seen board is used where at least this many of its corners are seen
MIN_SEEN = 8
#: ROS-Industrial's eye-in-hand set: its modified circle grid as its cal_data.yaml gives it (10 x 10 dots, 25.4 mm)
RIC_CIRCLES = (10, 10, 0.0254)


def ric_circle_grid(folder: Path) -> dict:
    """Ours and OpenCV's methods on ROS-Industrial's eye-in-hand circle-grid set: the camera calibrated by this
    package from the same images (OPENCV5), its corrected centres for every method (OpenCV's board poses by
    ``solvePnP`` on them), the views with every dot seen; the dots' spacing the robot's translations tell (this
    package refuses the source's 25.4 mm and says the spacing it sees; every method is then run with that one); the
    held-out prediction of each pose's centres from its robot pose."""
    from ccs_kornia.io.images import load_image_gray
    from ccs_kornia.modules.detection.boards import CircleGrid
    from ccs_kornia.modules.detection.circles.circle_grid import CircleGridDetector
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    cols, rows, given = RIC_CIRCLES
    grid = CircleGrid(cols, rows, given, marked_origin=True)
    poses = _csv_poses(folder / "poses.csv")
    names = sorted(poses, key=lambda n: int(n.split(".")[0]))
    images = [torch.from_numpy(np.asarray(load_image_gray(folder / "images" / n)[0], dtype=np.float32))[None]
              for n in names]
    pipe = CalibrationPipeline(CircleGridDetector(grid), model=OPENCV5, distortion_correction=False,
                               diagnostics=False)
    with torch.inference_mode():
        res = pipe(torch.stack(images), grid.board_size, grid.spacing)
    found = res.detections.found & res.detections.valid.all(-1)
    idx = found.nonzero().flatten()
    corners = res.detections.corners[idx].double()
    T = np.stack([poses[names[i]] for i in idx.tolist()])
    camera = res.camera
    K, dist = camera.K[0].numpy(), camera.dist[0].numpy()
    every = torch.ones(1, *corners.shape[:2], dtype=torch.bool)

    def ours(spacing: float):
        return calibrate_hand_eye(corners[None], every, grid.object_points() * (spacing / given),
                                  torch.from_numpy(T)[None], camera, "eye_in_hand", image_size=(640, 480))

    first = ours(given)
    told = next((i["scale"] for i in first.issues[0] if i["check"] == "board_scale"), 1.0)
    spacing = given * told
    he = ours(spacing) if told != 1.0 else first
    obj = grid.object_points() * (spacing / given)
    n = len(idx)
    M = np.stack([_pnp(obj.numpy(), corners[v].numpy(), K, dist) for v in range(n)])
    rows = {"ours": {"X": he.X[0].numpy().tolist(), "heldout_px": float(he.heldout_rms[0]),
                     "heldout_mm": 1000 * float(he.heldout_distance[0]),
                     "heldout_per_pose": he.heldout_rms_px[0].tolist(), "rms_px": float(he.rms[0]),
                     "verdict": he.verdict[0]}}
    rows.update(_opencv_rows("eye_in_hand", T, M, obj.numpy(), corners.numpy(), K, dist))
    return {"poses": n, "camera_rms_px": float(res.rms), "given_spacing": given, "spacing": spacing,
            "refused_at_given": first.reasons[0], "methods": rows}


#: ROS-Industrial's eye-to-hand ChArUco set's board: 5 x 7 squares of 36.195 mm, markers 18.256 mm, DICT_6X6_250
RIC_CHARUCO = (5, 7, 0.036195, 0.018256, "DICT_6X6_250")


def ric_charuco(folder: Path) -> dict:
    """Ours and OpenCV's methods on ROS-Industrial's eye-to-hand ChArUco set: the camera calibrated by this package
    from the same images (OPENCV5; the set's own intrinsics have no distortion, which its lens has), our corners for
    every method (OpenCV's board poses by ``solvePnP`` on each view's corners seen), the views with at least
    :data:`MIN_SEEN` corners; the held-out prediction of each pose's corners from its robot pose."""
    from ccs_kornia.io.images import load_image_gray
    from ccs_kornia.modules.detection.boards import CharucoBoard
    from ccs_kornia.modules.detection.markers.charuco import CharucoDetector
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    board = CharucoBoard(*RIC_CHARUCO)
    poses = _csv_poses(folder / "poses.csv")
    names = sorted(poses, key=lambda n: int(n.split(".")[0]))
    images = [torch.from_numpy(np.asarray(load_image_gray(folder / "images" / n)[0], dtype=np.float32))[None]
              for n in names]
    size = (images[0].shape[-1], images[0].shape[-2])
    pipe = CalibrationPipeline(CharucoDetector(board), model=OPENCV5, distortion_correction=False, diagnostics=False)
    with torch.inference_mode():
        res = pipe(torch.stack(images), board.board_size, board.square)
    det = res.detections
    seen_all = det.valid & det.corners.isfinite().all(-1)
    idx = (det.found & (seen_all.sum(-1) >= MIN_SEEN)).nonzero().flatten()
    corners, seen = det.corners[idx].double(), seen_all[idx]
    T = np.stack([poses[names[i]] for i in idx.tolist()])
    camera = res.camera
    K, dist = camera.K[0].numpy(), camera.dist[0].numpy()
    obj = board.object_points().double()
    he = calibrate_hand_eye(corners[None], seen[None], obj, torch.from_numpy(T)[None], camera, "eye_to_hand",
                            image_size=size)
    n = len(idx)
    c, m, o = corners.numpy(), seen.numpy(), obj.numpy()
    M = np.stack([_pnp(o[m[v]], c[v][m[v]], K, dist) for v in range(n)])
    rows = {"ours": {"X": he.X[0].numpy().tolist(), "heldout_px": float(he.heldout_rms[0]),
                     "heldout_mm": 1000 * float(he.heldout_distance[0]),
                     "heldout_per_pose": he.heldout_rms_px[0].tolist(), "rms_px": float(he.rms[0]),
                     "verdict": he.verdict[0]}}
    rows.update(_opencv_rows("eye_to_hand", T, M, o, c, K, dist, seen=m))
    return {"poses": n, "images": len(names), "camera_rms_px": float(res.rms), "methods": rows}


def run_hand_eye(cfg=None, trials: int | None = None, seed: int = SEED, log=print) -> dict:
    """Run the benchmark: ``trials`` rendered scenes per set-up (default ``cfg.hand_eye_trials``, else 20), and the
    real robot where its data is found. Returns a JSON-able dict."""
    trials = trials if trials is not None else int(getattr(cfg, "hand_eye_trials", 20))
    views = tuple(getattr(cfg, "hand_eye_views", (8, 30)))
    rows = []
    for k, setup in enumerate(("eye_in_hand", "eye_to_hand")):
        for t in range(trials):
            rows.append(_trial(seed + 1000 * k + t, setup, views))
            r = rows[-1]
            ours = r["ours"]
            log(f"[hand_eye] {setup} trial {t + 1}/{trials}: {r['views']} poses"
                f"{', small rotations' if r['small_rotations'] else ''}; ours "
                + (f"{ours['t_mm']:.2f} mm {ours['r_deg']:.3f} deg" if "t_mm" in ours else "failed"))
    out = {"trials_per_setup": trials, "seed": seed, "rows": rows, "summary": _summary(rows),
           "summary_small_rotations": _summary([r for r in rows if r["small_rotations"]])}
    kin_trials = int(getattr(cfg, "hand_eye_kinematic_trials", 6))
    if kin_trials:
        kin = []
        for k, setup in enumerate(("eye_in_hand", "eye_to_hand")):
            for t in range(kin_trials):
                kin.append(_trial(KINEMATIC_SEED + 1000 * k + t, setup, KINEMATIC_VIEWS, kinematic=True))
                ours = kin[-1]["ours"]
                log(f"[hand_eye] kinematic errors, {setup} trial {t + 1}/{kin_trials}: {kin[-1]['views']} poses; ours "
                    + (f"{ours['t_mm']:.2f} mm {ours['r_deg']:.3f} deg" if "t_mm" in ours else "failed"))
        out["kinematic"] = {"trials_per_setup": kin_trials, "seed": KINEMATIC_SEED, "rows": kin,
                            "summary": _summary(kin)}
    from ccs_kornia.bench.sections.real import default_real_dir

    root = Path(cfg.real_dir) if cfg is not None and getattr(cfg, "real_dir", None) else default_real_dir()
    folder = root / "visp_franka_eye_to_hand"
    if not getattr(cfg, "hand_eye_real", True):
        out["real_skipped"] = "not asked"
    elif not folder.is_dir():
        out["real_skipped"] = f"{folder} not found"
    else:
        out["real"] = {"visp_franka_eye_to_hand": visp_franka(folder)}
        log("[hand_eye] real robot: visp_franka_eye_to_hand done")
    circles = root / "ric_circlegrid_eye_in_hand"
    if getattr(cfg, "hand_eye_real", True) and circles.is_dir():
        out.setdefault("real", {})["ric_circlegrid_eye_in_hand"] = ric_circle_grid(circles)
        log("[hand_eye] real robot: ric_circlegrid_eye_in_hand done")
    charuco = root / "ric_charuco_eye_to_hand"
    if getattr(cfg, "hand_eye_real", True) and charuco.is_dir():
        out.setdefault("real", {})["ric_charuco_eye_to_hand"] = ric_charuco(charuco)
        log("[hand_eye] real robot: ric_charuco_eye_to_hand done")
    return out


def _fmt(x: float, digits: int = 2) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def hand_eye_md(sec: dict) -> list[str]:
    """Markdown of :func:`run_hand_eye`'s result."""
    if "summary" not in sec:
        return [f"Not run: {sec.get('error') or sec.get('skipped', '')}"]
    n = sec["trials_per_setup"]
    lines = [f"{n} rendered scenes per set-up (eye-in-hand, eye-to-hand; Panda arm, 8-30 poses, 0.1-0.3 px corner "
             f"noise, 0-0.02 deg joint noise, a third with views within {SMALL_TILT_DEG:g} deg). X error over the "
             f"trials a method did not fail (failure: an exception, a refusal, or more than {FAIL_MM:g} mm / "
             f"{FAIL_DEG:g} deg off); the worst case over every trial where a method returned an answer; held-out: "
             "each pose predicted from its robot pose by the method run on the others (mean over trials of the "
             "RMS px).", ""]
    for title, key in (("All trials", "summary"), ("Small-rotation trials", "summary_small_rotations")):
        lines += [f"{title}:", "", "| method | failures | X mm mean / max | X deg mean / max | worst mm / deg (all) | "
                  "held-out px |", "|---|---|---|---|---|---|"]
        for name, s in sec[key].items():
            lines.append(f"| {LABELS[name]} | {s['failures']}/{s['trials']} | {_fmt(s['t_mm_mean'])} / "
                         f"{_fmt(s['t_mm_max'])} | {_fmt(s['r_deg_mean'], 3)} / {_fmt(s['r_deg_max'], 3)} | "
                         f"{_fmt(s['t_mm_max_all'])} / {_fmt(s['r_deg_max_all'], 3)} | {_fmt(s['heldout_px_mean'])} |")
        lines.append("")
    o = sec["summary"]["ours"]
    if "coverage_axes" in o:
        lines += [f"Honesty of our 1-sigma: {100 * o['coverage_axes']:.0f} % of the error's components within their "
                  f"1-sigma (68 % expected), norms within the sigma's norm: translation {100 * o['coverage_t']:.0f} %, "
                  f"rotation {100 * o['coverage_r']:.0f} % (61 % expected).", ""]
    kin = sec.get("kinematic")
    if kin:
        lo = {k: r[0] for k, r in KINEMATIC_RANGES.items()}
        hi = {k: r[1] for k, r in KINEMATIC_RANGES.items()}
        lines += [(f"Rendered arms with kinematic errors ({kin['trials_per_setup']} scenes per set-up, "
                   f"{KINEMATIC_VIEWS[0]}-{KINEMATIC_VIEWS[1]} poses, seeds from {kin['seed']}): the true arm's joint "
                   f"offsets {lo['joint_offset_deg']:g}-{hi['joint_offset_deg']:g} deg and DH link lengths "
                   f"{lo['link_error_mm']:g}-{hi['link_error_mm']:g} mm (sigma, one draw per scene) off the kinematics "
                   f"it reports with, the reported pose {1000 * lo['time_offset_s']:g}-{1000 * hi['time_offset_s']:g} ms "
                   f"behind the image while the arm moves on ({KINEMATIC_MOVE_S:g} s from view to view), besides the "
                   "corner and joint noise above:"), "",
                  "| method | failures | X mm mean / max | X deg mean / max | worst mm / deg (all) | held-out px |",
                  "|---|---|---|---|---|---|"]
        for name, s in kin["summary"].items():
            lines.append(f"| {LABELS[name]} | {s['failures']}/{s['trials']} | {_fmt(s['t_mm_mean'])} / "
                         f"{_fmt(s['t_mm_max'])} | {_fmt(s['r_deg_mean'], 3)} / {_fmt(s['r_deg_max'], 3)} | "
                         f"{_fmt(s['t_mm_max_all'])} / {_fmt(s['r_deg_max_all'], 3)} | {_fmt(s['heldout_px_mean'])} |")
        chosen = sum(1 for r in kin["rows"] if r["ours"].get("noise_choice"))
        lines += ["", (f"Ours kept another model of the robot's error than the estimated noise term on {chosen} of "
                       f"{len(kin['rows'])} scenes."), ""]
    real = sec.get("real", {}).get("visp_franka_eye_to_hand")
    if real:
        lines += [f"Real robot, ViSP's Franka eye-to-hand data ({real['poses']} poses, one AprilTag, our corners, "
                  "ViSP's camera): X against ViSP's published result, held-out prediction RMS px over the poses.", "",
                  "| method | X vs ViSP mm / deg | held-out px |", "|---|---|---|"]
        for name, row in real["methods"].items():
            if row.get("failed") and "heldout_px" not in row:
                lines.append(f"| {LABELS[name]} | failed: {row.get('error', '')} | - |")
                continue
            lines.append(f"| {LABELS[name]} | {_fmt(row.get('vs_visp_mm'))} / {_fmt(row.get('vs_visp_deg'), 3)} | "
                         f"{_fmt(row['heldout_px'])} |")
        ours = real["methods"]["ours"]
        if "whole_heldout_px" in ours:
            lines += ["", (f"Ours with the whole procedure held out (each pose predicted by the calibration of the "
                           f"other {real['poses'] - 1}, its choice of the robot's error model made on their held-out "
                           f"poses): {_fmt(ours['whole_heldout_px'])} px. Kept: "
                           f"{ours.get('noise_choice') or 'the estimated term'}.")]
    elif sec.get("real_skipped"):
        lines.append(f"Real robot: not run ({sec['real_skipped']}).")
    ric = sec.get("real", {}).get("ric_circlegrid_eye_in_hand")
    if ric:
        lines += ["", f"Real robot, ROS-Industrial's eye-in-hand circle grid ({ric['poses']} poses with every dot seen; "
                  f"the camera calibrated by this package from the same images, RMS {ric['camera_rms_px']:.3f} px; "
                  f"its corrected centres for every method; the dots' spacing the robot tells, "
                  f"{1000 * ric['spacing']:.2f} mm, for every method: at the source's {1000 * ric['given_spacing']:.1f} "
                  f"mm ours refuses: {ric['refused_at_given'] or 'not refused'}): held-out prediction RMS px over the "
                  "poses.", "",
                  "| method | held-out px |", "|---|---|"]
        for name, row in ric["methods"].items():
            lines.append(f"| {LABELS[name]} | " + (f"failed: {row.get('error', '')}" if "heldout_px" not in row
                                                    else _fmt(row["heldout_px"])) + " |")
    charuco = sec.get("real", {}).get("ric_charuco_eye_to_hand")
    if charuco:
        lines += ["", (f"Real robot, ROS-Industrial's eye-to-hand ChArUco set ({charuco['poses']} of its "
                       f"{charuco['images']} poses with {MIN_SEEN} corners seen at least; the camera calibrated by this "
                       f"package from the same images, RMS {charuco['camera_rms_px']:.3f} px; our corners for every "
                       "method): held-out prediction RMS px over the poses."), "", "| method | held-out px |",
                  "|---|---|"]
        for name, row in charuco["methods"].items():
            lines.append(f"| {LABELS[name]} | " + (f"failed: {row.get('error', '')}" if "heldout_px" not in row
                                                    else _fmt(row["heldout_px"])) + " |")
    return lines
