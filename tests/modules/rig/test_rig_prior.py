"""The intrinsics prior of the rig's joint fit: the LM core's prior block, the solver's prior from each camera's own
views, how far the intrinsics moved in single-camera sigmas."""

from __future__ import annotations

import pytest
import torch
from _cameras import cameras

from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.geometry.models import K1K2, PINHOLE
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.rig import RigSolver
from ccs_kornia.modules.rig.rig_lm import rig_layout, rig_levenberg_marquardt
from ccs_kornia.modules.rig.rig_state import RigObservations, RigState

D = torch.float64
K = torch.tensor([[600.0, 0, 330], [0, 605, 245], [0, 0, 1]], dtype=D)


def two_camera_problem(device, B=1, frames=6, seed=0):
    """A noise-free stereo problem for rig_levenberg_marquardt: the start and the observations."""
    g = torch.Generator().manual_seed(seed)
    obj = board_object_points(6, 5, 0.05, dtype=D)
    rv = 0.4 * (torch.rand(frames, 3, generator=g, dtype=D) - 0.5)
    tv = torch.tensor([-0.12, -0.1, 0.9], dtype=D).expand(frames, 3)
    Tc = torch.tensor([-0.15, 0.0, 0.01], dtype=D)
    x0 = project_points(obj.expand(frames, -1, -1), K.expand(frames, 3, 3), None, rv, tv)
    x1 = project_points(obj.expand(frames, -1, -1), K.expand(frames, 3, 3), None, rv, tv + Tc)
    corners = torch.stack([x0, x1])[None].expand(B, -1, -1, -1, -1).to(device)
    R = torch.eye(3, dtype=D).expand(B, 2, 3, 3).to(device)
    T = torch.stack([torch.zeros(3, dtype=D), Tc + 0.01]).expand(B, 2, 3).to(device)
    start = torch.tensor([[610.0, 598.0, 325.0, 250.0]], dtype=D).expand(B, 4).to(device)
    models = [PINHOLE] * 2
    rig = RigState(models, [start, start], R, T, exp_so3(rv)[None].expand(B, -1, -1, -1).to(device),
                   tv[None].expand(B, -1, -1).to(device))
    return rig, RigObservations(obj.to(device), corners, torch.ones(B, 2, frames, 30, dtype=D, device=device))


def test_prior_smoke_and_shapes(device):
    rig, obs = two_camera_problem(device)
    info = torch.eye(4, dtype=D, device=device)[None]
    res = rig_levenberg_marquardt(rig, obs, prior=[(rig.params[0], info), None])
    assert res.prior_cost is not None and res.prior_cost.shape == (1,)
    assert int(res.status) == LMStatus.CONVERGED and float(res.prior_cost) >= 0.0
    assert res.covariance.shape == (1, rig_layout(rig.models)[2], rig_layout(rig.models)[2])


def test_no_prior_has_no_prior_cost(device):
    rig, obs = two_camera_problem(device)
    res = rig_levenberg_marquardt(rig, obs)
    assert res.prior_cost is None


def test_zero_information_is_no_prior(device):
    rig, obs = two_camera_problem(device)
    zero = torch.zeros(1, 4, 4, dtype=D, device=device)
    a = rig_levenberg_marquardt(rig, obs)
    b = rig_levenberg_marquardt(rig, obs, prior=[(rig.params[0], zero), (rig.params[1], zero)])
    assert torch.allclose(a.state.params[0], b.state.params[0], atol=1e-9)
    assert torch.allclose(a.state.T, b.state.T, atol=1e-12)
    assert float(b.prior_cost) == 0.0


def test_strong_prior_holds_the_intrinsics(device):
    rig, obs = two_camera_problem(device)
    free = rig_levenberg_marquardt(rig, obs)
    assert torch.allclose(free.state.params[0][0], K.to(device)[[0, 1, 0, 1], [0, 1, 2, 2]], atol=1e-6)  # the truth
    strong = 1e12 * torch.eye(4, dtype=D, device=device)[None]
    held = rig_levenberg_marquardt(rig, obs, prior=[(rig.params[0], strong), None])
    assert torch.allclose(held.state.params[0], rig.params[0], atol=1e-3)  # camera 0 kept at its prior's centre
    assert float((held.state.params[1] - rig.params[1]).abs().max()) > 1.0  # camera 1, without a prior, still moved
    # a weak prior lies between: it pulls toward its centre, less than the strong one
    weak = rig_levenberg_marquardt(rig, obs,
                                   prior=[(rig.params[0], 1e-2 * torch.eye(4, dtype=D, device=device)[None]), None])
    d_free = (free.state.params[0] - rig.params[0]).norm()
    d_weak = (weak.state.params[0] - rig.params[0]).norm()
    assert float(d_weak) < float(d_free) and float(d_weak) > float((held.state.params[0] - rig.params[0]).norm())


def test_prior_batch_equals_one_by_one():
    rig, obs = two_camera_problem("cpu", B=2)
    info = torch.stack([torch.eye(4, dtype=D), 10.0 * torch.eye(4, dtype=D)])
    batch = rig_levenberg_marquardt(rig, obs, prior=[(rig.params[0], info), None])
    for b in range(2):
        one = rig_levenberg_marquardt(rig.rig(b), RigObservations(obs.object_points, obs.corners[b : b + 1],
                                                                  obs.weights[b : b + 1]),
                                      prior=[(rig.params[0][b : b + 1], info[b : b + 1]), None])
        assert torch.allclose(batch.state.params[0][b], one.state.params[0][0], atol=1e-8)
        assert torch.allclose(batch.prior_cost[b], one.prior_cost[0], rtol=1e-6, atol=1e-12)


def test_prior_exceptions():
    rig, obs = two_camera_problem("cpu")
    with pytest.raises(ValueError, match="one entry"):
        rig_levenberg_marquardt(rig, obs, prior=[None])
    with pytest.raises(ValueError, match="prior of camera 0"):
        rig_levenberg_marquardt(rig, obs, prior=[(rig.params[0], torch.eye(3, dtype=D)[None]), None])
    with pytest.raises(ValueError, match="intrinsics_prior"):
        RigSolver(K1K2, intrinsics_prior=0.0)


def moving_rig(seed=3, frames=14, moved=(2, 5, 8, 11), shift=0.004):
    """Two k1k2 cameras; in ``moved`` frames camera 1 saw the board ``shift`` (board units) further along x: a board
    that moved between the two cameras' exposures."""
    cams = [(K1K2, K, torch.tensor([-0.12, 0.03], dtype=D))] * 2
    R = exp_so3(torch.tensor([[0.0, 0, 0], [0.01, -0.12, 0.0]], dtype=D))
    T = torch.tensor([[0.0, 0, 0], [-0.2, 0.01, 0.0]], dtype=D)
    s = render_rig(cameras(cams, [(640, 480)] * 2), R, T, num_frames=frames, seed=seed, noise_px=0.1)
    s2 = render_rig(cameras(cams, [(640, 480)] * 2), R, T - torch.tensor([[shift, 0, 0]], dtype=D), num_frames=frames,
                    seed=seed, noise_px=0.1)
    corners = s.corners.clone()
    for f in moved:
        corners[1, f] = s2.corners[1, f]
    return s, corners


def test_solver_reports_moves_in_single_camera_sigmas():
    s, corners = moving_rig()
    res = RigSolver(K1K2, folds=0)(corners, s.valid, s.object_points, s.image_sizes)
    assert res.success
    assert len(res.single_cameras) == 2 and len(res.single_std) == 2 and len(res.intrinsics_moved_sigma) == 2
    for c in range(2):
        assert res.single_std[c].shape == (6,) and bool((res.single_std[c] > 0).all())
        moved = res.cameras.params[c, :4] - res.single_cameras.params[c, :4]
        assert torch.allclose(res.intrinsics_moved_sigma[c][:4], moved / res.single_std[c][:4], atol=1e-9)
    assert res.prior_weight.shape == (2,) and bool((res.prior_weight > 0.0).all())  # the moved frames: held


def test_prior_keeps_intrinsics_nearer_their_own_calibration():
    s, corners = moving_rig()
    free = RigSolver(K1K2, folds=0, intrinsics_prior=None, frame_kernel="none")(corners, s.valid, s.object_points,
                                                                                  s.image_sizes)
    held = RigSolver(K1K2, folds=0, frame_kernel="none")(corners, s.valid, s.object_points, s.image_sizes)
    for c in range(2):
        assert float(held.intrinsics_moved_sigma[c].abs().max()) <= float(free.intrinsics_moved_sigma[c].abs().max())
    fixed = RigSolver(K1K2, folds=0)(corners, s.valid, s.object_points, s.image_sizes, initial=held.single_cameras,
                                       fixed=[True, False])
    assert float(fixed.intrinsics_moved_sigma[0].abs().max()) == 0.0 and float(fixed.prior_weight[0]) == 0.0
