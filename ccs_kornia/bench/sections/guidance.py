r"""Guided capture benchmark: a simulated person following the next best pose, against ROS ``camera_calibration``'s
rule and against random poses, on cameras with known truth.

**The cameras** (640x480, a 9x6 board of 25 mm squares, corners projected exactly, then Gaussian detector noise of
``noise_px``): ``normal`` (radial-tangential, 64 degrees across), ``wide`` (radial-tangential, 104 degrees across,
strong barrel, monotonic over the whole image) and ``fisheye`` (Kannala-Brandt, 165 degrees across, 212 on the
diagonal). Each is calibrated with its own model.

**The people.** A hand-held pose is where the board's centre sits in the image, how much of the width it fills and
how far it is turned about the camera's x and y axes (and about its normal): what a person controls.

* ``guided`` follows :mod:`~ccs_kornia.modules.calibration.quality.next_pose`: the best pose for the current
  calibration (before the first solve, for a guessed camera of the right kind whose focal length and barrel come
  from the frames kept so far, :func:`~ccs_kornia.pipeline.guided_capture.guess_camera`) is shown; the person moves the board
  from where it was towards it, stops short by a reaction delay (a fraction 0-20 % of the way, uniform) and holds
  it with hand jitter (``jitter_mm`` per axis, ``jitter_deg`` per axis); the frame is kept where at least 60 % of the
  corners are in the image (the detector takes partial boards, as a ChArUco board's: the poses shown include
  boards partly beyond the image's edge, :data:`~ccs_kornia.modules.calibration.quality.next_pose.MIN_SEEN`). The
  calibration is solved again at each count of :data:`COUNTS` (a solve whose RMS is over three times the noise's is not followed: the guidance keeps the camera
  before it); between solves the new views' information is taken at the pose the last camera gives them.
* ``ros`` waves the board about at random (positions over the whole image, 30-80 % of the width, tilts up to 45
  degrees about each axis, 20 degrees about the normal; the whole board in the image, 8 px clear of its border, as
  ROS's detector needs) and ROS's rule keeps a frame when its X, Y, size and skew parameters differ from every kept
  frame's by more than 0.2 (sum of absolute differences), up to 40 samples; ROS enables CALIBRATE at 40 samples or
  once its four bars are full (ranges 0.7, 0.7, 0.4, 0.5), its ``goodenough``.
* ``random`` keeps every one of those random poses.
* ``random_partial`` keeps random poses drawn the same way but where at least
  :data:`~ccs_kornia.modules.calibration.quality.next_pose.MIN_SEEN` of the corners are in the image, the others left
  out, as the guided person's: what a ChArUco board waved about at random gives (ROS's rule needs whole chessboards).

**The figures.** The error against the truth: the RMS over a 16x12 grid of pixels of the distance between where the
true and the calibrated camera project the same ray (the camera rotation fitted out, as mrcal does). The target
error of a camera is the median error of ROS's rule at its 40 samples; per trial, the frames each person needs to
reach it (the first count of :data:`COUNTS` at or below it), and each person's error at equal counts. Seeds start at
:data:`SEED`.
"""

from __future__ import annotations

import math
import statistics

import numpy as np
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, OPENCV5
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.calibration.quality.next_pose import (
    MIN_SEEN,
    candidate_poses,
    next_poses,
    place_board,
)
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    projection_difference,
)
from ccs_kornia.modules.calibration.quality.view_information import view_information
from ccs_kornia.pipeline.guided_capture import guess_camera

__all__ = ["CAMERAS", "COUNTS", "PEOPLE", "SEED", "guidance_md", "projection_error", "ros_parameters", "run_guidance",
           "run_guidance_camera"]

#: first seed of the trials
SEED = 800_000
#: frame counts at which every person's calibration is solved and compared
COUNTS = (4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40)
#: camera kind -> (model, true parameters, the guessed camera's focal length before the first solve)
CAMERAS = {
    "normal": (OPENCV5, [530.0, 532.0, 322.0, 238.0, -0.12, 0.08, 0.0008, -0.0005, 0.0], 640.0),
    "wide": (OPENCV5, [330.0, 331.0, 318.0, 243.0, -0.25, 0.06, 0.0006, 0.0004, 0.0], 640.0),
    "fisheye": (FISHEYE, [215.0, 215.5, 321.0, 241.0, 0.03, -0.01, 0.004, -0.001], 640.0 / 3),
}
SIZE = (640, 480)
BOARD = (9, 6)
SQUARE = 0.025
#: ROS's detector refuses a board with a corner this close to the image border (px)
ROS_BORDER = 8.0
#: ROS's sample distance threshold, bar ranges and sample count
ROS_MIN_DISTANCE = 0.2
ROS_RANGES = (0.7, 0.7, 0.4, 0.5)
ROS_SAMPLES = 40
#: the people compared, as the tables name them
PEOPLE = {"guided": "guided", "ros": "ros", "random": "random", "random_partial": "random, partial boards"}


def _camera(kind: str, guess: bool = False) -> Camera:
    model, params, focal = CAMERAS[kind]
    p = torch.tensor(params, dtype=torch.float64)
    if guess:  # what a person knows before the first solve: the kind of lens, a focal length, the image centre
        p = torch.zeros_like(p)
        p[:4] = torch.tensor([focal, focal, (SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2])
    return Camera(model, p, SIZE)


def projection_error(truth: Camera, estimate: Camera, grid: tuple[int, int] = (16, 12)) -> torch.Tensor:
    """:math:`(C,)` the RMS over a grid of pixels of the distance (px) between where the true and the estimated
    cameras project the same ray, the camera rotation fitted out (NaN for a failed estimate)."""
    pixels = image_points(SIZE, grid)
    fit = torch.ones(pixels.shape[0], dtype=torch.bool)
    truth = Camera(truth.model, truth.params.expand(len(estimate), -1), SIZE)
    d = projection_difference(truth, estimate.nan_to_num(), pixels, compensate_rotation=fit)
    bad = ~estimate.params.isfinite().all(-1)
    rms = d.pow(2).nanmean(-1).sqrt()
    return torch.where(bad, torch.full_like(rms, float("nan")), rms)


def ros_parameters(corners: np.ndarray, board: tuple[int, int], size: tuple[int, int]) -> list[float]:
    """ROS ``camera_calibration``'s description of one chessboard view: X, Y (the board's mean position, the image
    shrunk by half the board's size), size (the square root of the outer quadrilateral's share of the image) and skew
    (twice the outer corner angle's departure from 90 degrees, at most 1).

    Example:
        >>> c = np.array([[x, y] for y in (100.0, 200.0) for x in (100.0, 300.0)])
        >>> [round(v, 3) for v in ros_parameters(c, (2, 2), (640, 480))]
        [0.259, 0.234, 0.255, 0.0]
    """
    cols, _ = board
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    ul, ur, dr, dl = c[0], c[cols - 1], c[-1], c[-cols]
    p, q = (dr - ur) + (dl - dr), (ur - ul) + (dr - ur)
    area = abs(p[0] * q[1] - p[1] * q[0]) / 2.0
    ab, cb = ul - ur, dr - ur
    angle = math.acos(float(np.dot(ab, cb) / (np.linalg.norm(ab) * np.linalg.norm(cb))))
    skew = min(1.0, 2.0 * abs(math.pi / 2 - angle))
    border = math.sqrt(area)
    w, h = size
    px = min(1.0, max(0.0, float(c[:, 0].mean() - border / 2) / (w - border)))
    py = min(1.0, max(0.0, float(c[:, 1].mean() - border / 2) / (h - border)))
    return [px, py, math.sqrt(area / (w * h)), skew]


def _ros_bars_full(kept: list[list[float]]) -> bool:
    lo = [min(p[i] for p in kept) for i in range(2)] + [0.0, 0.0]
    hi = [max(p[i] for p in kept) for i in range(4)]
    return all((b - a) / r >= 1.0 for a, b, r in zip(lo, hi, ROS_RANGES, strict=True))


def _project(camera: Camera, obj: torch.Tensor, rvec: torch.Tensor, tvec: torch.Tensor) -> torch.Tensor:
    pts = torch.einsum("kij,nj->kni", exp_so3(rvec), obj) + tvec[:, None]
    uv = camera.project(pts.reshape(1, -1, 3))[0].reshape(rvec.shape[0], -1, 2)
    return torch.where((pts[..., 2:] > 0), uv, torch.full_like(uv, float("nan")))


def _inside(uv: torch.Tensor, border: float) -> torch.Tensor:
    return (uv.isfinite().all(-1) & (uv[..., 0] >= border) & (uv[..., 0] <= SIZE[0] - 1 - border)
            & (uv[..., 1] >= border) & (uv[..., 1] <= SIZE[1] - 1 - border))


def _random_stream(truth: Camera, obj: torch.Tensor, g: torch.Generator, count: int,
                   min_seen: float = 1.0) -> tuple[torch.Tensor, ...]:
    """Random hand-held poses: rvec, tvec (K, 3). With ``min_seen`` 1 the whole board in the image, ROS's border
    clear; below 1, at least that fraction of the corners in the image (the others left out, as the guided person's)."""
    rv, tv = [], []
    while sum(len(r) for r in rv) < count:
        k = 4 * count
        u = torch.rand(k, 6, generator=g, dtype=torch.float64)
        px = torch.stack([u[:, 0] * SIZE[0], u[:, 1] * SIZE[1]], -1)
        fill = 0.3 + 0.5 * u[:, 2]
        tilt = (u[:, 3:5] - 0.5) * 90.0
        roll = (u[:, 5] - 0.5) * 40.0
        rvec, tvec, uv, depth = place_board(truth, obj, px, fill, tilt, roll)
        if min_seen >= 1.0:
            ok = (_inside(uv, ROS_BORDER) & (depth > 0)).all(-1)
        else:
            ok = (depth > 0).all(-1) & (_inside(uv, 1.0).double().mean(-1) >= min_seen - 1e-9)
        rv.append(rvec[ok])
        tv.append(tvec[ok])
    return torch.cat(rv)[:count], torch.cat(tv)[:count]


def _solve(model, uv: torch.Tensor, valid: torch.Tensor, obj: torch.Tensor):
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    solver = CalibrationSolver(model=model, use_ransac=False, checks=False, reject_outliers=False)
    return solver(torch.where(valid[..., None], uv, torch.zeros_like(uv)), valid, obj, SIZE)


def _views_information(camera: Camera, obj: torch.Tensor, uv: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """:math:`(P, P)` the information of views whose poses are not solved: each posed by the camera given (a
    perspective-n-point fit on the camera's rays), then :func:`view_information`."""
    import cv2

    rays = camera.unproject(torch.where(valid[..., None], uv, torch.zeros_like(uv)).reshape(1, -1, 2))[0]
    rays = rays.reshape(*uv.shape[:-1], 3)
    rv, tv = [], []
    for v in range(uv.shape[0]):
        m = valid[v] & (rays[v, :, 2] > 1e-6)
        xy = (rays[v, m, :2] / rays[v, m, 2:]).numpy()
        ok, r, t = cv2.solvePnP(obj[m].numpy(), xy, np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
        rv.append(torch.from_numpy(r.reshape(3)) if ok else torch.zeros(3, dtype=torch.float64))
        tv.append(torch.from_numpy(t.reshape(3)) if ok else torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    M = view_information(camera, torch.stack(rv)[None], torch.stack(tv)[None], obj, valid[None].double())
    return M[0].sum(0)


def _errors_at_counts(model, truth: Camera, uv: torch.Tensor, valid: torch.Tensor, obj: torch.Tensor,
                      counts: tuple[int, ...]) -> np.ndarray:
    """(T, len(counts)) the error against the truth of each trial's first ``n`` frames, solved together."""
    out = np.full((uv.shape[0], len(counts)), np.nan)
    for j, n in enumerate(counts):
        if n > uv.shape[1]:
            continue
        res = _solve(model, uv[:, :n], valid[:, :n], obj)
        out[:, j] = projection_error(truth, res.camera).numpy()
    return out


def _guided(kind: str, truth: Camera, obj: torch.Tensor, trials: int, counts: tuple[int, ...], noise: float,
            jitter_mm: float, jitter_deg: float, shortfall: float, seed: int) -> tuple[np.ndarray, list[str]]:
    """The guided person, all trials in step: errors (T, len(counts)) and the first trial's instructions."""
    model = truth.model
    g = torch.Generator().manual_seed(seed)
    guess = _camera(kind, guess=True)
    P = model.num_params
    n_max = max(counts)
    uv = torch.zeros(trials, n_max, obj.shape[0], 2, dtype=torch.float64)
    valid = torch.zeros(trials, n_max, obj.shape[0], dtype=torch.bool)
    cams = [guess] * trials
    infos = [torch.zeros(P, P, dtype=torch.float64) for _ in range(trials)]
    solved_upto = [0] * trials
    sigma = [noise] * trials
    cands = candidate_poses(guess, obj, BOARD)
    where = [(torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64))] * trials
    errors = np.full((trials, len(counts)), np.nan)
    said: list[str] = []
    kept = [0] * trials
    tries = 0
    while min(kept) < n_max and tries < 4 * n_max:
        tries += 1
        for t in range(trials):
            if kept[t] >= n_max:
                continue
            s = next_poses(cams[t], infos[t], obj, sigma[t], BOARD,
                           candidates=cands if cams[t] is guess else None, top=1)
            if t == 0:
                said.append(s.instruction)
            r_goal, t_goal = s.poses.rvec[0], s.poses.tvec[0]
            r_was, t_was = where[t]
            lam = 1.0 - shortfall * float(torch.rand(1, generator=g, dtype=torch.float64))
            R_was = exp_so3(r_was)
            step = log_so3(exp_so3(r_goal) @ R_was.T)
            jit = torch.randn(6, generator=g, dtype=torch.float64)
            R_now = exp_so3(torch.deg2rad(jitter_deg * jit[:3])) @ exp_so3(lam * step) @ R_was
            t_now = t_was + lam * (t_goal - t_was) + jitter_mm / 1000 * jit[3:]
            r_now = log_so3(R_now)
            where[t] = (r_now, t_now)
            c = _project(truth, obj, r_now[None], t_now[None])[0]
            seen = _inside(c, 1.0)
            if float(seen.double().mean()) < 0.6:
                continue
            k = kept[t]
            uv[t, k] = c + noise * torch.randn(c.shape, generator=g, dtype=torch.float64)
            valid[t, k] = seen
            kept[t] += 1
            if not solved_upto[t] and not model.is_fisheye:  # before a solve: the lens guessed from the views so far
                seen_uv = torch.where(valid[t, :k + 1, :, None], uv[t, :k + 1], float("nan"))
                cams[t] = guess_camera(model, SIZE, seen_uv, obj)
                infos[t] = _views_information(cams[t], obj, uv[t, :k + 1], valid[t, :k + 1])
            elif kept[t] not in counts:  # between solves: the new view posed by the last camera
                infos[t] = infos[t] + _views_information(cams[t], obj, uv[t, k:k + 1], valid[t, k:k + 1])
        ready = [n for n in counts if all(kept[t] >= n for t in range(trials)) and n > max(solved_upto)]
        for n in ready:
            res = _solve(model, uv[:, :n], valid[:, :n], obj)
            errors[:, counts.index(n)] = projection_error(truth, res.camera).numpy()
            for t in range(trials):
                if not bool(res.camera.params[t].isfinite().all()) or not float(res.rms[t]) < 3 * noise * math.sqrt(2):
                    continue
                cams[t] = res.camera[t]
                M = view_information(cams[t], res.rvec[t:t + 1], res.tvec[t:t + 1], obj, valid[t:t + 1, :n].double())
                infos[t] = M[0].sum(0)
                if kept[t] > n:
                    infos[t] = infos[t] + _views_information(cams[t], obj, uv[t, n:kept[t]], valid[t, n:kept[t]])
                sigma[t] = float(res.rms[t]) / math.sqrt(2) if math.isfinite(float(res.rms[t])) else noise
                solved_upto[t] = n
    return errors, said[:6]


def _ros_and_random(truth: Camera, obj: torch.Tensor, trials: int, counts: tuple[int, ...], noise: float,
                    seed: int) -> dict:
    g = torch.Generator().manual_seed(seed)
    n_max = max(counts)
    shape = (trials, n_max, obj.shape[0])
    rand_uv = torch.zeros(*shape, 2, dtype=torch.float64)
    ros_uv = torch.zeros(*shape, 2, dtype=torch.float64)
    ros_ready, ros_seen = [], []
    for t in range(trials):
        rvec, tvec = _random_stream(truth, obj, g, 2000)
        c = _project(truth, obj, rvec, tvec)
        c = c + noise * torch.randn(c.shape, generator=g, dtype=torch.float64)
        rand_uv[t] = c[:n_max]
        kept: list[list[float]] = []
        ready = None
        for k in range(c.shape[0]):
            p = ros_parameters(c[k].numpy(), BOARD, SIZE)
            if kept and min(sum(abs(a - b) for a, b in zip(p, q, strict=True)) for q in kept) <= ROS_MIN_DISTANCE:
                continue
            ros_uv[t, len(kept)] = c[k]
            kept.append(p)
            if ready is None and _ros_bars_full(kept):
                ready = len(kept)
            if len(kept) == n_max:
                ros_seen.append(k + 1)
                break
        else:
            raise RuntimeError("ROS's rule kept fewer than 40 of 2000 random poses.")
        ros_ready.append(ready if ready is not None else ROS_SAMPLES)
    valid = torch.ones(shape, dtype=torch.bool)
    model = truth.model
    return {"random": _errors_at_counts(model, truth, rand_uv, valid, obj, counts),
            "ros": _errors_at_counts(model, truth, ros_uv, valid, obj, counts),
            "ros_goodenough": ros_ready, "ros_frames_seen": ros_seen}


def _random_partial(truth: Camera, obj: torch.Tensor, trials: int, counts: tuple[int, ...], noise: float,
                    seed: int) -> np.ndarray:
    """Random hand-held poses where at least :data:`MIN_SEEN` of the corners are in the image, the others left out
    (a ChArUco board's detector, as the guided person's partial boards): errors (T, len(counts))."""
    g = torch.Generator().manual_seed(seed)
    n_max = max(counts)
    uv = torch.zeros(trials, n_max, obj.shape[0], 2, dtype=torch.float64)
    valid = torch.zeros(trials, n_max, obj.shape[0], dtype=torch.bool)
    for t in range(trials):
        rvec, tvec = _random_stream(truth, obj, g, n_max, min_seen=MIN_SEEN)
        c = _project(truth, obj, rvec, tvec)
        valid[t] = _inside(c, 1.0)
        uv[t] = c + noise * torch.randn(c.shape, generator=g, dtype=torch.float64)
    return _errors_at_counts(truth.model, truth, uv, valid, obj, counts)


def _frames_to(errors: np.ndarray, target: float, counts: tuple[int, ...]) -> list[int | None]:
    out = []
    for row in errors:
        hit = [n for n, e in zip(counts, row, strict=True) if math.isfinite(e) and e <= target]
        out.append(hit[0] if hit else None)
    return out


def _median_frames(frames: list[int | None], beyond: int) -> float:
    """The median over trials, a trial that never reached the target counted beyond the last count."""
    return float(statistics.median([f if f is not None else beyond for f in frames]))


def run_guidance_camera(kind: str, trials: int = 8, counts: tuple[int, ...] = COUNTS, noise: float = 0.2,
                        jitter_mm: float = 15.0, jitter_deg: float = 4.0, shortfall: float = 0.2, seed: int = SEED,
                        log=print) -> dict:
    """One camera kind: the four people's errors at :data:`COUNTS` and the frames each needs (a JSON-able dict)."""
    truth = _camera(kind)
    obj = board_object_points(*BOARD, SQUARE, dtype=torch.float64)
    guided, said = _guided(kind, truth, obj, trials, counts, noise, jitter_mm, jitter_deg, shortfall, seed)
    log(f"[guidance] {kind}: guided done")
    other = _ros_and_random(truth, obj, trials, counts, noise, seed + 1)
    errors = {"guided": guided, "ros": other["ros"], "random": other["random"],
              "random_partial": _random_partial(truth, obj, trials, counts, noise, seed + 2)}
    j40 = counts.index(max(counts))
    target = float(np.nanmedian(errors["ros"][:, j40]))
    beyond = max(counts) + 10
    out: dict = {"target_px": target, "counts": list(counts), "trials": trials, "instructions": said,
                 "noise_px": noise, "min_seen": MIN_SEEN, "jitter_mm": jitter_mm, "jitter_deg": jitter_deg, "shortfall": shortfall,
                 "ros_goodenough": other["ros_goodenough"], "ros_frames_seen": other["ros_frames_seen"],
                 "people": {}}
    for name, e in errors.items():
        frames = _frames_to(e, target, counts)
        out["people"][name] = {"errors_px": e.tolist(),
                               "median_px": [float(np.nanmedian(c)) for c in e.T],
                               "frames_to_target": frames,
                               "median_frames": _median_frames(frames, beyond),
                               "reached": sum(f is not None for f in frames)}
    g, r, q, qp = (out["people"][n]["median_frames"] for n in ("guided", "ros", "random", "random_partial"))
    out["fewer_frames_than_ros"] = 1.0 - g / r
    out["fewer_frames_than_random"] = 1.0 - g / q
    out["fewer_frames_than_random_partial"] = 1.0 - g / qp
    log(f"[guidance] {kind}: target {target:.3f} px; frames guided {g:g}, ROS {r:g}, random {q:g}, "
        f"random with partial boards {qp:g}")
    return out


def run_guidance(cfg=None, log=print) -> dict:
    """Run the benchmark (``cfg.guidance_trials`` trials per camera kind of ``cfg.guidance_cameras``). Returns a
    JSON-able dict."""
    trials = int(getattr(cfg, "guidance_trials", 8))
    kinds = tuple(getattr(cfg, "guidance_cameras", tuple(CAMERAS)))
    counts = tuple(getattr(cfg, "guidance_counts", COUNTS))
    out: dict = {"trials": trials, "seed": SEED, "cameras": {}}
    for k, kind in enumerate(kinds):
        out["cameras"][kind] = run_guidance_camera(kind, trials, counts, seed=SEED + 1000 * k, log=log)
    return out


def guidance_md(sec: dict) -> list[str]:
    """Markdown of :func:`run_guidance`'s result."""
    if "cameras" not in sec:
        return [f"Not run: {sec.get('error') or sec.get('skipped', '')}"]
    first = next(iter(sec["cameras"].values()))
    lines = [(f"{sec['trials']} simulated people per camera (640x480, 9x6 board, {first['noise_px']:g} px detector noise): "
              f"guided by the next best pose (reaction delay: 0-{100 * first['shortfall']:.0f} % short of the pose; "
              f"hand jitter {first['jitter_mm']:g} mm and {first['jitter_deg']:g} degrees per axis), "
              "ROS camera_calibration's rule on random hand-held poses (40 samples), the random poses themselves "
              "(whole boards, as ROS's), and random poses with partial boards allowed (at least "
              f"{100 * first['min_seen']:.0f} % of the corners in the image, the others left out, as "
              "the guided person's). "
              "Error: RMS over the image of the projection difference to the true camera (px, rotation fitted out). "
              "Target: ROS's median error at its 40 samples. Frames: the median over trials of the first count of "
              f"{', '.join(str(c) for c in first['counts'])} at or below the target "
              "(a trial that never reaches it counts as 10 beyond the last)."), "",
             ("| camera | target px | frames guided | frames ROS | frames random | frames random, partial boards | "
              "fewer than ROS | fewer than random | fewer than random, partial boards | "
              "ROS goodenough (median samples) |"), "|---|---|---|---|---|---|---|---|---|---|"]
    for kind, c in sec["cameras"].items():
        frames = " | ".join(f"{c['people'][n]['median_frames']:g} ({c['people'][n]['reached']}/{c['trials']})"
                            for n in PEOPLE)
        fewer = " | ".join(f"{100 * c['fewer_frames_than_' + n]:.0f} %" for n in list(PEOPLE)[1:])
        lines.append(f"| {kind} | {c['target_px']:.3f} | {frames} | {fewer} | {statistics.median(c['ros_goodenough']):g} |")
    lines += ["", "Median error against the truth (px) at equal frame counts:", ""]
    for kind, c in sec["cameras"].items():
        counts = c["counts"]
        lines += [f"**{kind}**", "", "| frames | " + " | ".join(str(n) for n in counts) + " |",
                  "|---|" + "---|" * len(counts)]
        for name, label in PEOPLE.items():
            lines.append(f"| {label} | " + " | ".join(f"{v:.3f}" for v in c["people"][name]["median_px"]) + " |")
        lines += ["", f"First instructions (trial 1): {'; '.join(repr(s) for s in c['instructions'][:4])}.", ""]
    return lines
