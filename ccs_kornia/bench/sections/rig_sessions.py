"""Rig benchmark of hand-held sessions: rendered webcam rigs and the shared four-camera caliscope session.

**Rendered sessions** (:func:`rendered_session`, seeds from :data:`SEED`): a rig of 3-4 webcams
(:func:`~ccs_kornia.data.recordings.recordings.webcam_rig`, 1280x720, 60-75 degrees across, mild OpenCV distortion, free-running
phases, 8-20 ms exposures, 2-10 ms of timestamp jitter and 0-15 ms of latency) filming a small hand-held board (4x3
inner corners of 54 mm, :func:`~ccs_kornia.data.recordings.handheld.sample_handheld_trajectory` at 12-30 % of the image width,
sweeps of 0.05-1 m/s) for :data:`DURATION` s; the frames are paired by the logged timestamps as a recording program does
(:meth:`~ccs_kornia.data.recordings.recordings.RigRecording.sync_table`) and every :data:`FRAME_STEP`-th instant is kept. The
corners are rendered at corner level: each camera's exact corners (its own exposure, its rolling shutter's row
times: :func:`~ccs_kornia.data.recordings.exposure.exposure_truth`) plus Gaussian noise of ``0.1 px`` and a fifth of the corner's
motion blur; a view blurred by more than :data:`MAX_BLUR_PX` or with fewer than 6 corners is not detected.
Four conditions of the same sessions:

* ``handheld``: as recorded (rolling shutter, motion between the cameras' exposures);
* ``global``: the same cameras with a global shutter (the motion between exposures stays);
* ``timestamps``: what a perfect model of the board's motion (a constant-velocity board per frame with its exact
  velocity, and the readout) would give when fed the logged timestamps: each camera sees the board at the reference
  camera's instant moved by the error of its logged time offset (its jitter and latency against the reference's);
* ``frozen``: every camera of a frame sees the board at the same instant, global shutter, no blur: what a perfect
  model of the board's motion with the true exposure times would give, the bound of what modelling it could gain.

Methods, all on the same corners and the same single-camera calibrations (``OPENCV5``,
:func:`~ccs_kornia.modules.rig.rig_init.calibrate_cameras`): ``fixed`` (each camera's own calibration held, one joint
fit of the extrinsics: ``--fix-intrinsics``), ``joint`` (free intrinsics, no prior, no frame weighting:
``intrinsics_prior=None, frame_kernel=FrameKernel.NONE``), ``prior`` (the intrinsics prior without the frame weighting), ``ours``
(:class:`~ccs_kornia.modules.rig.rig_solver.RigSolver`'s defaults: the intrinsics prior and the frame weighting) and
``opencv`` (``cv2.calibrateMultiview`` on the whole-board observations, OpenCV calibrating each camera first; run in
the ``handheld`` condition only, where it takes 40-120 s a session).
Figures per camera ``c >= 1`` (against camera 0): rotation error (deg) and translation error (% of the baseline);
per camera: ``fx`` error (%) and principal point error (px); per session: the **transfer error** on held-out frames
(:func:`transfer_error`: a board posed in one camera alone, carried into another through the rig, against where that
camera sees it; on static test frames at other instants, 0.1 px of noise), median px.

**caliscope_4cam_charuco** (:func:`run_caliscope`): the shared session (4 webcams, 48 frames, ChArUco 4x5, the
published calibration in ``reference/camera_array.toml``): each camera through the single-camera pipeline, then the
rig with fixed intrinsics, the joint fit without prior or weighting, and ours; transfer error on held-out frames
(5 folds of the frames, each fitted on the others), intrinsics against the published ones and moved in single-camera sigmas, rotation from
the published rig, the frames named as inconsistent.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.geometry.poses import pair_pose
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.calibration.board_poses import camera_poses
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.modules.rig.frame_consistency import FrameKernel
from ccs_kornia.modules.rig.rig_init import calibrate_cameras

__all__ = [
    "CONDITIONS",
    "DURATION",
    "FRAME_STEP",
    "MAX_BLUR_PX",
    "METHODS",
    "SEED",
    "opencv_multiview",
    "rendered_session",
    "rig_sessions_md",
    "run_caliscope",
    "run_rig_sessions",
    "transfer_error",
]

#: first seed of the rendered sessions (the tests use seeds below 1000)
SEED = 700_000
#: seconds recorded per rendered session
DURATION = 40.0
#: every this many synchronised instants is a frame of the session
FRAME_STEP = 8
#: views blurred by more than this (px) are not detected
MAX_BLUR_PX = 15.0
METHODS = ("fixed", "joint", "prior", "ours", "opencv")
CONDITIONS = ("handheld", "global", "timestamps", "frozen")


@dataclasses.dataclass
class Session:
    """A rendered session: corners :math:`(C, F, N, 2)` (NaN where not detected), the true cameras and extrinsics,
    and static test frames :math:`(C, F_t, N, 2)`."""

    corners: torch.Tensor
    object_points: torch.Tensor
    image_sizes: list[tuple[int, int]]
    cameras: Camera
    R: torch.Tensor
    T: torch.Tensor
    frame_times: torch.Tensor
    test_corners: torch.Tensor
    spread_ms: torch.Tensor  #: (F,) the largest time between two cameras' exposures of a frame (frame times), ms


def _pixels(cam, traj, pattern, obj, times):
    """Board corners :math:`(F, N, 2)` seen by ``cam`` at ``times`` :math:`(F,)` (all corners at once), NaN where not
    imaged."""
    R, t = cam.to_camera(*traj.pose_at(times))
    pc = obj[None] @ R.transpose(-1, -2) + t[:, None]
    pix, ok = cam.project(pc)
    w, h = cam.image_size
    inside = (pix[..., 0] >= 0) & (pix[..., 0] <= w - 1) & (pix[..., 1] >= 0) & (pix[..., 1] <= h - 1)
    seen = ok & inside & pattern.facing(R, t)[:, None]
    return torch.where(seen[..., None], pix, float("nan"))


def rendered_session(seed: int, condition: str = "handheld", cameras: int | None = None,
                     duration: float = DURATION, step: int = FRAME_STEP, noise_px: float = 0.1) -> Session:
    """One rendered hand-held session (see the module doc)."""
    from ccs_kornia.data.recordings.exposure import exposure_truth
    from ccs_kornia.data.recordings.handheld import sample_handheld_trajectory
    from ccs_kornia.data.recordings.patterns import ChessPattern
    from ccs_kornia.data.recordings.recordings import RigRecording, webcam_rig

    if condition not in CONDITIONS:
        raise ValueError(f"condition must be one of {CONDITIONS}, got {condition!r}.")
    g = torch.Generator().manual_seed(seed)
    C = int(cameras or 3 + int(torch.randint(0, 2, (1,), generator=g)))
    cams = webcam_rig(C, (1280, 720), seed=seed)
    if condition != "handheld":
        cams = [dataclasses.replace(c, line_time=0.0) for c in cams]
    still = condition in ("timestamps", "frozen")
    pattern = ChessPattern(4, 3, 0.054)
    obj = pattern.object_points()
    traj = sample_handheld_trajectory(cams, pattern, duration, seed, fill=(0.12, 0.3))
    rec = RigRecording(cams, pattern, traj, duration, seed)
    table: dict[int, dict[int, int]] = {}
    for s, c, j, _ in rec.sync_table():
        table.setdefault(s, {})[c] = j
    instants = sorted(table)
    train, test = instants[::step], instants[step // 2 :: step]
    F, N = len(train), obj.shape[0]
    corners = torch.full((C, F, N, 2), float("nan"), dtype=torch.float64)
    times = torch.full((C, F), float("nan"), dtype=torch.float64)
    ref = min(range(C), key=lambda c: (cams[c].fps, c))
    for c in range(C):
        picks = [(k, table[s][c]) for k, s in enumerate(train) if c in table[s]]
        if not picks:
            continue
        ks = torch.tensor([k for k, _ in picks])
        starts = rec[c].frame_start[[j for _, j in picks]]
        times[c, ks] = cams[c].frame_times(starts)
        if still:  # every camera at the reference camera's instant (moved by its time error), no blur
            at = []
            for k, j in zip(ks.tolist(), [j for _, j in picks]):
                r = ref if ref in table[train[k]] else c
                t_ref = float(cams[r].frame_times(rec[r].frame_start[table[train[k]][r]]))
                error = 0.0
                if condition == "timestamps":  # the logged offset's error: (true - logged) of c less the reference's
                    t_c = float(cams[c].frame_times(rec[c].frame_start[j]))
                    error = (t_c - float(rec[c].timestamp[j])) - (t_ref - float(rec[r].timestamp[table[train[k]][r]]))
                at.append(t_ref + error)
            px = _pixels(cams[c], traj, pattern, obj, torch.tensor(at, dtype=torch.float64))
            blur = torch.zeros(px.shape[:2], dtype=torch.float64)
        else:
            truth = exposure_truth(cams[c], pattern, traj, starts)
            px = torch.where(truth.visible[..., None], truth.corners, float("nan"))
            blur = truth.motion.norm(dim=-1).nan_to_num(0.0)
        sigma = (noise_px ** 2 + (0.2 * blur) ** 2).sqrt()
        px = px + sigma[..., None] * torch.randn(px.shape, generator=g, dtype=torch.float64)
        seen = px.isfinite().all(-1)
        blurred = torch.where(seen, blur, 0.0).sum(-1) / seen.sum(-1).clamp_min(1) > MAX_BLUR_PX
        keep = (seen.sum(-1) >= 6) & ~blurred
        corners[c, ks] = torch.where(keep[:, None, None], px, float("nan"))
    spread = (times.nan_to_num(float("inf")).amin(0) - times.nan_to_num(-float("inf")).amax(0)).abs() * 1e3
    frame_times = torch.tensor(train, dtype=torch.float64)
    test_corners = torch.full((C, len(test), N, 2), float("nan"), dtype=torch.float64)
    test_times = torch.tensor([float(rec[ref].timestamp[table[s][ref]]) if ref in table[s] else float("nan")
                               for s in test], dtype=torch.float64)
    ok = test_times.isfinite()
    for c in range(C):
        px = _pixels(cams[c], traj, pattern, obj, test_times[ok])
        px = px + noise_px * torch.randn(px.shape, generator=g, dtype=torch.float64)
        test_corners[c, ok] = torch.where((px.isfinite().all(-1).sum(-1) >= 6)[:, None, None], px, float("nan"))
    R, T = rec.extrinsics
    truth = Camera.cat([c.camera for c in cams])
    return Session(corners, obj, [c.image_size for c in cams], truth, R, T, frame_times, test_corners,
                   spread.masked_fill(~spread.isfinite(), float("nan")))


def transfer_error(cameras: Camera, R: torch.Tensor, T: torch.Tensor, corners: torch.Tensor,
                   valid: torch.Tensor, object_points: torch.Tensor, min_corners: int = 6) -> torch.Tensor:
    """Every corner's transfer error (px): the board posed in one camera alone (its intrinsics held), carried into
    another camera of the same frame through the rig's extrinsics and projected with that camera's intrinsics,
    against where that camera sees the corner; over every ordered pair of cameras and every frame both see.

    Args:
        cameras: C cameras; R, T: :math:`(C, 3, 3)`, :math:`(C, 3)` extrinsics (``x_c = R_c x_0 + T_c``).
        corners: :math:`(C, F, N, 2)`; valid: :math:`(C, F, N)`; object_points: :math:`(N, 3)`.
        min_corners: a camera poses the board in a frame where it sees at least this many corners.

    Returns:
        :math:`(M,)` px, one per corner and ordered pair (empty where no frame is shared).
    """
    C = len(cameras)
    obj = object_points.double()
    valid = valid & corners.isfinite().all(-1)
    poses = []
    cameras = cameras.to(dtype=torch.float64)
    for c in range(C):
        cam = cameras[c]
        rv, tv, ok, _ = camera_poses(cam.params, cam.model, corners[c][None].double().nan_to_num(0.0), valid[c][None],
                                     obj, min_corners)
        poses.append((exp_so3(rv[0]), tv[0], ok[0]))
    out = []
    for i in range(C):
        for j in range(C):
            if i == j:
                continue
            Rij, Tij = pair_pose(R.double(), T.double(), i, j)
            frames = poses[i][2] & valid[j].any(-1)
            if not bool(frames.any()):
                continue
            X = (poses[i][0][frames] @ obj.T).transpose(-1, -2) + poses[i][1][frames][:, None]
            Xj = X @ Rij.T + Tij
            uv = cameras[j].project(Xj[None])[0]
            d = (uv - corners[j][frames].double()).norm(dim=-1)
            out.append(d[valid[j][frames] & d.isfinite()])
    return torch.cat(out) if out else torch.zeros(0, dtype=torch.float64)


def opencv_multiview(
    corners: torch.Tensor, object_points: torch.Tensor, image_sizes: list[tuple[int, int]],
    initial: Camera | None = None,
) -> tuple[Camera, torch.Tensor, torch.Tensor] | str:
    """``cv2.calibrateMultiview`` on the observations of the whole board, every camera ``CALIB_MODEL_PINHOLE`` (5
    coefficients); with ``initial`` cameras, their intrinsics as the guess (``CALIB_USE_INTRINSIC_GUESS``, as the
    tutorial's ``find_intrinsics_in_advance``), else OpenCV calibrates each camera first. (Partial boards, given as
    ``(-1, -1)`` as its documentation allows, made it diverge on these sessions: RMS 290 px on a frozen one.)
    Returns ``(cameras, R, T)`` or an error."""
    import cv2

    C, F = corners.shape[:2]
    seen = corners.isfinite().all(-1)
    mask = seen.all(-1).numpy().astype(np.uint8)
    pts = np.where(seen[..., None].numpy(), corners.numpy(), -1.0).astype(np.float32)
    obj = np.repeat(object_points.numpy().astype(np.float32)[None], F, 0)
    Ks = dists = None
    flags = 0
    if initial is not None:
        Ks = [K.numpy().copy() for K in initial.K.double()]
        dists = [np.pad(d, (0, 5 - d.size))[:5].reshape(1, 5).copy()
                 for d in (initial.coeffs(c).double().numpy() for c in range(len(initial)))]
        flags = cv2.CALIB_USE_INTRINSIC_GUESS
    try:
        out = cv2.calibrateMultiview(obj, pts, [tuple(int(v) for v in s) for s in image_sizes], mask,
                                     np.zeros(C, dtype=np.uint8), Ks, dists, None, None, flags=flags)
    except cv2.error as err:
        return str(err).strip().splitlines()[-1]
    _, Ks, dists, Rs, Ts = out
    cams = Camera.cat([Camera.from_opencv(OPENCV5, torch.from_numpy(np.asarray(K, dtype=np.float64)),
                                          torch.from_numpy(np.asarray(d, dtype=np.float64).ravel()[:5]), size)
                       for K, d, size in zip(Ks, dists, image_sizes)])
    R = torch.stack([torch.from_numpy(np.asarray(r, dtype=np.float64).reshape(3, 3)) if np.asarray(r).size == 9 else
                     exp_so3(torch.from_numpy(np.asarray(r, dtype=np.float64).ravel())) for r in Rs])
    T = torch.stack([torch.from_numpy(np.asarray(t, dtype=np.float64).ravel()) for t in Ts])
    if not (torch.isfinite(R).all() and torch.isfinite(T).all()):
        return "non-finite result"
    return cams, R, T


def _errors(cams, R, T, s: Session) -> dict:
    """Per-camera errors of one calibration of a session."""
    C = len(cams)
    rot = [float(log_so3((R[c] @ s.R[c].T)[None])[0].norm()) * 180 / math.pi for c in range(1, C)]
    pct = [100 * float((T[c] - s.T[c]).norm() / s.T[c].norm()) for c in range(1, C)]
    K, K_true = cams.K, s.cameras.K
    fx = [100 * abs(float(K[c, 0, 0] / K_true[c, 0, 0]) - 1) for c in range(C)]
    pp = [float((K[c, :2, 2] - K_true[c, :2, 2]).norm()) for c in range(C)]
    te = transfer_error(cams, R, T, s.test_corners, s.test_corners.isfinite().all(-1), s.object_points)
    return {"rot_deg": rot, "trans_pct": pct, "fx_pct": fx, "pp_px": pp,
            "transfer_px": float(te.median()) if te.numel() else float("nan")}


def _solve_all(s: Session, methods=METHODS) -> dict:
    """Every method on a session: per method its errors (or ``{"failed": reason}``) and seconds."""
    from ccs_kornia.modules.rig.rig_solver import RigSolver

    C = s.corners.shape[0]
    valid = s.corners.isfinite().all(-1)
    initial = []
    for c in range(C):
        p, ok, *_ = calibrate_cameras(s.corners[c][None], valid[c][None], s.object_points, s.image_sizes[c], OPENCV5)
        initial.append(Camera(OPENCV5, p, s.image_sizes[c]) if bool(ok[0]) else None)
    out = {}
    opts = {"fixed": {"frame_kernel": FrameKernel.NONE},
            "joint": {"intrinsics_prior": None, "frame_kernel": FrameKernel.NONE},
            "prior": {"frame_kernel": FrameKernel.NONE}, "ours": {}}
    for name in methods:
        t0 = time.perf_counter()
        try:
            if name == "opencv":
                got = opencv_multiview(s.corners, s.object_points, s.image_sizes)
                if isinstance(got, str):
                    out[name] = {"failed": got}
                    continue
                cams, R, T = got
            else:
                if any(c is None for c in initial):
                    out[name] = {"failed": "a camera alone could not be calibrated"}
                    continue
                res = RigSolver(OPENCV5, folds=0, **opts[name])(
                    s.corners, valid, s.object_points, s.image_sizes, initial=initial,
                    fixed=[name == "fixed"] * C, frame_times=s.frame_times)
                if not res.success:
                    out[name] = {"failed": res.reason}
                    continue
                cams, R, T = res.cameras, res.R, res.T
            out[name] = {**_errors(cams, R, T, s), "seconds": time.perf_counter() - t0}
            if name != "opencv":
                out[name]["converged"] = bool(res.converged)
                w = res.frame_weight
                out[name]["low_weight_frames"] = int(((w < 0.5) & w.isfinite()).sum())
        except (ValueError, RuntimeError) as err:
            out[name] = {"failed": str(err)}
    return out


def _mean(values):
    v = [x for x in values if not math.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


def run_rig_sessions(cfg=None, trials: int | None = None, conditions=None, methods=METHODS, seed: int = SEED,
                     log=print, caliscope: bool | None = None, duration: float | None = None) -> dict:
    """Run the rendered sessions (``trials``, default ``cfg.rig_session_trials`` else 8, of ``duration`` s) under
    ``conditions`` (default the config's, else :data:`CONDITIONS`) and the caliscope session when present
    (``cfg.real_dir``; ``caliscope`` default ``cfg.rig_session_caliscope``). Returns a JSON-able dict."""
    trials = trials if trials is not None else int(getattr(cfg, "rig_session_trials", 8))
    conditions = tuple(conditions or getattr(cfg, "rig_session_conditions", CONDITIONS))
    duration = float(duration or getattr(cfg, "rig_session_duration", DURATION))
    caliscope = bool(getattr(cfg, "rig_session_caliscope", True)) if caliscope is None else caliscope
    rows = []
    for t in range(trials):
        for cond in conditions:
            t0 = time.perf_counter()
            s = rendered_session(seed + t, cond, duration=duration)
            run = [m for m in methods if m != "opencv" or cond == "handheld"]
            row = {"trial": t, "condition": cond, "cameras": s.corners.shape[0], "frames": s.corners.shape[1],
                   "spread_ms_median": float(s.spread_ms.nanmedian()), "methods": _solve_all(s, run)}
            rows.append(row)
            log(f"[rig_sessions] trial {t + 1}/{trials} {cond}: {row['cameras']} cameras, {row['frames']} frames "
                f"({time.perf_counter() - t0:.0f} s): " + ", ".join(
                    f"{m} {r.get('transfer_px', float('nan')):.3f} px" for m, r in row["methods"].items()))
    summary = {}
    for cond in conditions:
        summary[cond] = {}
        for m in methods:
            if not any(m in r["methods"] for r in rows if r["condition"] == cond):
                continue
            got = [r["methods"][m] for r in rows if r["condition"] == cond and "failed" not in r["methods"][m]]
            summary[cond][m] = {
                "sessions": sum(r["condition"] == cond for r in rows), "failures":
                    sum(r["condition"] == cond and "failed" in r["methods"][m] for r in rows if m in r["methods"]),
                "rot_deg": _mean([x for g in got for x in g["rot_deg"]]),
                "trans_pct": _mean([x for g in got for x in g["trans_pct"]]),
                "fx_pct": _mean([x for g in got for x in g["fx_pct"]]),
                "pp_px": _mean([x for g in got for x in g["pp_px"]]),
                "transfer_px": _mean([g["transfer_px"] for g in got]),
            }
    worse = {}
    for cond in conditions:  # sessions where ours is worse than the fixed-intrinsics recipe
        pairs = [(r["methods"]["ours"], r["methods"]["fixed"]) for r in rows if r["condition"] == cond
                 and "failed" not in r["methods"].get("ours", {"failed": 1})
                 and "failed" not in r["methods"].get("fixed", {"failed": 1})]
        worse[cond] = {k: sum(_mean(o[k]) > _mean(f[k]) if isinstance(o[k], list) else o[k] > f[k] for o, f in pairs)
                       for k in ("rot_deg", "trans_pct", "fx_pct", "pp_px", "transfer_px")}
    out = {"trials": trials, "seed": seed, "duration_s": duration, "rows": rows, "summary": summary,
           "ours_worse_than_fixed": worse}
    from ccs_kornia.bench.sections.real import default_real_dir

    real = Path(getattr(cfg, "real_dir", None) or default_real_dir()) / "caliscope_4cam_charuco"
    if caliscope and real.is_dir():
        try:
            out["caliscope"] = run_caliscope(real, log=log)
        except Exception as err:  # the rendered figures stand without it
            out["caliscope"] = {"error": f"{type(err).__name__}: {err}"}
    return out


def _reference(folder: Path):
    """The published calibration: cameras and extrinsics from camera 0 (``x_c = R_c x_0 + T_c``)."""
    import tomllib

    ref = tomllib.loads((folder / "reference" / "camera_array.toml").read_text())["cameras"]
    keys = sorted(ref, key=int)
    cams = Camera.cat([Camera.from_opencv(OPENCV5, torch.tensor(ref[k]["matrix"], dtype=torch.float64),
                                          torch.tensor(ref[k]["distortions"], dtype=torch.float64)) for k in keys])
    Rw = [torch.tensor(ref[k]["rotation"], dtype=torch.float64) for k in keys]
    tw = [torch.tensor(ref[k]["translation"], dtype=torch.float64) for k in keys]
    R = torch.stack([r @ Rw[0].T for r in Rw])
    T = torch.stack([t - r @ Rw[0].T @ tw[0] for r, t in zip(Rw, tw)])
    return cams, R, T


def run_caliscope(folder: Path, models=None, folds: int = 5, log=print) -> dict:
    """The shared caliscope session (see the module doc)."""
    from ccs_kornia.modules.calibration.quality.diagnostics import split_views
    from ccs_kornia.modules.detection.boards import CharucoBoard, grid_object_points
    from ccs_kornia.modules.detection.markers.charuco import CharucoDetector
    from ccs_kornia.modules.rig.rig_solver import RigSolver
    from ccs_kornia.pipeline.frame_matching import match_frames
    from ccs_kornia.pipeline.rig_pipeline import RigPipeline
    from ccs_kornia.pipeline.sources import FileSource

    board = CharucoBoard(4, 5, 0.054, 0.0405, "DICT_4X4_1000")
    files = [sorted(str(p) for p in (folder / f"cam_{k}").glob("*.jpg")) for k in range(4)]
    names = [f"cam{k}" for k in range(4)]
    t0 = time.perf_counter()
    models = ModelChoice() if models is None else models
    pipe = RigPipeline(CharucoDetector(board), models=models, workers=1, detection_batch_size=8)
    source = FileSource(files, names)
    cameras = pipe.detect_and_calibrate(source, board.board_size, board.square)
    frames = match_frames(files)
    log(f"[rig_sessions] caliscope: cameras detected and calibrated in {time.perf_counter() - t0:.0f} s")
    ref_cams, ref_R, ref_T = _reference(folder)
    obj = grid_object_points(board, board.board_size, board.square, dtype=torch.float64)
    out = {"models": str(models), "methods": {}}
    variants = {"fixed": ({"frame_kernel": FrameKernel.NONE}, True),
                "joint": ({"intrinsics_prior": None, "frame_kernel": FrameKernel.NONE}, False), "ours": ({}, False)}
    for name, (opts, fix) in variants.items():
        pipe.solver_kwargs = dict(opts)
        pipe.fixed = {}
        if fix:
            pipe.fixed = {i: r.calibration.camera.to("cpu", torch.float64) for i, r in enumerate(cameras)}
        t1 = time.perf_counter()
        res = pipe.run(source, board.board_size, board.square, frames, names, cameras=cameras)
        rig = res.rig
        corners, valid = res.corners, res.valid
        # held-out transfer: each fold's frames posed and carried by the rig fitted on the other frames
        seen = valid.any(-1).any(0)[None]
        split = split_views(seen, folds)[0]  # (folds, F)
        errs = []
        for k in range(folds):
            test = split[k]
            v = valid & ~test[None, :, None]
            fit = RigSolver(res.models, folds=0, **opts)(corners, v, obj, [tuple(s) for s in rig.image_sizes],
                                                        initial=res.initial, fixed=[fix] * 4 if fix else None,
                                                        names=names, weights=res.weights)
            errs.append(transfer_error(fit.cameras, fit.R, fit.T, corners, valid & test[None, :, None], obj))
        held = torch.cat(errs)
        rot = {f"{i}-{j}": float(log_so3((pair_pose(rig.R, rig.T, i, j)[0] @ pair_pose(ref_R, ref_T, i, j)[0].T)[None])
                                 [0].norm()) * 180 / math.pi for i in range(4) for j in range(i + 1, 4)}
        item = {
            "heldout_transfer_px": float(held.median()),
            "transfer_px": float(transfer_error(rig.cameras, rig.R, rig.T, corners, valid, obj).median()),
            "converged": bool(rig.converged), "iterations": int(rig.iterations), "verdict": rig.verdict,
            "models": [str(m) for m in rig.cameras.models],
            "fx": rig.cameras.K[:, 0, 0].tolist(), "cy": rig.cameras.K[:, 1, 2].tolist(),
            "moved_sigma_max": [float(m.abs().max()) for m in rig.intrinsics_moved_sigma],
            "rotation_from_published_deg": rot,
            "low_weight_frames": [res.frames.labels[f] for f in range(len(res.frames.labels))
                                  if float(rig.frame_weight[f]) < 0.5],
            "seconds": time.perf_counter() - t1,
        }
        out["methods"][name] = item
        log(f"[rig_sessions] caliscope {name}: held-out transfer {item['heldout_transfer_px']:.3f} px, "
            f"converged {item['converged']}, fx {[round(x, 1) for x in item['fx']]}")
    ref_held = transfer_error(ref_cams, ref_R, ref_T, res.corners, res.valid, obj)
    out["published"] = {"transfer_px": float(ref_held.median()), "fx": ref_cams.K[:, 0, 0].tolist(),
                        "cy": ref_cams.K[:, 1, 2].tolist()}
    return out


def rig_sessions_md(sec: dict) -> list[str]:
    """Markdown of :func:`run_rig_sessions`'s result."""
    if "summary" not in sec:
        return [f"Not run: {sec.get('error') or sec.get('skipped', '')}"]
    lines = [(f"{sec['trials']} rendered hand-held sessions of 3-4 webcams (module doc of `bench/sections/rig_sessions.py`); "
              "means over the cameras and sessions that did not fail. Transfer: held-out static frames, median px."),
             "",
             ("| condition | method | failures | rotation deg | translation % | fx % | principal point px | "
              "transfer px |"),
             "|---|---|---|---|---|---|---|---|"]
    for cond, methods in sec["summary"].items():
        for m, s in methods.items():
            lines.append(f"| {cond} | {m} | {s['failures']} / {s['sessions']} | {s['rot_deg']:.3f} | "
                         f"{s['trans_pct']:.2f} | {s['fx_pct']:.2f} | {s['pp_px']:.2f} | {s['transfer_px']:.3f} |")
    worse = sec.get("ours_worse_than_fixed", {})
    if worse:
        lines += ["", "Sessions where `ours` is worse than `fixed` (per figure): " + "; ".join(
            f"{c}: " + ", ".join(f"{k} {v}" for k, v in w.items()) for c, w in worse.items())]
    cal = sec.get("caliscope")
    if cal and "methods" in cal:
        lines += ["", ("caliscope_4cam_charuco (`--model auto`): held-out transfer (5 folds of frames), fit transfer, "
                       "fx per camera, largest intrinsic move in single-camera sigmas, frames weighing below one half:"),
                  "",
                  "| method | held-out transfer px | transfer px | converged | fx | moved sigma | low-weight frames |",
                  "|---|---|---|---|---|---|---|"]
        for m, r in cal["methods"].items():
            lines.append(f"| {m} | {r['heldout_transfer_px']:.3f} | {r['transfer_px']:.3f} | {r['converged']} | "
                         f"{', '.join(f'{x:.1f}' for x in r['fx'])} | "
                         f"{', '.join(f'{x:.1f}' for x in r['moved_sigma_max'])} | {len(r['low_weight_frames'])} |")
        p = cal["published"]
        lines.append(f"| published | | {p['transfer_px']:.3f} | | {', '.join(f'{x:.1f}' for x in p['fx'])} | | |")
    elif cal:
        lines += ["", f"caliscope_4cam_charuco: {cal.get('error')}"]
    return lines
