"""Frame consistency of a rig: the kernels, the per-frame disagreement, the board's motion, and the solver's frame
weighting (frames whose board moved between the cameras' exposures found, named and down-weighted)."""

from __future__ import annotations

import math

import pytest
import torch
from _cameras import cameras

from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.rig import RigSolver
from ccs_kornia.modules.rig.frame_consistency import (
    BOARD_MOVING,
    NOT_MOTION,
    FrameKernel,
    board_motion,
    disagreement_cause,
    frame_disagreement,
    own_view_errors,
)
from ccs_kornia.modules.rig.rig_state import RigObservations, RigState

D = torch.float64
K = torch.tensor([[600.0, 0, 330], [0, 605, 245], [0, 0, 1]], dtype=D)
R_RIG = exp_so3(torch.tensor([[0.0, 0, 0], [0.01, -0.12, 0.0], [-0.02, 0.1, 0.01]], dtype=D))
T_RIG = torch.tensor([[0.0, 0, 0], [-0.2, 0.01, 0.0], [0.2, 0.0, 0.01]], dtype=D)


def rig(C=2, frames=14, seed=3, noise=0.1, **kw):
    cams = [(K1K2, K, torch.tensor([-0.12, 0.03], dtype=D))] * C
    return render_rig(cameras(cams, [(640, 480)] * C), R_RIG[:C], T_RIG[:C], num_frames=frames, seed=seed, noise_px=noise,
                      **kw)


def moved(s, frames, shift):
    """Camera 1's corners of ``frames`` as if the board had moved ``shift`` (board units) along x before its
    exposure."""
    C = s.corners.shape[0]
    s2 = render_rig(cameras([(K1K2, K, torch.tensor([-0.12, 0.03], dtype=D))] * C, s.image_sizes), R_RIG[:C],
                    T_RIG[:C] - torch.tensor([shift, 0, 0], dtype=D), num_frames=s.corners.shape[1], seed=3,
                    noise_px=0.1)
    corners = s.corners.clone()
    for f in frames:
        corners[1, f] = s2.corners[1, f]
    return corners


@pytest.mark.parametrize("kernel", list(FrameKernel))
def test_kernels(kernel, device, dtype):
    d = torch.tensor([0.0, 0.5, 1.0, 2.0, 10.0, float("nan")], device=device, dtype=dtype)
    w = kernel.weights(d, 1.0)
    assert w.shape == d.shape and w.dtype == dtype and w.device.type == device.type
    assert bool(((w >= 0) & (w <= 1)).all()) and float(w[0]) == 1.0 and float(w[-1]) == 1.0  # NaN: one camera
    assert bool((w[:-1][1:] <= w[:-1][:-1]).all())  # never more weight for a larger disagreement
    assert kernel.reweights == (kernel is not FrameKernel.NONE)
    if kernel is FrameKernel.CAUCHY:
        assert torch.allclose(w[:5], 1.0 / (1.0 + d[:5] ** 2))
    if kernel is FrameKernel.DROP:
        assert w[:5].tolist() == [1.0, 1.0, 1.0, 1.0, 0.0]


def test_kernel_names():
    assert FrameKernel("cauchy") is FrameKernel.CAUCHY and FrameKernel("none") is FrameKernel.NONE
    with pytest.raises(ValueError):
        FrameKernel("tukey")


def test_disagreement_exact_rig_is_zero():
    s = rig(noise=0.0)
    models = [K1K2] * 2
    params = [models[0].params_from(K[None], torch.tensor([[-0.12, 0.03]], dtype=D))] * 2
    used = s.valid.sum(-1)[None] >= 6
    w = (s.valid & used[0, ..., None]).to(D)[None]
    state = RigState(models, params, s.R[None], s.T[None], exp_so3(s.board_rvec)[None], s.board_tvec[None])
    own = own_view_errors(state, RigObservations(s.object_points, s.corners[None], w))
    assert own.shape == (1, 2, s.corners.shape[1]) and float(own.max()) < 1e-12


def test_disagreement_shapes_and_nan():
    sq = torch.rand(2, 3, 5, dtype=D)
    used = torch.ones(2, 3, 5, dtype=torch.bool)
    used[:, 1:, 0] = False  # frame 0: one camera only
    cam, frame = frame_disagreement(sq + 1.0, sq, torch.full((2, 3, 5), 4), used)
    assert cam.shape == (2, 3, 5) and frame.shape == (2, 5)
    assert bool(frame[:, 0].isnan().all()) and torch.allclose(frame[:, 1:], torch.full((2, 4), 0.5, dtype=D))
    assert bool(cam[:, 1:, 0].isnan().all())
    cam, frame = frame_disagreement(sq, sq + 1.0, torch.full((2, 3, 5), 4), used)  # never negative
    assert float(frame.nan_to_num(0.0).max()) == 0.0


def test_board_motion():
    s = rig(noise=0.0)
    models = [K1K2] * 2
    params = [models[0].params_from(K[None], torch.tensor([[-0.12, 0.03]], dtype=D))] * 2
    F = s.corners.shape[1]
    used = (s.valid.sum(-1) >= 6)[None]
    state = RigState(models, params, s.R[None], s.T[None], exp_so3(s.board_rvec)[None], s.board_tvec[None])
    times = torch.arange(F, dtype=D)
    motion = board_motion(state, s.object_points, used, times)
    assert motion.shape == (1, F) and bool(motion[0, used[0].any(0)].isfinite().all())
    assert float(motion.nan_to_num(float("inf")).min()) > 1.0  # independent rendered poses: the board jumps
    slow = board_motion(state, s.object_points, used, 2 * times)
    assert torch.allclose(slow, motion, equal_nan=True)  # per frame period: the unit of time does not matter
    none = board_motion(state, s.object_points, used, torch.full((F,), float("nan"), dtype=D))
    assert bool(none.isnan().all())


def test_disagreement_cause():
    assert disagreement_cause(2.0, 10.0) == BOARD_MOVING
    assert disagreement_cause(2.0, 1.0) == NOT_MOTION
    assert disagreement_cause(float("nan"), 1.0) == "" and disagreement_cause(2.0, float("nan")) == ""


def test_solver_finds_and_downweights_moving_frames():
    s = rig(frames=16)
    bad = [3, 7, 12]
    corners = moved(s, bad, 0.006)
    res = RigSolver(K1K2, folds=0)(corners, s.valid, s.object_points, s.image_sizes)
    assert res.frame_disagreement.shape == (16,) and res.frame_weight.shape == (16,)
    low = sorted(torch.nonzero(res.frame_weight < 0.5).flatten().tolist())
    assert low == bad, (low, res.frame_disagreement)
    assert float(res.frame_disagreement[bad].min()) > 3 * float(res.frame_disagreement[[f for f in range(16)
                                                                                        if f not in bad]].max())
    assert math.isfinite(res.frame_scale) and res.frame_scale > 0
    assert res.shared_frames.shape == (2, 2) and float(res.shared_frames[0, 1]) < 16 - 2


def test_frame_weighting_recovers_the_extrinsics():
    s = rig(frames=16)
    corners = moved(s, [3, 7, 12], 0.006)
    plain = RigSolver(K1K2, folds=0, frame_kernel="none")(corners, s.valid, s.object_points, s.image_sizes)
    weighted = RigSolver(K1K2, folds=0)(corners, s.valid, s.object_points, s.image_sizes)
    err = [float((r.T[1] - s.T[1]).norm()) for r in (plain, weighted)]
    rot = [float(log_so3(r.R[1] @ s.R[1].T).norm()) for r in (plain, weighted)]
    assert err[1] < 0.5 * err[0] and rot[1] <= rot[0]
    assert bool((plain.frame_weight.nan_to_num(1.0) == 1.0).all())  # no reweighting: every frame counts fully


def test_frame_times_give_motion_and_are_checked():
    s = rig(frames=10)
    res = RigSolver(K1K2, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes,
                                     frame_times=torch.arange(10, dtype=D))
    assert res.frame_motion.shape == (10,) and bool(res.frame_motion.isfinite().any())
    nothing = RigSolver(K1K2, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert bool(nothing.frame_motion.isnan().all())
    with pytest.raises(ValueError, match="frame_times"):
        RigSolver(K1K2, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes, frame_times=torch.zeros(3))


def test_frame_weighting_batch_equals_one_by_one():
    s = rig(frames=12)
    a, b = moved(s, [2, 6], 0.006), s.corners
    solver = RigSolver(K1K2, folds=0)
    batch = solver(torch.stack([a, b]), torch.stack([s.valid, s.valid]), s.object_points, s.image_sizes)
    for k, corners in enumerate((a, b)):
        one = solver(corners, s.valid, s.object_points, s.image_sizes)
        assert torch.allclose(batch[k].frame_weight, one.frame_weight, atol=1e-9, equal_nan=True)
        assert torch.allclose(batch[k].T, one.T, atol=1e-10)
