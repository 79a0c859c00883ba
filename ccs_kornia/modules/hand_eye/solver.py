r"""Hand-eye calibration by a joint fit of every board corner, batched over problems (docs/hand_eye.md).

From board corners per view, the robot's flange pose per view and the camera, :func:`calibrate_hand_eye` estimates
``X`` (the camera's pose on the robot) and ``Z`` (the board's pose in the robot's other frame):

1. the board's pose in each view from its corners alone (homography of the undistorted corners, refined with the
   camera held; :func:`~ccs_kornia.modules.calibration.board_poses.camera_poses`);
2. the checks of :mod:`~ccs_kornia.modules.hand_eye.degeneracy` (too few poses, tiny rotations, one axis, robot and
   camera disagreeing in rotation or scale): a problem that fails one is refused, with the poses named;
3. every closed form of :mod:`~ccs_kornia.modules.hand_eye.closed_forms`, each scored by the reprojection error of
   its ``X`` and ``Z`` over all corners: the fit starts from the best (never a fixed method);
4. the joint fit (:mod:`~ccs_kornia.modules.hand_eye.problem`, :mod:`~ccs_kornia.modules.hand_eye.fit`): all corners,
   ``X``, ``Z``, optionally the camera's intrinsics and a robot-pose noise term; the covariance of the result;
5. a fit whose error is far above any detector's (:data:`DISAGREE_PX` per 1000 px of diagonal) means the robot and
   the camera disagree: refused, with a note when the inverted poses (the base in the flange frame) fit; a board whose
   size disagrees with the robot's translations (:mod:`~ccs_kornia.modules.hand_eye.target_scale`) is refused with
   the size the robot sees;
6. the held-out figures (:mod:`~ccs_kornia.modules.hand_eye.heldout`) and the verdict;
6b. with ``board_flatness``, the board's sag (:mod:`~ccs_kornia.geometry.board_warp`) fitted with ``X`` and ``Z`` on
   the same LM and kept where the views determine it and it lowers the leave-one-pose-out RMS by 5 %
   (:func:`~ccs_kornia.modules.calibration.board_flatness.keep_board_warp`, the single camera's rule);
7. with the robot-pose noise estimated (``"auto"``) and held-out poses predicted less than well (above the verdict's
   ``good_heldout``), other models of the robot's error: the poses taken as exact, and fixed rotation and translation
   sigmas weighed apart (:data:`NOISE_GRID_DEG` x :data:`NOISE_GRID_MM`); the one that predicts the held-out poses
   best is kept where it does so at least :data:`NOISE_MODEL_GAIN` times better than the estimated term. A real arm's
   errors are systematic (joint offsets, link lengths, elasticity), not the isotropic noise the term models, and with
   few corners per pose its rotation and translation parts trade against the board's tilt: the variance components
   are then weakly determined (too large on one arm, too small on another: docs/hand_eye.md) and the robot's own
   prediction of a pose it has not seen is the better judge. On rendered robots, whose pose noise is the term's,
   held-out poses are predicted well and the term is kept.

:class:`HandEyeSolver` is the module form; with ``corners`` (or robot poses) requiring grad, ``X``, ``Z`` and the
free intrinsics carry gradients by implicit differentiation of the optimum
(:mod:`~ccs_kornia.modules.hand_eye.implicit`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import torch
from torch import nn

from ccs_kornia.geometry.board_warp import board_warp_basis
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.board_flatness import board_warp_determined, board_warp_record, keep_board_warp
from ccs_kornia.modules.calibration.board_poses import camera_poses
from ccs_kornia.modules.calibration.board_symmetry import (
    board_symmetries,
    undo_symmetry,
)
from ccs_kornia.modules.calibration.lm import parameter_basis
from ccs_kornia.modules.hand_eye.board_order import align_board_orders, renumber_corners
from ccs_kornia.modules.hand_eye.closed_forms import closed_form_candidates
from ccs_kornia.modules.hand_eye.degeneracy import MIN_POSES, hand_eye_issues
from ccs_kornia.modules.hand_eye.fit import fit_problem
from ccs_kornia.modules.hand_eye.heldout import jackknife_covariance, leave_one_pose_out
from ccs_kornia.modules.hand_eye.noise import fit_with_noise_estimate
from ccs_kornia.modules.hand_eye.problem import (
    GLOBAL_POSE_PARAMS,
    HandEyeProblem,
    HandEyeState,
)
from ccs_kornia.modules.hand_eye.camera_fit import calibrated_view_rms
from ccs_kornia.modules.hand_eye.result import (
    HandEyeResult,
    HandEyeVerdictThresholds,
    camera_misfits,
    hand_eye_verdict,
)
from ccs_kornia.modules.hand_eye.setup import HandEyeSetup, invert_transforms
from ccs_kornia.modules.hand_eye.target_scale import SCALE_SIGMAS, SCALE_TOLERANCE, board_scale
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["DISAGREE_PX", "JACKKNIFE_MIN_POSES", "NOISE_GRID_DEG", "NOISE_GRID_MM", "NOISE_MODEL_GAIN", "HandEyeSolver",
           "calibrate_hand_eye"]

#: a fit whose RMS exceeds this (px per 1000 px of image diagonal) is refused: robot and camera disagree
DISAGREE_PX = 10.0
#: where the robot-pose noise is estimated, its start: (radians, metres)
START_NOISE = (1e-3, 1e-3)
#: a held-out refit re-estimates the noise in this many rounds, from the full fit's estimate (more rounds change the
#: held-out figures by little: docs/hand_eye.md)
HELDOUT_NOISE_ROUNDS = 2
#: another model of the robot's error replaces the estimated noise term where its held-out RMS is below this
#: fraction of the term's
NOISE_MODEL_GAIN = 0.9
#: the fixed robot-pose sigmas tried where held-out poses are predicted less than well: every rotation sigma (degrees)
#: with every translation sigma (millimetres), a decade apart from each other
NOISE_GRID_DEG = (0.03, 0.3, 3.0, 30.0)
NOISE_GRID_MM = (0.3, 3.0, 30.0)
#: the 1-sigma comes from the leave-one-pose-out refits' spread (jackknife) where at least this many poses were held
#: out, else from the fit's covariance (which sees the corners' noise only, not a robot pose's error)
JACKKNIFE_MIN_POSES = 5


def _pose(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def _cameras(camera: Camera, B: int, dtype, device) -> Camera:
    """The problems' cameras: one for all, or one per problem (one model)."""
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera (ccs_kornia.geometry.camera), got {type(camera).__name__}.")
    if len(camera) not in (1, B):
        raise ValueError(f"camera: one camera, or one per problem ({B}), got {len(camera)}.")
    if not camera.uniform:
        raise ValueError(f"the cameras of one batch must share a model, got {camera!r}.")
    params = camera.params.to(device=device, dtype=dtype).expand(B, -1).clone()
    return Camera(camera.model, params, camera.image_sizes * (B // len(camera)))


def _view_rms(problem: HandEyeProblem, state: HandEyeState) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r = problem.residuals(state)
    on = problem.w > 0
    sq = torch.where(on, (r * r).sum(-1), 0.0)
    n = on.sum(-1)
    view = (sq.sum(-1) / n.clamp_min(1)).sqrt().masked_fill(n == 0, float("nan"))
    total = (sq.sum((1, 2)) / n.sum(-1).clamp_min(1)).sqrt()
    return total, view, r


def _start(problem: HandEyeProblem, A, M, usable, params) -> tuple[HandEyeState, torch.Tensor, torch.Tensor, list[str]]:
    """Every closed form scored by its RMS over all corners; the best per problem as the start."""
    B, V, N = problem.shape
    names, Xs, Zs = closed_form_candidates(A, M, usable)
    K = len(names)
    idx = torch.arange(B, device=A.device).repeat_interleave(K)
    sub = problem.subset(idx)
    cand = HandEyeProblem.initial_state(Xs.reshape(B * K, 4, 4), Zs.reshape(B * K, 4, 4), params[idx], V)
    rms = _view_rms(sub, cand)[0].reshape(B, K)
    rms = torch.where(rms.isfinite(), rms, torch.full_like(rms, float("inf")))
    best = rms.argmin(-1)
    b = torch.arange(B, device=A.device)
    state = HandEyeProblem.initial_state(Xs[b, best], Zs[b, best], params, V)
    return state, rms, best, names


def _fitter(robot_noise, metres_per_unit: float, max_iters: int):
    """How a problem is fitted: plainly, with given robot-pose sigmas, or with them estimated (``"auto"``); returns
    ``fit(problem, state) -> (FitResult, the problem as fitted, NoiseEstimate or None)``."""
    if isinstance(robot_noise, str):
        if robot_noise != "auto":
            raise ValueError(f"robot_noise must be None, (rotation, translation) or 'auto', got {robot_noise!r}.")

        def fit(problem, state, rounds: int = 12):
            B = problem.shape[0]
            # from the problem's own sigmas where it has some (a held-out refit starts from the full fit's)
            start = problem.noise if problem.noise is not None else torch.tensor(
                [START_NOISE[0], START_NOISE[1] / metres_per_unit], dtype=problem.w.dtype,
                device=problem.w.device).expand(B, 2)
            est = fit_with_noise_estimate(problem.reweighted(torch.ones(B, dtype=problem.w.dtype,
                                                                        device=problem.w.device), start),
                                          state, start, rounds=rounds, max_iters=max_iters)
            return est.fit, est.problem, est
        return fit

    def plain(problem, state, rounds: int = 0):
        return fit_problem(problem, state, max_iters=max_iters), problem, None
    return plain


def _solve(problem, A, M, usable, params, fitter):
    state, start_rms, best, names = _start(problem, A, M, usable, params)
    fit, fitted, est = fitter(problem, state)
    return fit, fitted, est, start_rms, best, names


def calibrate_hand_eye(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    robot_poses: torch.Tensor,
    camera: Camera,
    setup: HandEyeSetup | str = HandEyeSetup.EYE_IN_HAND,
    weights: torch.Tensor | None = None,
    free_intrinsics: bool | Sequence[str] = False,
    robot_noise: tuple[float, float] | str | None = "auto",
    heldout: bool = True,
    image_size: tuple[int, int] = (640, 480),
    metres_per_unit: float = 1.0,
    names: list[list[str]] | None = None,
    min_corners: int = 4,
    max_iters: int = 100,
    align_orders: bool = False,
    board_flatness: bool = False,
) -> HandEyeResult:
    r"""Hand-eye calibration of ``B`` problems (module doc).

    Args:
        corners: :math:`(B, V, N, 2)` board corners per view (anything where not valid).
        valid: :math:`(B, V, N)` bool, the corners seen.
        object_points: :math:`(N, 3)` the board's points, in the robot poses' unit.
        robot_poses: :math:`(B, V, 4, 4)` the flange's pose in the base frame per view (``x_base = T x_flange``; NaN
            where the robot's pose is missing).
        camera: the camera (:class:`~ccs_kornia.geometry.camera.Camera`), one for all or one per problem (one model
            for the batch).
        setup: eye-in-hand or eye-to-hand (:class:`~ccs_kornia.modules.hand_eye.setup.HandEyeSetup`).
        weights: :math:`(B, V, N)` inverse variances of the corners (default 1).
        free_intrinsics: fit the camera's parameters too: ``True`` (all of its model's), or their names.
        robot_noise: the robot poses' 1-sigma, fitted as a correction per pose: ``"auto"`` (default: estimated with
            the corners' from the data, :mod:`~ccs_kornia.modules.hand_eye.noise`), ``(rotation in radians,
            translation in the poses' unit)``, or ``None`` (the poses taken as exact).
        heldout: compute the leave-one-pose-out figures.
        image_size: ``(W, H)``, for the verdict's and the refusal's pixel scales.
        metres_per_unit: the poses' unit in metres (for the verdict's translation limits).
        names: per problem, per view labels for the messages.
        min_corners: a view with fewer corners is not used.
        max_iters: iterations of the fit.
        align_orders: the detector may number a symmetric board's corners differently from view to view (a plain
            chessboard's 180-degree turn): give every view one numbering, agreed through the robot
            (:mod:`~ccs_kornia.modules.hand_eye.board_order`); ``False`` where the corners carry ids (markers, tags).
        board_flatness: also fit the board's sag with ``X`` and ``Z`` (mrcal's two coefficients,
            :mod:`~ccs_kornia.geometry.board_warp`) and keep it where the held-out poses say it helps (step 6b of the
            module doc; ``heldout`` needed): the result's ``board_warp``, ``board_warp_std`` and ``board_flatness``.

    Returns:
        :class:`~ccs_kornia.modules.hand_eye.result.HandEyeResult`.

    Example:
        >>> from ccs_kornia.data.scenes.robots import render_hand_eye
        >>> from ccs_kornia.geometry.models import K1K2
        >>> s = render_hand_eye("eye_in_hand", views=8, seed=0, noise_px=0.0, joint_noise_deg=0.0)
        >>> cam = Camera.from_opencv(K1K2, s.K, s.dist)
        >>> res = calibrate_hand_eye(s.corners[None], s.valid[None], s.object_points, s.robot_poses[None], cam,
        ...                          "eye_in_hand", heldout=False)
        >>> bool(res.success[0]), float((res.X[0] - s.X).abs().max()) < 1e-8
        (True, True)
    """
    args = (corners, valid, object_points, robot_poses, camera, setup, weights, free_intrinsics)
    options = dict(image_size=image_size, metres_per_unit=metres_per_unit, names=names, min_corners=min_corners,
                   max_iters=max_iters, align_orders=align_orders)
    result = _calibrate(*args, robot_noise=robot_noise, heldout=heldout, **options)
    kept = None
    if board_flatness and heldout:
        result, kept = _judge_flatness(args, options, result, robot_noise)
    if not (heldout and isinstance(robot_noise, str) and robot_noise == "auto"):
        return result
    # where held-out poses are predicted less than well, other models of the robot's error, kept where they predict
    # them clearly better (module doc, step 7)
    good = HandEyeVerdictThresholds().good_heldout * math.hypot(*image_size) / 1000.0
    worth = result.success & (result.heldout_rms > good)
    choice = [""] * len(worth)
    if not bool(worth.any()):
        return dataclasses.replace(result, noise_choice=choice)
    auto_rms = result.heldout_rms.clone()
    best = result
    # one model at a time: a batch of every model runs each fit as long as its slowest one needs
    models = [None] + [(math.radians(deg), mm / 1000.0 / metres_per_unit) for deg in NOISE_GRID_DEG
                       for mm in NOISE_GRID_MM]
    for model in models:
        other = _on_board(args, options, model, kept)
        better = worth & other.success & (other.heldout_rms < NOISE_MODEL_GAIN * auto_rms) & \
            (other.heldout_rms < best.heldout_rms)
        if not bool(better.any()):
            continue
        what = "the poses taken as exact" if model is None else \
            f"the robot's poses held at {math.degrees(model[0]):.3g} deg, {1000 * metres_per_unit * model[1]:.3g} mm"
        for b in better.nonzero().flatten().tolist():
            choice[b] = (f"{what}: they predict held-out poses {float(other.heldout_rms[b]):.2f} px off, the estimated "
                         f"noise term ({math.degrees(float(result.robot_noise[b, 0])):.3g} deg, "
                         f"{1000 * metres_per_unit * float(result.robot_noise[b, 1]):.3g} mm) "
                         f"{float(auto_rms[b]):.2f} px")
        best = _choose(best, other, better)
    return dataclasses.replace(best, noise_choice=choice, board_flatness=_final_warps(best))


def _flat(result: HandEyeResult) -> HandEyeResult:
    """A flat-board result as one of a judged batch: its sag 0, the sag's 1-sigma NaN."""
    B = result.X.shape[0]
    return dataclasses.replace(result, board_warp=result.X.new_zeros(B, 2),
                               board_warp_std=result.X.new_full((B, 2), float("nan")))


def _judge_flatness(args, options, flat: HandEyeResult, robot_noise) -> tuple[HandEyeResult, torch.Tensor]:
    """Step 6b: the board's sag fitted with the rest and kept per problem by
    :func:`~ccs_kornia.modules.calibration.board_flatness.keep_board_warp` on the leave-one-pose-out RMS (a sag the
    poses do not determine costs one fit, no held-out refits); the result and the problems that keep it."""
    obj = args[2].detach().to(torch.float64)
    B = flat.X.shape[0]
    kept = torch.zeros(B, dtype=torch.bool, device=flat.X.device)
    if not bool(board_warp_basis(obj).abs().amax() > 0):  # every point on the board's edge (one tag): no sag to see
        return dataclasses.replace(_flat(flat), board_flatness=[None] * B), kept
    probe = _calibrate(*args, robot_noise=robot_noise, heldout=False, board_warp=True, **options)
    determined = board_warp_determined(probe.board_warp, probe.board_warp_std, obj) & probe.success & flat.success
    nan = float("nan")
    records = [board_warp_record(False, probe.board_warp[b], probe.board_warp_std[b], nan, nan, "heldout_rms_px")
               for b in range(B)]
    out = _flat(flat)
    if bool(determined.any()):
        bent = _calibrate(*args, robot_noise=robot_noise, heldout=True, board_warp=True, **options)
        kept = determined & bent.success & keep_board_warp(bent.board_warp, bent.board_warp_std, obj,
                                                           flat.heldout_rms, bent.heldout_rms)
        for b in determined.nonzero().flatten().tolist():
            records[b] = board_warp_record(bool(kept[b]), bent.board_warp[b], bent.board_warp_std[b],
                                           flat.heldout_rms[b], bent.heldout_rms[b], "heldout_rms_px")
        out = _choose(out, bent, kept)
    return dataclasses.replace(out, board_flatness=records), kept


def _on_board(args, options, robot_noise, kept: torch.Tensor | None) -> HandEyeResult:
    """:func:`_calibrate` with ``robot_noise`` on the board as judged: bent where ``kept`` (B,), flat elsewhere
    (``None``: not judged)."""
    if kept is None:
        return _calibrate(*args, robot_noise=robot_noise, heldout=True, **options)
    bent = _calibrate(*args, robot_noise=robot_noise, heldout=True, board_warp=True, **options) \
        if bool(kept.any()) else None
    if bent is not None and bool(kept.all()):
        return bent
    flat = _flat(_calibrate(*args, robot_noise=robot_noise, heldout=True, **options))
    return flat if bent is None else _choose(flat, bent, kept)


def _final_warps(result: HandEyeResult) -> list[dict | None] | None:
    """The judged records with the sag and 1-sigma of the fit finally kept (another model of the robot's error
    refits it)."""
    if result.board_flatness is None:
        return None
    records = []
    for b, r in enumerate(result.board_flatness):
        if r is not None and r["kept"]:
            r = board_warp_record(True, result.board_warp[b], result.board_warp_std[b], r["heldout_rms_px"]["flat"]
                                  or float("nan"), r["heldout_rms_px"]["warp"] or float("nan"), "heldout_rms_px")
        records.append(r)
    return records


def _choose(current: HandEyeResult, other: HandEyeResult, pick: torch.Tensor) -> HandEyeResult:
    """Per problem, ``other``'s result where ``pick`` (B,), else ``current``'s: ``other`` fitted with fixed robot-pose
    sigmas or the poses taken as exact (its noise term's sigmas zero then, its corners' sigma not estimated: NaN)."""
    if not bool(pick.any()):
        return current
    values = {}
    B = pick.shape[0]
    for f in dataclasses.fields(current):
        a, b = getattr(current, f.name), getattr(other, f.name)
        if a is None and b is None:  # (both poses taken as exact: no noise term, no corrections)
            values[f.name] = None
        elif f.name == "robot_noise":
            b = torch.zeros_like(a) if b is None else b.to(a)
            values[f.name] = torch.where(pick[:, None].to(a.device), b, a)
        elif f.name == "pixel_sigma":
            values[f.name] = None if a is None else torch.where(pick.to(a.device), float("nan"), a)
        elif f.name == "corrections":
            R, t = a
            keep = pick.to(R.device)
            Rb, tb = (torch.eye(3, dtype=R.dtype, device=R.device).expand_as(R), torch.zeros_like(t)) if b is None else b
            values[f.name] = (torch.where(keep[:, None, None, None], Rb, R), torch.where(keep[:, None, None], tb, t))
        elif isinstance(a, Camera):
            values[f.name] = a.with_params(torch.where(pick[:, None].to(a.params.device), b.params, a.params))
        elif isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor) and a.dim() and a.shape[0] == B \
                and a.shape == b.shape:
            values[f.name] = torch.where(pick.to(a.device).reshape(B, *([1] * (a.dim() - 1))), b, a)
        elif isinstance(a, list) and isinstance(b, list) and len(a) == B and f.name != "start_names":
            values[f.name] = [b[k] if bool(pick[k]) else a[k] for k in range(B)]
        else:
            values[f.name] = a
    return HandEyeResult(**values)


def _calibrate(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    robot_poses: torch.Tensor,
    camera: Camera,
    setup: HandEyeSetup | str = HandEyeSetup.EYE_IN_HAND,
    weights: torch.Tensor | None = None,
    free_intrinsics: bool | Sequence[str] = False,
    robot_noise: tuple[float, float] | str | None = "auto",
    heldout: bool = True,
    image_size: tuple[int, int] = (640, 480),
    metres_per_unit: float = 1.0,
    names: list[list[str]] | None = None,
    min_corners: int = 4,
    max_iters: int = 100,
    align_orders: bool = False,
    board_warp: bool = False,
) -> HandEyeResult:
    """:func:`calibrate_hand_eye` with one robot-noise setting, the board flat or its sag estimated (``board_warp``:
    the result's ``board_warp`` and ``board_warp_std``)."""
    setup = HandEyeSetup.parse(setup)
    check_tensor(corners, "corners", ["B", "V", "N", "2"])
    B, V, N = corners.shape[:3]
    check_tensor(valid, "valid", [B, V, N])
    check_tensor(robot_poses, "robot_poses", [B, V, 4, 4])
    check_tensor(object_points, "object_points", [N, 3])
    device, dtype = corners.device, torch.float64
    cameras = _cameras(camera, B, dtype, device)
    model, params = cameras.model, cameras.params
    corners = corners.detach().to(dtype)
    poses = robot_poses.detach().to(dtype)
    obj = object_points.detach().to(device=device, dtype=dtype)
    w = valid.bool() & corners.isfinite().all(-1)
    if weights is not None:
        check_tensor(weights, "weights", [B, V, N])
        w = w & (weights > 0)
    # 1. the board's pose in each view alone
    rvec, tvec, ok, own_rms = camera_poses(params, model, corners, w, obj, min_corners=min_corners)
    M = _pose(exp_so3(rvec), tvec)
    pose_ok = poses.flatten(-2).isfinite().all(-1)
    usable = ok & pose_ok & (w.sum(-1) >= min_corners)
    M = torch.where(usable[..., None, None], M, torch.full_like(M, float("nan")))
    safe_poses = torch.where(pose_ok[..., None, None], poses, torch.eye(4, dtype=dtype, device=device))
    A = setup.chain(safe_poses)
    order = torch.zeros(B, V, dtype=torch.long, device=device)
    if align_orders:
        syms = board_symmetries(obj)
        order = align_board_orders(A, torch.where(usable[..., None, None], M, torch.eye(4, dtype=dtype, device=device)),
                                   usable, syms)
        if bool(order.any()):
            corners, w = renumber_corners(corners, w, order, syms)
            for k in range(1, len(syms)):
                sel = order == k
                R, t = undo_symmetry(M[..., :3, :3], M[..., :3, 3], syms[k])
                M = torch.where(sel[..., None, None], _pose(R, t), M)
    # 2. the checks
    issues = hand_eye_issues(A, torch.where(usable[..., None, None], M, torch.eye(4, dtype=dtype, device=device)),
                             usable, names)
    wts = (w & usable[..., None]).to(dtype) * (1.0 if weights is None else weights.detach().to(dtype).clamp_min(0))
    basis = None
    if free_intrinsics:
        free = None if free_intrinsics is True else list(free_intrinsics)
        basis = parameter_basis(model, params, free)
    fitter = _fitter(robot_noise, metres_per_unit, max_iters)
    fixed_noise = None if isinstance(robot_noise, str) else robot_noise
    problem = HandEyeProblem(setup, model, safe_poses, obj, corners, wts, basis, fixed_noise, board_warp)
    # 3.-4. the closed forms, the best one, the fit
    M_safe = torch.where(usable[..., None, None], M, torch.eye(4, dtype=dtype, device=device))
    fit, problem, est, start_rms, best, start_names = _solve(problem, A, M_safe, usable, params, fitter)
    s = fit.state
    rms, view_rms, residuals = _view_rms(problem, s)
    scale = math.hypot(*image_size) / 1000.0
    # 5. robot and camera disagree: refused, with a note where the inverted poses fit
    refused = [any(i["severity"] == "error" for i in iss) for iss in issues]
    far = [(not refused[b]) and not (float(rms[b]) <= DISAGREE_PX * scale) for b in range(B)]
    if any(far):
        idx = torch.tensor([b for b in range(B) if far[b]], device=device)
        inv = invert_transforms(safe_poses[idx])
        alt = HandEyeProblem(setup, model, inv, obj, corners[idx], wts[idx], None if basis is None else basis[idx],
                             fixed_noise, board_warp)
        alt_fit = _solve(alt, setup.chain(inv), M_safe[idx], usable[idx], params[idx], fitter)[0]
        alt_rms = _view_rms(alt, alt_fit.state)[0]
        for k, b in enumerate(idx.tolist()):
            worst = torch.nan_to_num(view_rms[b], nan=-1.0).argsort(descending=True)[:3].tolist()
            labels = [names[b][v] if names else f"pose {v}" for v in worst if bool(usable[b, v])]
            note = ""
            if float(alt_rms[k]) < min(DISAGREE_PX * scale, float(rms[b]) / 3):
                note = (f"; the inverted poses fit ({float(alt_rms[k]):.2f} px): the poses look like the base in the "
                        "flange frame, give the flange in the base frame (x_base = T x_flange)")
            issues[b].append({"severity": "error", "check": "disagree", "poses": worst,
                              "message": f"the robot's poses and the images do not agree: the best fit is "
                                         f"{float(rms[b]):.1f} px RMS off (worst: {', '.join(labels)}){note}; check "
                                         "the pose file (order, units, convention) and --eye-in-hand/--eye-to-hand"})
            refused[b] = True
    # whether the given camera fits the images: each view's own board pose with it against a camera calibrated from
    # the same views (computed where a cause is to be named; the camera held only)
    camera_fits: dict[int, tuple[float, float]] = {}

    def camera_fit(b: int) -> tuple[float, float]:
        if b not in camera_fits:
            own = own_rms[b][usable[b] & own_rms[b].isfinite()]
            if basis is not None or not own.numel():
                camera_fits[b] = (float("nan"), float("nan"))
            else:
                use = (w & usable[..., None])[b:b + 1]
                camera_fits[b] = (float(own.median()),
                                  float(calibrated_view_rms(corners[b:b + 1], use, obj, image_size)[0]))
        return camera_fits[b]

    # 5b. the board's size against the robot's translations (with the fit's rotations): a board given at the wrong
    # size is refused, with the size the robot sees, unless the camera does not fit the images (which biases it: the
    # verdict then names the camera)
    scale_s, scale_se = board_scale(A, M_safe, usable, s.RX, s.RZ)
    for b in range(B):
        ratio, se = float(scale_s[b]), float(scale_se[b])
        if refused[b] or not math.isfinite(ratio) or not abs(ratio - 1.0) > max(SCALE_TOLERANCE, SCALE_SIGMAS * se):
            continue
        if camera_misfits(*camera_fit(b)):
            continue
        issues[b].append({"severity": "error", "check": "board_scale", "poses": usable[b].nonzero().flatten().tolist(),
                          "scale": ratio, "scale_se": se,
                          "message": f"the board's size disagrees with the robot's translations: the robot sees the "
                                     f"board {ratio:.4f} +- {se:.4f} times the size it was given "
                                     f"({100 * (ratio - 1):+.1f} %)"})
        refused[b] = True
    # 6. held-out figures, uncertainty (the leave-one-pose-out refits' spread where there are enough), verdict
    X, Z = _pose(s.RX, s.tX), _pose(s.RZ, s.tZ)
    cov = fit.covariance
    warp = warp_std = None
    if board_warp:  # the sag's coordinates are the global block's last two: its 1-sigma, the rest's covariance
        warp, warp_std = s.warp, cov[:, -2:, -2:].diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
        cov = cov[:, :-2, :-2]
    x_cov, z_cov = cov[:, 0:6, 0:6].clone(), cov[:, 6:12, 6:12].clone()
    source = ["fit"] * B
    P = params.shape[-1]
    intr_std = torch.zeros(B, P, dtype=dtype, device=device)
    if basis is not None:
        pc = basis @ cov[:, GLOBAL_POSE_PARAMS:, GLOBAL_POSE_PARAMS:] @ basis.transpose(-1, -2)
        intr_std = pc.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
    nan = float("nan")
    if heldout:
        held = leave_one_pose_out(problem, s, usable, min_views=MIN_POSES, max_iters=max_iters,
                                  refit=lambda p, st: fitter(p, st, HELDOUT_NOISE_ROUNDS)[0])
        h_px, h_d, h_pred = held.rms_px, held.rms_distance, held.predicted
        jx, n_out = jackknife_covariance(X, held.X)
        jz, _ = jackknife_covariance(Z, held.Z)
        jack = n_out >= JACKKNIFE_MIN_POSES
        x_cov = torch.where(jack[:, None, None], jx, x_cov)
        z_cov = torch.where(jack[:, None, None], jz, z_cov)
        source = ["leave-one-pose-out" if bool(j) else "fit" for j in jack]
        if basis is not None:
            p_out = held.params
            ok = p_out.isfinite().all(-1)
            n = ok.sum(-1).clamp_min(1).to(dtype)
            d = torch.where(ok[..., None], p_out - p_out.nan_to_num(0.0).sum(1, keepdim=True) / n[:, None, None], 0.0)
            jp = ((d * d).sum(1) * ((n - 1) / n)[:, None]).sqrt()
            intr_std = torch.where(jack[:, None], jp, intr_std)
    else:
        h_px = torch.full((B, V), nan, dtype=dtype, device=device)
        h_d = h_px.clone()
        h_pred = torch.full((B, V, N, 2), nan, dtype=dtype, device=device)
    deg = 180.0 / math.pi
    x_std = x_cov.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
    z_std = z_cov.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
    result = HandEyeResult(
        setup=setup, success=torch.tensor([not r for r in refused], device=device),
        reasons=["; ".join(i["message"] for i in iss if i["severity"] == "error") for iss in issues], issues=issues,
        X=X, Z=Z, camera=cameras.with_params(s.params), covariance=cov, x_covariance=x_cov, z_covariance=z_cov,
        std_source=source, x_rotation_std_deg=x_std[:, 0:3] * deg, x_translation_std=x_std[:, 3:6],
        z_rotation_std_deg=z_std[:, 0:3] * deg, z_translation_std=z_std[:, 3:6], intrinsics_std=intr_std, rms=rms, view_rms=view_rms, residuals=residuals,
        used=usable, board_poses=M, start=[start_names[int(k)] for k in best], start_rms=start_rms,
        start_names=start_names, heldout_rms_px=h_px, heldout_rms_distance=h_d, heldout_predicted=h_pred,
        verdict=[], verdict_reasons=[], iterations=fit.iterations, lm_status=fit.status,
        robot_noise=None if problem.noise is None else problem.noise,
        pixel_sigma=None if est is None else est.pixel_sigma,
        corrections=None if problem.noise is None else (s.RE, s.tE),
        board_order=order, corners=torch.where(w[..., None], corners, float("nan")), board_warp=warp,
        board_warp_std=warp_std,
    )
    held_all = result.heldout_rms
    for b in range(B):
        if refused[b]:
            result.verdict.append("refused: " + result.reasons[b])
            result.verdict_reasons.append([result.reasons[b]])
            continue
        # where the held-out poses are predicted less than well, whether the camera explains it (the given camera against one
        # calibrated from the same views; the camera held only)
        given = calibrated = float("nan")
        if b in camera_fits or float(held_all[b]) > HandEyeVerdictThresholds().good_heldout * scale:
            given, calibrated = camera_fit(b)
        v, why = hand_eye_verdict(float(held_all[b]), float(result.X_rotation_std_deg[b]),
                                  float(result.X_translation_std[b]), image_size, metres_per_unit,
                                  camera_fit_px=given, calibrated_fit_px=calibrated, fit_rms_px=float(rms[b]))
        result.verdict.append(v)
        result.verdict_reasons.append(why)
    return result


class HandEyeSolver(nn.Module):
    r"""Module form of :func:`calibrate_hand_eye`, beside :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`
    and :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver`: the set-up and options fixed at construction.

    Where ``corners`` or ``robot_poses`` require grad, the result's ``X``, ``Z`` and ``params`` carry gradients by
    implicit differentiation of the optimum (:mod:`~ccs_kornia.modules.hand_eye.implicit`).

    Args:
        setup: eye-in-hand or eye-to-hand.
        free_intrinsics, robot_noise, heldout, min_corners, max_iters, align_orders, board_flatness: see
            :func:`calibrate_hand_eye`.

    Shape:
        corners :math:`(B, V, N, 2)`, valid :math:`(B, V, N)`, object_points :math:`(N, 3)`, robot_poses
        :math:`(B, V, 4, 4)` -> :class:`~ccs_kornia.modules.hand_eye.result.HandEyeResult`.

    Example:
        >>> from ccs_kornia.data.scenes.robots import render_hand_eye
        >>> from ccs_kornia.geometry.models import K1K2
        >>> s = render_hand_eye("eye_to_hand", views=8, seed=1)
        >>> solver = HandEyeSolver("eye_to_hand")
        >>> cam = Camera.from_opencv(K1K2, s.K, s.dist)
        >>> res = solver(s.corners[None], s.valid[None], s.object_points, s.robot_poses[None], cam)
        >>> res.verdict[0], float((res.X[0, :3, 3] - s.X[:3, 3]).norm()) < 0.005
        ('good', True)
    """

    def __init__(self, setup: HandEyeSetup | str = HandEyeSetup.EYE_IN_HAND, free_intrinsics: bool | Sequence[str] = False,
                 robot_noise: tuple[float, float] | str | None = "auto", heldout: bool = True, min_corners: int = 4,
                 max_iters: int = 100, align_orders: bool = False, board_flatness: bool = False) -> None:
        super().__init__()
        self.setup = HandEyeSetup.parse(setup)
        self.free_intrinsics = free_intrinsics
        self.robot_noise = robot_noise
        self.heldout = heldout
        self.min_corners = min_corners
        self.max_iters = max_iters
        self.align_orders = align_orders
        self.board_flatness = board_flatness

    def forward(self, corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
                robot_poses: torch.Tensor, camera: Camera,
                weights: torch.Tensor | None = None, image_size: tuple[int, int] = (640, 480),
                metres_per_unit: float = 1.0, names: list[list[str]] | None = None) -> HandEyeResult:
        out = calibrate_hand_eye(corners, valid, object_points, robot_poses, camera, self.setup, weights,
                                 self.free_intrinsics, self.robot_noise, self.heldout, image_size, metres_per_unit,
                                 names, self.min_corners, self.max_iters, self.align_orders, self.board_flatness)
        if torch.is_grad_enabled() and (corners.requires_grad or robot_poses.requires_grad):
            from ccs_kornia.modules.hand_eye.implicit import attach_gradients

            out = attach_gradients(out, corners, valid, object_points, robot_poses, weights, self.free_intrinsics,
                                   self.robot_noise)
        return out
