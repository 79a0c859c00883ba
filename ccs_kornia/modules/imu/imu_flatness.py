r"""Whether the board's sag is worth keeping in a camera-IMU fit: the held-out frames' error with and without it.

The sag (:mod:`~ccs_kornia.geometry.board_warp`, two globals of
:class:`~ccs_kornia.modules.imu.problem.ImuCameraProblem` with ``board_warp``) is fitted with everything else, from the
flat board's optimum. Where the frames determine it (its larger coefficient ``min_sigmas`` standard deviations from 0,
:func:`~ccs_kornia.modules.calibration.board_flatness.board_warp_determined`), the recording is fitted again without
every other frame of each camera (the second of :func:`~ccs_kornia.modules.calibration.board_flatness.split_halves`),
once with a flat board and once with the sag, and the frames left out are predicted: their board pose from the fitted
trajectory at their time (the IMU carries the motion between the frames kept, one frame interval), through
``T_cam_imu``, the time offset and the board as the fit found it. The median of their corners' reprojection errors is
the held-out figure, and the sag is kept by the rule of every fit that observes a board
(:func:`~ccs_kornia.modules.calibration.board_flatness.keep_board_warp`).

Alternate frames rather than blocks of time: a held-out frame sits one frame interval from fitted ones on both sides, so
its predicted pose is as good as the trajectory between frames, and what separates the two boards is their shape; a
block of several seconds would be predicted from the IMU alone, whose drift over the block would swamp a bend of a
millimetre.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch

from ccs_kornia.geometry.board_warp import board_warp_basis
from ccs_kornia.modules.calibration.board_flatness import (
    board_warp_determined,
    board_warp_record,
    keep_board_warp,
    split_halves,
)
from ccs_kornia.modules.calibration.schur_lm import SchurLMResult, schur_lm
from ccs_kornia.modules.imu.problem import ImuCameraData, ImuCameraProblem

__all__ = ["ImuBoardWarpChoice", "choose_imu_board_warp", "heldout_frames", "heldout_median", "select_frames"]

#: how the fits of the judgement stop: as the solver's (a cost settled to 8 digits, from a warm start)
_FTOL, _LAMBDA = 1e-8, 1e-6


@dataclass
class ImuBoardWarpChoice:
    """What :func:`choose_imu_board_warp` found.

    Attributes:
        kept: the sag is kept.
        fit: the fit to use: the sag's where kept, the flat board's otherwise.
        problem: its problem.
        warp: :math:`(2,)` the sag fitted on every frame (mrcal's ``calobject_warp``, the board's units), kept or not.
        std: :math:`(2,)` its 1-sigma.
        record: the ``board_flatness`` block
            (:func:`~ccs_kornia.modules.calibration.board_flatness.board_warp_record`, ``heldout_median_px``).
    """

    kept: bool
    fit: SchurLMResult
    problem: ImuCameraProblem
    warp: torch.Tensor
    std: torch.Tensor
    record: dict


def heldout_frames(data: ImuCameraData) -> torch.Tensor:
    """:math:`(F,)` bool: every other frame of each camera, in time (the second of
    :func:`~ccs_kornia.modules.calibration.board_flatness.split_halves`).

    Example:
        >>> from types import SimpleNamespace
        >>> d = SimpleNamespace(frame_camera=torch.tensor([0, 0, 0, 1, 1, 1, 1]), num_cameras=2)
        >>> heldout_frames(d).long().tolist()
        [0, 1, 0, 0, 1, 0, 1]
    """
    C = data.num_cameras
    used = data.frame_camera[None] == torch.arange(C, device=data.frame_camera.device)[:, None]
    return split_halves(used)[1].any(0)


def select_frames(data: ImuCameraData, keep: torch.Tensor) -> ImuCameraData:
    """The measurements with the frames ``keep`` :math:`(F,)` only (the IMU's samples all).

    Example:
        >>> from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
        >>> r = visual_inertial_recording(duration=2.0, seed=0)
        >>> d = ImuCameraData.from_corners(r.imu_times, r.gyro, r.accel, r.cameras, r.object_points, r.frame_times,
        ...                                r.corners)
        >>> held = heldout_frames(d)
        >>> select_frames(d, ~held).corners.shape[0] + select_frames(d, held).corners.shape[0] == d.corners.shape[0]
        True
    """
    return replace(data, frame_times=data.frame_times[keep], frame_camera=data.frame_camera[keep],
                   corners=data.corners[keep], seen=data.seen[keep])


def heldout_median(problem_of: Callable[[ImuCameraData, bool], ImuCameraProblem], data: ImuCameraData,
                   held: torch.Tensor, start: dict[str, torch.Tensor], board_warp: bool,
                   max_iters: int = 50) -> float:
    """The median reprojection error (px) of the frames ``held`` :math:`(F,)` predicted by a fit of the others (from
    ``start``), with a flat board or its sag (``board_warp``); ``problem_of(data, board_warp)`` makes the problem."""
    fit = schur_lm(problem_of(select_frames(data, ~held), board_warp), start, max_iters=max_iters, ftol=_FTOL,
                   absolute_weights=True, lambda_init=_LAMBDA)
    other = select_frames(data, held)
    rc = problem_of(other, board_warp).residuals(fit.unknowns)[2]
    err = rc.norm(dim=-1)[other.seen]
    return float(err.median()) if err.numel() else math.nan


def choose_imu_board_warp(problem_of: Callable[[ImuCameraData, bool], ImuCameraProblem], data: ImuCameraData,
                          flat: SchurLMResult, max_iters: int = 50, margin: float = 0.05,
                          min_sigmas: float = 3.0) -> ImuBoardWarpChoice:
    r"""The board's sag fitted beside the flat-board fit ``flat`` of ``data``, kept where the held-out frames say it
    helps (module doc).

    Args:
        problem_of: ``problem_of(data, board_warp)``: the fit's problem (its weights, knots and options) of some
            frames, with a flat board or the sag.
        data: the frames fitted.
        flat: the flat board's fit (:func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm` of
            ``problem_of(data, False)``).
        max_iters: LM iterations per fit at most.
        margin, min_sigmas: :func:`~ccs_kornia.modules.calibration.board_flatness.keep_board_warp`'s.

    Returns:
        :class:`ImuBoardWarpChoice`.
    """
    obj = data.object_points
    bent_problem = problem_of(data, True)
    bent = schur_lm(bent_problem, flat.unknowns, max_iters=max_iters, ftol=_FTOL, absolute_weights=True,
                    lambda_init=_LAMBDA)
    warp = bent.unknowns["warp"][0]
    std = bent.covariance[0, -2:, -2:].diagonal().clamp_min(0).sqrt()
    ok = bool(warp.isfinite().all() and std.isfinite().all() and bent.cost.isfinite().all())
    held_flat = held_warp = math.nan
    kept = False
    # a board whose points are all on its edge (a single tag) shows no sag; one the frames do not determine is not
    # kept, without the held-out fits
    if ok and bool(board_warp_basis(obj).abs().amax() > 0) and bool(board_warp_determined(warp, std, obj, min_sigmas)):
        held = heldout_frames(data)
        held_flat = heldout_median(problem_of, data, held, flat.unknowns, False, max_iters)
        held_warp = heldout_median(problem_of, data, held, bent.unknowns, True, max_iters)
        kept = bool(keep_board_warp(warp, std, obj, torch.tensor(held_flat), torch.tensor(held_warp), margin,
                                    min_sigmas))
    record = board_warp_record(kept, warp, std, held_flat, held_warp)
    return ImuBoardWarpChoice(kept, bent if kept else flat, bent_problem if kept else problem_of(data, False), warp,
                              std, record)
