r"""Camera-IMU calibration of one recording: where the IMU sits on each camera and the time offset between them.

:func:`calibrate_imu_camera` (and its module form :class:`ImuCameraSolver`) checks the clocks, finds each frame's board
pose, aligns each camera's angular rates with the gyroscope's (time offset and rotation,
:mod:`~ccs_kornia.modules.imu.initial`), starts the IMU's trajectory from the frames, and fits everything jointly
(:mod:`~ccs_kornia.modules.imu.problem` on the LM core, whose banded elimination keeps a step linear in the recording's
length). The noise: the stated densities (Kalibr's ``imu.yaml``; EuRoC's ADIS16448 where none is given) and the
corners' spread from their board-pose fits start the weights; then each sensor's white noise is rescaled to what its
residuals show (variance components) and the fit is repeated from its optimum, until the two agree, so the 1-sigma hold when the stated values are off, and the result
says how far off they were. The random walks are kept as stated. With ``board_flatness`` the board's sag is fitted too
and kept where frames left out of the fit are predicted better with it
(:mod:`~ccs_kornia.modules.imu.imu_flatness`).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import torch
from torch import nn

from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics, ImuModel
from ccs_kornia.geometry.imu_noise import ImuNoise
from ccs_kornia.modules.calibration.schur_lm import schur_lm
from ccs_kornia.modules.imu.imu_flatness import choose_imu_board_warp
from ccs_kornia.modules.imu.initial import (
    align_rates,
    board_poses,
    clock_offset,
    initial_unknowns,
)
from ccs_kornia.modules.imu.intrinsics_evidence import residual_scale
from ccs_kornia.modules.imu.problem import (
    ITEM,
    ImuCameraData,
    ImuCameraProblem,
    Weights,
)
from ccs_kornia.modules.imu.result import (
    ImuCameraResult,
    ImuVerdictThresholds,
    imu_camera_verdict,
)
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["MAX_ROUNDS", "NOISE_SETTLED", "ImuCameraSolver", "calibrate_imu_camera"]

#: the fits at most (each after a reweighting of the sensors' noise)
MAX_ROUNDS = 4
#: the reweighting ends when every sensor's variance factor is within this of 1 (its sigma within about 5 %)
NOISE_SETTLED = 0.1


def _check_clocks(data: ImuCameraData, max_shift: float) -> None:
    """Refuse, in one line, clocks that cannot be aligned."""
    t = data.imu_times
    if t.shape[0] < 100:
        raise UserError(f"the IMU log has {t.shape[0]} samples: too short to calibrate (a recording of 30-60 s is usual).")
    if bool((t[1:] <= t[:-1]).any()):
        k = int((t[1:] <= t[:-1]).nonzero()[0, 0]) + 1
        raise UserError(f"the IMU's timestamps do not increase at sample {k} ({float(t[k]):.6f} s after "
                        f"{float(t[k - 1]):.6f} s).")
    for c in range(data.num_cameras):
        f = data.frame_times[data.frame_camera == c]
        if f.shape[0] == 0:
            raise NoResult(f"camera {c} has no frame with the board.")
        if bool((f[1:] < f[:-1]).any()):
            raise UserError(f"camera {c}'s frame timestamps go backwards.")
        overlap = min(float(f[-1]), float(t[-1])) - max(float(f[0]), float(t[0]))
        if overlap < 2.0:
            raise UserError(f"camera {c}'s frames ({float(f[0]):.3f} .. {float(f[-1]):.3f} s) and the IMU's samples "
                            f"({float(t[0]):.3f} .. {float(t[-1]):.3f} s) overlap by {max(overlap, 0.0):.2f} s: "
                            "the clocks do not match (timestamps in another unit, or from another origin: "
                            "--align-clocks finds their offset from the motion).")


def _rms(x: torch.Tensor) -> float:
    return float(x.square().mean().sqrt()) if x.numel() else float("nan")


def calibrate_imu_camera(
    data: ImuCameraData,
    noise: ImuNoise | None = None,
    knot_spacing: float = 0.02,
    max_shift: float = 0.2,
    estimate_noise: bool = True,
    max_iters: int = 50,
    thresholds: ImuVerdictThresholds | None = None,
    rolling_shutter: bool = False,
    rig: torch.Tensor | None = None,
    refine_intrinsics: bool = False,
    imu_model: ImuModel = ImuModel.CALIBRATED,
    align_clocks: bool = False,
    board_flatness: bool = False,
) -> ImuCameraResult:
    """Calibrate the IMU against C cameras from one recording (see the module doc).

    Args:
        data: the measurements (:class:`~ccs_kornia.modules.imu.problem.ImuCameraData`; the cameras held).
        noise: the IMU's noise (Kalibr's ``imu.yaml``); ``None``: EuRoC's ADIS16448, then measured.
        knot_spacing: the trajectory spline's knot spacing (s).
        max_shift: the time offset's search half-width (s).
        estimate_noise: rescale each sensor's white noise to its residuals (variance components).
        max_iters: LM iterations per round at most.
        thresholds: the verdict's.
        rolling_shutter: the cameras read their rows one after the other: each camera's row delay is estimated
            (after a first fit with a global shutter, from 0).
        rig: :math:`(C, 4, 4)` the cameras' poses in camera 0's frame (``x_c = T_c0 x_0``, a rig calibration's
            extrinsics), held: camera 0's ``T_cam_imu`` is fitted and the others follow it exactly. ``None``: each
            camera's ``T_cam_imu`` is fitted on its own.
        refine_intrinsics: the cameras' parameters are fitted too (from the given ones; cameras of one model), else
            held.
        imu_model: :attr:`~ccs_kornia.geometry.imu_intrinsics.ImuModel.SCALE_MISALIGNMENT`: the IMU's scale factors,
            misalignment and g-sensitivity fitted too (from an ideal IMU); else the IMU is taken as calibrated.
        align_clocks: the clocks have different origins (a video's from 0, an IMU log's from the epoch): each camera's
            offset is first found from the angular speeds over the whole recordings
            (:func:`~ccs_kornia.modules.imu.initial.clock_offset`), then searched within ``max_shift`` of it.
        board_flatness: also fit the board's sag (mrcal's two coefficients, :mod:`~ccs_kornia.geometry.board_warp`)
            and keep it where frames left out of the fit are predicted better with it
            (:mod:`~ccs_kornia.modules.imu.imu_flatness`): the result's ``board_warp``, ``board_warp_std`` and
            ``board_flatness``.

    Returns:
        :class:`~ccs_kornia.modules.imu.result.ImuCameraResult`.
    """
    start = time.perf_counter()
    C = data.num_cameras
    R_cb, t_cb, ok = board_poses(data)
    clock = torch.zeros(C, dtype=data.gyro.dtype)
    if align_clocks:
        for c in range(C):
            sel = data.frame_camera == c
            try:
                clock[c] = clock_offset(data.frame_times[sel], R_cb[sel], ok[sel], data.imu_times, data.gyro)[0]
            except ValueError as e:
                raise NoResult(f"camera {c}: {e}") from None
        data = replace(data, frame_times=data.frame_times + clock[data.frame_camera])
    _check_clocks(data, max_shift)
    rate = float((data.imu_times.shape[0] - 1) / (data.imu_times[-1] - data.imu_times[0]))
    given = noise is not None
    stated = noise if noise is not None else replace(ImuNoise.euroc(), update_rate=rate)

    alignments = []
    for c in range(C):
        sel = (data.frame_camera == c) & ok
        if int(sel.sum()) < 10:
            raise NoResult(f"camera {c}: the board's pose was found in {int(sel.sum())} frames: too few to calibrate.")
        try:
            al = align_rates(data.frame_times[sel], R_cb[sel], ok[sel], data.imu_times, data.gyro, max_shift=max_shift)
        except ValueError as e:
            raise NoResult(f"camera {c}: {e}") from None
        if al.at_edge:
            raise NoResult(f"camera {c}: the time offset is at the search's edge ({1000 * al.shift:+.0f} ms of "
                           f"+-{1000 * max_shift:.0f} ms): the clocks may differ by more; widen the search "
                           "(--max-shift) or check the timestamps.")
        alignments.append(al)

    # the spline covers the IMU's samples; frames whose time falls outside it (with the offset) are left out
    t0 = float(data.imu_times[0])
    M = math.floor((float(data.imu_times[-1]) - t0) / knot_spacing) + 3
    t_end = t0 + (M - 3) * knot_spacing
    tau = data.frame_times + torch.tensor([a.shift for a in alignments], dtype=data.gyro.dtype)[data.frame_camera]
    margin = 2 * knot_spacing + 0.01
    keep = ok & (tau > t0 + margin) & (tau < t_end - margin)
    fit_data = replace(data, frame_times=data.frame_times[keep], frame_camera=data.frame_camera[keep],
                       corners=data.corners[keep], seen=data.seen[keep])
    frames_used = torch.bincount(fit_data.frame_camera, minlength=C)
    s0 = initial_unknowns(fit_data, t0, knot_spacing, M, R_cb[keep], t_cb[keep], ok[keep], alignments)
    if rig is not None:
        if rig.shape != (C, 4, 4):
            raise ValueError(f"rig: one pose (4, 4) per camera ({C}), got {tuple(rig.shape)}.")
        rig = rig.to(data.gyro.dtype)
        # the held rig's cameras start from camera 0's T_cam_imu
        s0["Rci"] = (rig[:, :3, :3] @ s0["Rci"][0, 0])[None]
        s0["tci"] = ((rig[:, :3, :3] @ s0["tci"][0, 0]) + rig[:, :3, 3])[None]

    # a sample's variance is the density squared times the rate; the corners start at 0.5 px (the rounds rescale both)
    weights = Weights(gyro=1 / (stated.gyroscope_noise_density**2 * rate),
                      accel=1 / (stated.accelerometer_noise_density**2 * rate),
                      pixel=1 / 0.5**2,
                      gyro_walk=1 / (stated.gyroscope_random_walk**2 * knot_spacing),
                      accel_walk=1 / (stated.accelerometer_random_walk**2 * knot_spacing))
    s = s0
    res = None
    iterations = 0
    # a rolling shutter's row delays join from the second fit (the first starts them from a global shutter); with the
    # noise estimated, every fit is followed by a reweighting until the weights agree with the residuals within
    # NOISE_SETTLED (at most MAX_ROUNDS fits)
    for k in range(MAX_ROUNDS):
        shutter = rolling_shutter and k > 0
        problem = ImuCameraProblem(fit_data, t0, knot_spacing, M, weights, rolling_shutter=shutter, rig=rig,
                                   refine_intrinsics=refine_intrinsics, imu_model=imu_model)
        # a cost settled to 8 digits: tighter tolerances move T_cam_imu by nanometres at twice the iterations
        # (docs/imu.md); a warm start (the previous round's optimum, reweighted) needs little damping
        res = schur_lm(problem, s, max_iters=max_iters, ftol=1e-8, absolute_weights=True,
                       lambda_init=1e-3 if k == 0 else 1e-6)
        s = res.unknowns
        iterations += int(res.iterations)
        if not estimate_noise and shutter == rolling_shutter:
            break
        if not estimate_noise:
            continue
        rg, ra, rc = problem.residuals(s)
        n_pts = int(fit_data.seen.sum())
        n_total = float(problem.num_residuals)
        redundancy = (n_total - problem.G - ITEM * M) / n_total
        fg = float(rg.square().mean()) * weights.gyro / redundancy
        fa = float(ra.square().mean()) * weights.accel / redundancy
        fp = float(rc.square().sum()) / (2 * max(n_pts, 1)) * weights.pixel / redundancy
        settled = all(abs(f - 1) <= NOISE_SETTLED for f in (fg, fa, fp))
        if (settled and shutter == rolling_shutter) or k + 1 == MAX_ROUNDS:
            break
        weights = replace(weights, gyro=weights.gyro / fg, accel=weights.accel / fa, pixel=weights.pixel / fp)

    def problem_of(frames: ImuCameraData, board_warp: bool) -> ImuCameraProblem:
        return ImuCameraProblem(frames, t0, knot_spacing, M, weights, rolling_shutter=rolling_shutter, rig=rig,
                                refine_intrinsics=refine_intrinsics, imu_model=imu_model, board_warp=board_warp)

    problem = problem_of(fit_data, False)
    flatness = warp = warp_std = None
    if board_flatness:
        choice = choose_imu_board_warp(problem_of, fit_data, res, max_iters)
        res, problem, s, flatness = choice.fit, choice.problem, choice.fit.unknowns, choice.record
        if choice.kept:
            warp, warp_std = choice.warp.clone(), choice.std.clone()
    rg, ra, rc = problem.residuals(s)
    cov = problem.all_covariance(res.covariance[0])
    sd = cov.diagonal().clamp_min(0).sqrt()
    T = torch.eye(4, dtype=data.gyro.dtype).repeat(C, 1, 1)
    T[:, :3, :3], T[:, :3, 3] = s["Rci"][0], s["tci"][0]
    per_cam = sd[: problem.K * C].view(C, problem.K)
    imu_sd = sd[problem.K * C + 2:problem.K * C + 2 + problem.NI]
    pixel_rms = torch.stack([rc[fit_data.frame_camera == c][fit_data.seen[fit_data.frame_camera == c]].square().mean().sqrt()
                             for c in range(C)])
    measured = replace(stated,
                       gyroscope_noise_density=weights.gyro**-0.5 / math.sqrt(rate),
                       accelerometer_noise_density=weights.accel**-0.5 / math.sqrt(rate), update_rate=rate)
    out = ImuCameraResult(
        T_cam_imu=T, timeshift_cam_imu=s["shift"][0] + clock, rotation_std_deg=per_cam[:, :3] * 180 / math.pi,
        translation_std=per_cam[:, 3:6], timeshift_std=per_cam[:, 6], covariance=cov,
        line_delay=s["delay"][0].clone() if rolling_shutter else None,
        line_delay_std=per_cam[:, 7] if rolling_shutter else None, rig_held=rig is not None,
        cameras=problem.cameras(s), intrinsics_std=per_cam[:, problem.P0:] if refine_intrinsics else None,
        imu_intrinsics=ImuIntrinsics(s["Tg"][0].clone(), s["Ta"][0].clone(), s["Ag"][0].clone())
        if problem.NI else None, imu_intrinsics_std=imu_sd if problem.NI else None, gravity=s["g"][0].clone(),
        gyro_bias=s["bg"][0].clone(), accel_bias=s["ba"][0].clone(), gyro_rms=_rms(rg), accel_rms=_rms(ra),
        pixel_rms=pixel_rms, noise_stated=stated, noise_measured=measured, pixel_sigma=weights.pixel**-0.5,
        noise_given=given, alignment_shifts=alignments[0].shifts,
        alignment_correlation=torch.stack([a.correlation for a in alignments]),
        alignment_shift=torch.tensor([a.shift for a in alignments], dtype=data.gyro.dtype) + clock,
        max_shift=max_shift, clock_offset=clock if align_clocks else None,
        frames_used=frames_used, knot_spacing=knot_spacing, iterations=iterations, status=int(res.status[0]),
        board_warp=warp, board_warp_std=warp_std, board_flatness=flatness, seconds=time.perf_counter() - start,
        spline={"t0": t0, "dt": knot_spacing, "R": s["R"][0].clone(), "p": s["p"][0].clone()},
        residuals={"imu_times": fit_data.imu_times, "gyro": rg, "accel": ra, "frame_times": fit_data.frame_times,
                   "frame_camera": fit_data.frame_camera, "corners": rc, "seen": fit_data.seen})
    if imu_model is ImuModel.CALIBRATED:
        out.residual_scale = {"gyroscope": residual_scale(fit_data.gyro, rg),
                              "accelerometer": residual_scale(fit_data.accel, ra)}
    out.verdict, out.verdict_reasons = imu_camera_verdict(out, thresholds)
    return out


class ImuCameraSolver(nn.Module):
    r"""Module form of :func:`calibrate_imu_camera`, beside :class:`~ccs_kornia.modules.hand_eye.solver.HandEyeSolver`:
    the options fixed at construction.

    Args:
        noise, knot_spacing, max_shift, estimate_noise, max_iters, rolling_shutter: see :func:`calibrate_imu_camera`.
        rig: see :func:`calibrate_imu_camera` (held extrinsics of a rig, :math:`(C, 4, 4)`); a buffer.
        refine_intrinsics, imu_model, align_clocks, board_flatness: see :func:`calibrate_imu_camera`.

    Shape:
        :class:`~ccs_kornia.modules.imu.problem.ImuCameraData` (IMU :math:`(N, 3)` rates and accelerations, frames
        :math:`(F, P, 2)`) -> :class:`~ccs_kornia.modules.imu.result.ImuCameraResult` (``T_cam_imu`` :math:`(C, 4, 4)`).

    Example:
        >>> from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
        >>> r = visual_inertial_recording(duration=8.0, seed=3)
        >>> data = ImuCameraData.from_corners(r.imu_times, r.gyro, r.accel, r.cameras, r.object_points,
        ...                                   r.frame_times, r.corners)
        >>> res = ImuCameraSolver()(data)
        >>> float((res.T_cam_imu[0, :3, 3] - r.T_cam_imu[0, :3, 3]).norm()) < 0.005
        True
        >>> abs(float(res.timeshift_cam_imu[0] - r.shift[0])) < 1e-4
        True
    """

    def __init__(self, noise: ImuNoise | None = None, knot_spacing: float = 0.02, max_shift: float = 0.2,
                 estimate_noise: bool = True, max_iters: int = 50, rolling_shutter: bool = False,
                 rig: torch.Tensor | None = None, refine_intrinsics: bool = False,
                 imu_model: ImuModel = ImuModel.CALIBRATED, align_clocks: bool = False,
                 board_flatness: bool = False) -> None:
        super().__init__()
        self.board_flatness = board_flatness
        self.align_clocks = align_clocks
        self.imu_model = imu_model
        self.refine_intrinsics = refine_intrinsics
        self.register_buffer("rig", rig)
        self.rolling_shutter = rolling_shutter
        self.noise = noise
        self.knot_spacing = knot_spacing
        self.max_shift = max_shift
        self.estimate_noise = estimate_noise
        self.max_iters = max_iters

    def forward(self, data: ImuCameraData) -> ImuCameraResult:
        return calibrate_imu_camera(data, self.noise, self.knot_spacing, self.max_shift, self.estimate_noise,
                                    self.max_iters, rolling_shutter=self.rolling_shutter, rig=self.rig,
                                    refine_intrinsics=self.refine_intrinsics, imu_model=self.imu_model,
                                    align_clocks=self.align_clocks, board_flatness=self.board_flatness)
