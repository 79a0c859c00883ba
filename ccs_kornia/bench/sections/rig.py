"""Rig benchmark: our rig solver against OpenCV's stereo recipe on the same rendered corners.

Each trial renders a random rig (:func:`~ccs_kornia.data.scenes.rig.render_rig`): 2-4 cameras, each a pinhole
(``OPENCV5`` or ``K1K2``) or a fisheye (``FISHEYE``, Kannala-Brandt), baselines 0.1-0.4 m, yaw/pitch up to 15 degrees, board poses
that leave partial boards near the image edges, cameras missing 10 % of the frames, Gaussian pixel noise of 0.1-0.3
px. Seeds start at :data:`SEED` (disjoint from the tests').

* ours: :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver` on every corner;
* OpenCV, as its users run it (full boards only): each camera alone on the frames where it sees every corner
  (``cv2.calibrateCamera``, with ``CALIB_ZERO_TANGENT_DIST | CALIB_FIX_K3`` for ``K1K2``; ``cv2.fisheye.calibrate``
  through :func:`~ccs_kornia.bench.methods.fisheye_opencv.opencv_fisheye`), then camera 0 with each other camera on the
  frames where both see every corner: ``cv2.stereoCalibrate`` (two pinholes) or ``cv2.fisheye.stereoCalibrate`` (two
  fisheyes) with ``CALIB_FIX_INTRINSIC``; a pinhole/fisheye pair has no OpenCV function, so both cameras' corners are
  undistorted to normalized coordinates first and ``cv2.stereoCalibrate`` runs with ``K = I`` and no distortion.
  An exception, fewer than 3 usable frames or a non-finite result counts as a failure.

Per camera pair (camera 0, camera c): rotation error (degrees), translation error (% of the true baseline) and the
epipolar RMS (px) of all the corners both cameras see (each method with its own cameras). A pair fails when its
method fails or errs by more than :data:`FAIL_DEG` degrees or :data:`FAIL_PCT` % of the baseline.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from ccs_kornia.bench.common import CV2_FLAGS
from ccs_kornia.bench.methods.fisheye_opencv import opencv_fisheye
from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import FISHEYE, K1K2, OPENCV5
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.rig.rig_diagnostics import epipolar_sums
from ccs_kornia.modules.rig.rig_solver import RigSolver

__all__ = ["SEED", "FAIL_DEG", "FAIL_PCT", "random_rig", "opencv_rig", "run_rig", "rig_md"]

#: first seed of the trials (the tests use seeds below 1000)
SEED = 500_000
#: a pair whose rotation errs by more than this (degrees) counts as failed
FAIL_DEG = 1.0
#: a pair whose translation errs by more than this (% of the baseline) counts as failed
FAIL_PCT = 5.0
IMAGE_SIZE = (640, 480)


def random_rig(seed: int, frames: int = 20, board: tuple[int, int] = (9, 6), square: float = 0.04):
    """A rendered random rig (see the module doc) and its noise level."""
    g = np.random.default_rng(seed)
    C = int(g.integers(2, 5))
    W, H = IMAGE_SIZE
    cams = []
    for c in range(C):
        model = FISHEYE if g.random() < 0.4 else (OPENCV5 if g.random() < 0.5 else K1K2)
        if model.is_fisheye:
            f = g.uniform(220, 320)
            dist = torch.tensor([g.uniform(-0.05, 0.05), g.uniform(-0.02, 0.02), 0.0, 0.0], dtype=torch.float64)
        else:
            f = g.uniform(450, 700)
            dist = torch.tensor([g.uniform(-0.3, -0.05), g.uniform(0.0, 0.1), 0, 0, 0], dtype=torch.float64)
            if model == OPENCV5:
                dist[2:4] = torch.tensor(g.uniform(-0.001, 0.001, 2))
        K = torch.tensor([[f * g.uniform(0.99, 1.01), 0, (W - 1) / 2 + g.uniform(-10, 10)],
                          [0, f, (H - 1) / 2 + g.uniform(-10, 10)], [0, 0, 1]], dtype=torch.float64)
        cams.append(Camera.from_opencv(model, K, dist, IMAGE_SIZE))
    rv = torch.zeros(C, 3, dtype=torch.float64)
    T = torch.zeros(C, 3, dtype=torch.float64)
    for c in range(1, C):
        rv[c] = torch.tensor([g.uniform(-0.26, 0.26), g.uniform(-0.26, 0.26), g.uniform(-0.05, 0.05)])
        direction = g.normal(size=3) * np.array([1.0, 0.5, 0.2])
        T[c] = torch.tensor(direction / np.linalg.norm(direction) * g.uniform(0.1, 0.4))
    noise = float(g.uniform(0.1, 0.3))
    scene = render_rig(Camera.cat(cams), exp_so3(rv), T, num_frames=frames, seed=seed, board=board,
                       square=square, noise_px=noise, drop=0.1, distance=(0.7, 1.6), spread=0.3)
    return scene, noise


def _calibrate_one(model, obj, pts, size):
    """One camera of ``model`` alone, OpenCV (``cv2.fisheye`` for a fisheye): (K, dist) or None."""
    if model.is_fisheye:
        out = opencv_fisheye(obj, pts, size)
        return (out["K"], out["D"]) if out["ok"] else None
    flags = CV2_FLAGS[model]
    o = [obj.astype(np.float32).reshape(-1, 1, 3)] * len(pts)
    rms, K, d, _, _ = cv2.calibrateCamera(o, [p.astype(np.float32).reshape(-1, 1, 2) for p in pts], size, None, None,
                                          flags=flags)
    return (K, d.ravel()) if np.isfinite(rms) else None


def opencv_rig(scene, min_frames: int = 3) -> dict:
    """OpenCV's recipe (module doc) on a scene: per camera ``(K, dist)`` or None, per camera c >= 1 ``(R, T)`` of
    ``x_c = R x_0 + T`` or an error string."""
    obj = scene.object_points.numpy()
    C = len(scene.cameras)
    full = scene.valid.all(-1)  # (C, F)
    cams, errors = [], {}
    for c in range(C):
        frames = torch.nonzero(full[c]).flatten().tolist()
        try:
            if len(frames) < min_frames:
                raise ValueError(f"{len(frames)} full-board frames")
            cams.append(_calibrate_one(scene.cameras.models[c], obj, [scene.corners[c, f].numpy() for f in frames],
                                       scene.image_sizes[c]))
        except (cv2.error, ValueError) as e:
            cams.append(None)
            errors[c] = str(e).strip().splitlines()[-1]
    poses = {}
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    for c in range(1, C):
        frames = torch.nonzero(full[0] & full[c]).flatten().tolist()
        if cams[0] is None or cams[c] is None:
            poses[c] = "camera calibration failed: " + errors.get(0 if cams[0] is None else c, "")
            continue
        if len(frames) < min_frames:
            poses[c] = f"{len(frames)} frames where both see the whole board"
            continue
        fish0, fishc = (scene.cameras.models[k].is_fisheye for k in (0, c))
        pts0 = [scene.corners[0, f].numpy().reshape(-1, 1, 2) for f in frames]
        ptsc = [scene.corners[c, f].numpy().reshape(-1, 1, 2) for f in frames]
        try:
            if fish0 and fishc:
                o = [obj.reshape(1, -1, 3).astype(np.float64)] * len(frames)
                out = cv2.fisheye.stereoCalibrate(
                    o, [p.reshape(1, -1, 2) for p in pts0], [p.reshape(1, -1, 2) for p in ptsc], cams[0][0],
                    cams[0][1], cams[c][0], cams[c][1], scene.image_sizes[0], flags=cv2.fisheye.CALIB_FIX_INTRINSIC,
                    criteria=crit)
                R, T = out[5], out[6]
            else:
                o = [obj.reshape(-1, 1, 3).astype(np.float32)] * len(frames)
                if fish0 != fishc:  # no mixed stereo in OpenCV: undistort both first
                    rc = [_opencv_camera(scene.cameras.models[k], cams[k]) for k in (0, c)]
                    pts0 = [rc[0].undistort(torch.from_numpy(p).reshape(1, -1, 2)).reshape(p.shape).numpy() for p in pts0]
                    ptsc = [rc[1].undistort(torch.from_numpy(p).reshape(1, -1, 2)).reshape(p.shape).numpy() for p in ptsc]
                    K0 = Kc = np.eye(3)
                    d0 = dc = np.zeros(5)
                else:
                    K0, d0, Kc, dc = cams[0][0], cams[0][1], cams[c][0], cams[c][1]
                out = cv2.stereoCalibrate(o, [p.astype(np.float32) for p in pts0], [p.astype(np.float32) for p in ptsc],
                                          K0, d0, Kc, dc, scene.image_sizes[0], flags=cv2.CALIB_FIX_INTRINSIC,
                                          criteria=crit)
                R, T = out[5], out[6]
            ok = np.isfinite(R).all() and np.isfinite(T).all()
            poses[c] = (R, T.ravel()) if ok else "non-finite result"
        except cv2.error as e:
            poses[c] = str(e).strip().splitlines()[-1]
    return {"cameras": cams, "poses": poses}


def _opencv_camera(model, calibration) -> Camera:
    """OpenCV's ``(K, dist)`` of one camera as a camera of ``model`` (float64)."""
    K, dist = (torch.from_numpy(np.asarray(a, dtype=np.float64)) for a in calibration)
    return Camera.from_opencv(model, K, dist.flatten())


def _pair_errors(R, T, scene, c):
    rot = float(log_so3(torch.as_tensor(R, dtype=torch.float64) @ scene.R[c].T).norm()) * 180 / math.pi
    pct = 100 * float((torch.as_tensor(T, dtype=torch.float64).flatten() - scene.T[c]).norm() / scene.T[c].norm())
    return rot, pct


def _epipolar(cams, R, T, scene, c) -> float:
    Rr = torch.stack([torch.eye(3, dtype=torch.float64), torch.as_tensor(R, dtype=torch.float64)])
    Tr = torch.stack([torch.zeros(3, dtype=torch.float64), torch.as_tensor(T, dtype=torch.float64).flatten()])
    idx = [0, c]
    s, n = epipolar_sums(cams, Rr, Tr, scene.corners[idx], scene.valid[idx],
                         torch.ones(2, scene.corners.shape[1], dtype=torch.bool))
    return float((s[0, 1] / n[0, 1].clamp_min(1)).sqrt()) if int(n[0, 1]) else float("nan")


def run_rig(cfg=None, trials: int | None = None, frames: int | None = None, seed: int = SEED, log=print) -> dict:
    """Run the benchmark (``trials`` rigs of ``frames`` frames; defaults ``cfg.rig_trials`` / ``cfg.rig_frames``, else
    10 / 20). Returns a JSON-able dict with one row per camera pair (0, c) and the summary per method."""
    trials = trials if trials is not None else int(getattr(cfg, "rig_trials", 10))
    frames = frames if frames is not None else int(getattr(cfg, "rig_frames", 20))
    rows = []
    for t in range(trials):
        scene, noise = random_rig(seed + t, frames)
        C = len(scene.cameras)
        models = scene.cameras.models
        try:
            ours = RigSolver(models, folds=0)(scene.corners, scene.valid, scene.object_points, scene.image_sizes)
            ours_err = "" if ours.success else ours.reason
        except ValueError as e:
            ours, ours_err = None, str(e)
        cv = opencv_rig(scene)
        for c in range(1, C):
            row = {"trial": t, "cameras": C, "pair": f"{models[0]}-{models[c]}", "noise_px": noise,
                   "full_frames": int((scene.valid[0].all(-1) & scene.valid[c].all(-1)).sum()),
                   "frames_seen": int(((scene.valid[0].sum(-1) >= 6) & (scene.valid[c].sum(-1) >= 6)).sum())}
            for name in ("ours", "opencv"):
                if name == "ours":
                    if ours is None or ours_err:
                        row[name] = {"failed": True, "error": ours_err}
                        continue
                    R, T, cams = ours.R[c], ours.T[c], ours.cameras[[0, c]]
                else:
                    pose = cv["poses"][c]
                    if isinstance(pose, str):
                        row[name] = {"failed": True, "error": pose}
                        continue
                    R, T = (torch.from_numpy(np.asarray(p, dtype=np.float64)) for p in pose)
                    cams = Camera.cat([_opencv_camera(models[k], cv["cameras"][k]) for k in (0, c)])
                rot, pct = _pair_errors(R, T, scene, c)
                row[name] = {"rot_deg": rot, "trans_pct": pct, "epipolar_px": _epipolar(cams, R, T, scene, c),
                             "failed": not (rot <= FAIL_DEG and pct <= FAIL_PCT)}
            rows.append(row)
        log(f"[rig] trial {t + 1}/{trials}: {C} cameras ({', '.join(map(str, models))}), noise {noise:.2f} px")
    def stats(found: list[dict], prefix: str = "") -> dict:
        return {f"{prefix}{k}_{q}": (float(np.percentile([o[k] for o in found], p)) if found else float("nan"))
                for k in ("rot_deg", "trans_pct", "epipolar_px") for q, p in (("median", 50), ("p90", 90))}

    summary = {}
    both = [r for r in rows if not (r["ours"]["failed"] or r["opencv"]["failed"])]
    for name in ("ours", "opencv"):
        ok = [r[name] for r in rows if not r[name]["failed"]]
        summary[name] = {"pairs": len(rows), "failures": sum(r[name]["failed"] for r in rows), "common_pairs": len(both),
                         **stats(ok), **stats([r[name] for r in both], "common_")}
    return {"trials": trials, "frames": frames, "seed": seed, "rows": rows, "summary": summary}


def rig_md(sec: dict) -> list[str]:
    """Markdown of :func:`run_rig`'s result."""
    if "summary" not in sec:
        return [f"Not run: {sec.get('error') or sec.get('skipped', '')}"]
    lines = [f"{sec['trials']} rendered rigs (2-4 cameras, pinhole and fisheye mixed, partial boards, 0.1-0.3 px "
             f"noise), camera 0 paired with each other camera. Failure: an error, or more than {FAIL_DEG} deg / "
             f"{FAIL_PCT} % of the baseline off. Medians / 90th percentiles over the pairs that did not fail.", "",
             "| method | pairs | failures | rotation deg | translation % | epipolar px |", "|---|---|---|---|---|---|"]
    labels = (("ours", "ccs_kornia RigSolver"), ("opencv", "OpenCV calibrate + stereoCalibrate"))
    for prefix, title in (("", None), ("common_", "On the pairs neither method failed")):
        if title:
            n = sec["summary"]["ours"]["common_pairs"]
            lines += ["", f"{title} ({n}):", "", "| method | rotation deg | translation % | epipolar px |",
                      "|---|---|---|---|"]
        for name, label in labels:
            s = sec["summary"][name]
            head = f"| {label} | " + ("" if title else f"{s['pairs']} | {s['failures']} | ")
            lines.append(head + f"{s[prefix + 'rot_deg_median']:.3f} / {s[prefix + 'rot_deg_p90']:.3f} | "
                         f"{s[prefix + 'trans_pct_median']:.2f} / {s[prefix + 'trans_pct_p90']:.2f} | "
                         f"{s[prefix + 'epipolar_px_median']:.3f} / {s[prefix + 'epipolar_px_p90']:.3f} |")
    return lines
