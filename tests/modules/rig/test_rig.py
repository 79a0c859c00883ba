"""Rig solver: shapes, batching, mixed models, partial boards, recovery, exceptions, OpenCV cross-checks."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch
from _cameras import cameras

from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, PINHOLE
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.rig import RigSolver, calibrate_rig, stereo_rectify

D = torch.float64
K_WIDE = torch.tensor([[600.0, 0, 330], [0, 605, 245], [0, 0, 1]], dtype=D)
K_FISH = torch.tensor([[300.0, 0, 318], [0, 301, 242], [0, 0, 1]], dtype=D)
CAMERAS = [
    (OPENCV5, K_WIDE, torch.tensor([-0.2, 0.08, 0.001, -0.001, 0.0], dtype=D)),
    (FISHEYE, K_FISH, torch.tensor([0.02, -0.01, 0.003, 0.0], dtype=D)),
    (K1K2, K_WIDE, torch.tensor([-0.1, 0.02], dtype=D)),
    (FISHEYE, K_FISH, torch.tensor([0.01, 0.0, 0.0, 0.0], dtype=D)),
]
ROT = torch.tensor([[0, 0, 0], [0.02, -0.15, 0.01], [-0.03, 0.2, 0.02], [0.1, 0.05, -0.05]], dtype=D)
TRANS = torch.tensor([[0, 0, 0], [-0.2, 0.01, 0.0], [0.2, 0.0, 0.02], [0.0, -0.15, 0.01]], dtype=D)
SIZE = (640, 480)


def scene(C=2, models=None, frames=10, seed=0, noise=0.0, drop=0.0, **kw):
    cams = CAMERAS[:C] if models is None else [(m, K_WIDE, None if m == PINHOLE else torch.tensor([-0.1, 0.02], dtype=D))
                                                for m in models]
    return render_rig(cameras(cams, [SIZE] * C), exp_so3(ROT[:C]), TRANS[:C], num_frames=frames, seed=seed, noise_px=noise,
                      drop=drop, **kw)


def rot_err_deg(Ra, Rb):
    return float(log_so3(Ra @ Rb.T).norm()) * 180 / math.pi


def test_smoke():
    s = scene(2, models=[K1K2, K1K2])
    res = RigSolver(K1K2)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.success and res.reason == ""
    assert res.verdict == "good", res.reasons
    assert res.lm_status == LMStatus.CONVERGED and res.converged
    assert res.names == ["cam0", "cam1"]
    assert rot_err_deg(res.R[1], s.R[1]) < 1e-6
    assert float((res.T - s.T).abs().max()) < 1e-8


def test_shapes():
    C, F = 3, 8
    s = scene(C, frames=F, seed=1)
    N = s.object_points.shape[0]
    res = calibrate_rig(s.corners, s.valid, s.object_points, s.image_sizes, models=list(s.cameras.models),
                        names=["a", "b", "c"])
    assert res.R.shape == (C, 3, 3) and res.T.shape == (C, 3)
    assert res.board_rvec.shape == (F, 3) and res.board_tvec.shape == (F, 3)
    assert res.used.shape == (C, F) and res.used.dtype == torch.bool
    assert res.rms_matrix.shape == (C, F) and res.camera_rms.shape == (C,)
    assert res.baseline_std.shape == (C,) and res.rotation_std_deg.shape == (C,)
    assert res.epipolar_rms.shape == (C, C) and res.heldout_epipolar_rms.shape == (C, C)
    assert torch.equal(res.epipolar_rms, res.epipolar_rms.T)
    assert list(res.cameras.models) == [OPENCV5, FISHEYE, K1K2]
    assert [res.cameras.coeffs(c).shape[0] for c in range(3)] == [5, 4, 5]
    assert [t.shape[0] for t in res.intrinsics_std] == [9, 8, 6]
    assert res.names == ["a", "b", "c"] and res.image_sizes == [SIZE] * C
    assert float(res.baseline_std[0]) == 0.0 and float(res.rotation_std_deg[0]) == 0.0
    assert torch.equal(res.R[0], torch.eye(3, dtype=D)) and torch.equal(res.T[0], torch.zeros(3, dtype=D))
    assert isinstance(res.rms, float) and N == 35


def test_batch_equals_one_by_one():
    scenes = [scene(2, seed=s, noise=0.2) for s in (3, 4)]
    corners = torch.stack([s.corners for s in scenes])
    valid = torch.stack([s.valid for s in scenes])
    solver = RigSolver([OPENCV5, FISHEYE])
    batch = solver(corners, valid, scenes[0].object_points, scenes[0].image_sizes)
    assert isinstance(batch, list) and len(batch) == 2
    for b, s in enumerate(scenes):
        one = solver(s.corners, s.valid, s.object_points, s.image_sizes)
        assert torch.allclose(batch[b].R, one.R, atol=1e-9) and torch.allclose(batch[b].T, one.T, atol=1e-10)
        for cb, co in zip(batch[b].cameras, one.cameras):
            assert torch.allclose(cb.K, co.K, atol=1e-6) and torch.allclose(cb.dist, co.dist, atol=1e-8)
        assert torch.allclose(batch[b].heldout_epipolar_rms, one.heldout_epipolar_rms, atol=1e-6, equal_nan=True)


@pytest.mark.parametrize("C", [2, 3, 4])
def test_mixed_models_partial_boards_missing_frames_exact(C):
    s = scene(C, frames=16, seed=10 + C, drop=0.15)
    assert not bool(s.valid.all())  # partial boards and dropped frames
    assert bool(((s.valid.sum(-1) > 0) & ~s.valid.all(-1)).any())
    res = RigSolver(list(s.cameras.models), folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.success, res.reason
    for c in range(C):
        assert rot_err_deg(res.R[c], s.R[c]) < 1e-6
        assert float((res.T[c] - s.T[c]).norm()) < 1e-8
        assert float((res.cameras[c].K - s.cameras.K[c]).abs().max()) < 1e-5
    assert res.rms < 1e-6
    frames = res.used.any(0)
    assert bool(res.board_rvec[frames].isfinite().all()) and bool(res.board_rvec[~frames].isnan().all())


def test_noisy_recovery():
    C = 4
    s = scene(C, frames=20, seed=21, noise=0.2, drop=0.1)
    res = RigSolver(list(s.cameras.models))(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.success, res.reason
    for c in range(1, C):
        baseline = float(s.T[c].norm())
        err_t = float((res.T[c] - s.T[c]).norm())
        assert err_t / baseline < 0.01
        assert rot_err_deg(res.R[c], s.R[c]) < 0.5
        # the reported uncertainty covers the error (5 sigma)
        assert rot_err_deg(res.R[c], s.R[c]) < 5 * float(res.rotation_std_deg[c]) + 1e-3
        assert abs(float(res.T[c].norm()) - baseline) < 5 * float(res.baseline_std[c]) + 1e-5
    for c in range(C):
        assert float((res.cameras[c].K - s.cameras.K[c]).abs().max()) < 5.0
    assert 0.22 < res.rms < 0.3  # sqrt(2) * 0.2 px per corner, less the fitted degrees of freedom
    off = ~torch.eye(C, dtype=torch.bool)
    assert bool((res.heldout_epipolar_rms[off] < 0.6).all()), res.heldout_epipolar_rms
    assert res.verdict in ("good", "usable"), res.reasons


def test_initial_and_weights():
    s = scene(2, seed=30, noise=0.1)
    models = list(s.cameras.models)
    ref = RigSolver(models, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    shift = torch.diag(torch.tensor([0, 0, -0.01], dtype=D))
    init = [Camera.from_opencv(s.cameras.models[c], s.cameras.K[c] * 1.01 + shift, s.cameras.coeffs(c)) for c in range(2)]
    warm = RigSolver(models, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes, initial=init)
    assert torch.allclose(warm.T, ref.T, atol=1e-7) and torch.allclose(warm.cameras[0].K, ref.cameras[0].K, atol=1e-4)
    # uniform weights (any scale) are the unweighted fit
    w = 4.0 * s.valid.to(D)
    weighted = RigSolver(models, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes, weights=w)
    assert torch.allclose(weighted.T, ref.T, atol=1e-7)
    assert torch.allclose(weighted.baseline_std, ref.baseline_std, rtol=1e-4)


def test_fixed_intrinsics_kept_exactly():
    s = scene(2, seed=40, noise=0.2)
    models = list(s.cameras.models)
    init = [s.cameras[0].clone(), Camera.from_opencv(FISHEYE, K_FISH + torch.tensor([[2.0, 0, 1], [0, 2, -1], [0, 0, 0]], dtype=D),
                                                       s.cameras.coeffs(1).clone())]
    res = RigSolver(models, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes, initial=init,
                                     fixed=[True, True])
    for c in range(2):
        assert torch.equal(res.cameras[c].K, init[c].K) and torch.equal(res.cameras[c].dist, init[c].dist)
        assert float(res.intrinsics_std[c].abs().max()) == 0.0
    free = RigSolver(models, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes, initial=init,
                                      fixed=[True, False])
    assert torch.equal(free.cameras[0].K, init[0].K) and not torch.equal(free.cameras[1].K, init[1].K)


def test_exceptions():
    s = scene(2, seed=50)
    obj, sizes = s.object_points, s.image_sizes
    solver = RigSolver([OPENCV5, FISHEYE])
    with pytest.raises(ValueError, match="corners must be"):
        solver(s.corners[0], s.valid[0], obj, sizes)
    with pytest.raises(ValueError, match="valid must be"):
        solver(s.corners, s.valid[:, :3], obj, sizes)
    with pytest.raises(ValueError, match="object_points must be"):
        solver(s.corners, s.valid, obj[:5], sizes)
    with pytest.raises(ValueError, match="image_sizes"):
        solver(s.corners, s.valid, obj, sizes[:1])
    with pytest.raises(ValueError, match="at least 2 cameras"):
        solver(s.corners[:1], s.valid[:1], obj, sizes[:1])
    with pytest.raises(ValueError, match="must be one of the models"):
        RigSolver("pinhole")
    with pytest.raises(ValueError, match="models needs one entry per camera"):
        RigSolver([K1K2] * 3)(s.corners, s.valid, obj, sizes)
    with pytest.raises(ValueError, match="fixed but has no initial"):
        solver(s.corners, s.valid, obj, sizes, fixed=[True, False])
    with pytest.raises(ValueError, match="differs"):
        solver(s.corners, s.valid, obj, sizes, initial=[Camera.from_opencv(K1K2, K_WIDE), None])
    with pytest.raises(ValueError, match="weights must be"):
        solver(s.corners, s.valid, obj, sizes, weights=torch.ones(3))


def test_not_connected_names_cameras_and_frames():
    s = scene(4, models=[K1K2] * 4, frames=12, seed=60)
    valid = s.valid.clone()
    valid[2:, :6] = False  # cameras 2, 3 only see frames 6..11, cameras 0, 1 only frames 0..5
    valid[:2, 6:] = False
    corners = torch.where(valid[..., None], s.corners, float("nan"))
    with pytest.raises(ValueError) as err:
        RigSolver(K1K2)(corners, valid, s.object_points, s.image_sizes, names=["L", "R", "top", "side"])
    msg = str(err.value)
    assert "top, side" in msg and "not connected to L" in msg
    shared = ((valid[2].sum(-1) >= 6) & (valid[3].sum(-1) >= 6)).nonzero().flatten().tolist()
    assert len(shared) >= 2 and f"top-side {shared}" in msg


def _cv_points(s, c, frames):
    return [s.corners[c, f].numpy().astype(np.float32).reshape(-1, 1, 2) for f in frames]


def test_cross_check_cv2_stereo_calibrate():
    cams = [(OPENCV5, K_WIDE, torch.tensor([-0.2, 0.08, 0.001, -0.001, 0.01], dtype=D)),
            (OPENCV5, K_WIDE + 5 * torch.eye(3, dtype=D) * torch.tensor([1, 1, 0], dtype=D),
             torch.tensor([-0.15, 0.05, 0.0, 0.001, 0.0], dtype=D))]
    s = render_rig(cameras(cams, [SIZE] * 2), exp_so3(ROT[:2]), TRANS[:2], num_frames=20, seed=70, noise_px=0.2,
                   distance=(0.8, 1.2), spread=0.15)
    full = [f for f in range(20) if bool(s.valid[:, f].all())]
    assert len(full) >= 8
    obj = [s.object_points.numpy().astype(np.float32).reshape(-1, 1, 3)] * len(full)
    Kn = [c[1].numpy() for c in cams]
    dn = [c[2].numpy() for c in cams]
    rms, *_, R_cv, T_cv, _, _ = cv2.stereoCalibrate(
        obj, _cv_points(s, 0, full), _cv_points(s, 1, full), Kn[0], dn[0], Kn[1], dn[1], SIZE,
        flags=cv2.CALIB_FIX_INTRINSIC, criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    init = cameras(cams, SIZE)
    sel = torch.zeros(20, dtype=torch.bool)
    sel[full] = True
    valid = s.valid & sel[None, :, None]
    res = RigSolver(OPENCV5, folds=0)(s.corners, valid, s.object_points, s.image_sizes, initial=init,
                                       fixed=[True, True])
    assert rot_err_deg(res.R[1], torch.from_numpy(R_cv)) < 1e-3
    assert float((res.T[1] - torch.from_numpy(T_cv).flatten()).norm()) < 1e-5
    assert abs(res.rms - rms) < 1e-3


def test_stereo_rectify_matches_cv2():
    s = scene(2, models=[OPENCV5, OPENCV5], seed=80)
    res = RigSolver(OPENCV5, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    c1, c2 = res.cameras
    pair = res.pair(0, 1)
    out = stereo_rectify(c1, c2, SIZE, pair.R, pair.T, alpha=0.3)
    ref = cv2.stereoRectify(c1.K[0].numpy(), c1.dist[0].numpy(), c2.K[0].numpy(), c2.dist[0].numpy(), SIZE, pair.R.numpy(),
                            pair.T.numpy().reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.3)
    for k, v in zip(("R1", "R2", "P1", "P2", "Q", "roi1", "roi2"), ref):
        np.testing.assert_allclose(np.asarray(out[k], dtype=np.float64), np.asarray(v, dtype=np.float64), atol=1e-9)


def test_stereo_rectify_fisheye_and_mixed_rows_align():
    s = scene(2, models=[FISHEYE, FISHEYE], seed=81)
    res = RigSolver(FISHEYE, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    c1, c2 = res.cameras
    pair = res.pair(0, 1)
    out = stereo_rectify(c1, c2, SIZE, pair.R, pair.T)
    ref = cv2.fisheye.stereoRectify(c1.K[0].numpy(), c1.dist[0].numpy(), c2.K[0].numpy(), c2.dist[0].numpy(), SIZE,
                                    pair.R.numpy(), pair.T.numpy().reshape(3, 1), cv2.CALIB_ZERO_DISPARITY)
    for k, v in zip(("R1", "R2", "P1", "P2", "Q"), ref):
        np.testing.assert_allclose(out[k], v, atol=1e-9)
    # mixed pinhole / fisheye: rectified corners of both cameras lie on the same rows
    s = scene(2, seed=82)
    res = RigSolver(list(s.cameras.models), folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    c1, c2 = res.cameras
    pair = res.pair(0, 1)
    out = stereo_rectify(c1, c2, SIZE, pair.R, pair.T)
    both = s.valid[0] & s.valid[1]
    p1 = cv2.undistortPoints(s.corners[0][both].numpy().reshape(-1, 1, 2), c1.K[0].numpy(), c1.dist[0].numpy(),
                             R=out["R1"], P=out["P1"]).reshape(-1, 2)
    p2 = cv2.fisheye.undistortPoints(s.corners[1][both].numpy().reshape(-1, 1, 2), c2.K[0].numpy(), c2.dist[0].numpy(),
                                     R=out["R2"], P=out["P2"]).reshape(-1, 2)
    assert np.abs(p1[:, 1] - p2[:, 1]).max() < 1e-3  # (cv2's iterative undistortion: 1e-5 px)


def test_essential_fundamental_on_undistorted_corners():
    s = scene(2, seed=90)
    res = RigSolver(list(s.cameras.models), folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    pair = res.pair(0, 1)
    both = s.valid[0] & s.valid[1]
    x1 = res.cameras[0].undistort(s.corners[0][both][None])[0]
    x2 = res.cameras[1].undistort(s.corners[1][both][None])[0]
    ones = torch.ones_like(x1[:, :1])
    h1, h2 = torch.cat([x1, ones], -1), torch.cat([x2, ones], -1)
    assert float(((h2 @ pair.E) * h1).sum(-1).abs().max()) < 1e-9
    p1, p2 = h1 @ res.cameras.K[0].T, h2 @ res.cameras.K[1].T
    assert float(((p2 @ pair.F) * p1).sum(-1).abs().max()) < 1e-6
    # the pair from j to i is the inverse
    back = res.pair(1, 0)
    assert torch.allclose(back.R, pair.R.T, atol=1e-12) and torch.allclose(back.T, -pair.R.T @ pair.T, atol=1e-12)
    assert float(res.epipolar_rms[0, 1]) < 1e-6
    res.T[1] += 0.0  # ordinary tensors: in-place edits allowed
    res.cameras.params[0, 0] += 0.0


def test_heldout_needs_frames_and_verdict_flags_bad_data():
    s = scene(2, models=[K1K2, K1K2], frames=3, seed=100)
    res = RigSolver(K1K2)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.success and bool(res.heldout_epipolar_rms[0, 1].isnan())
    assert res.verdict == "usable" and any("too few shared frames" in r for r in res.reasons)
    s = scene(2, models=[K1K2, K1K2], frames=10, seed=101, noise=3.0)
    res = RigSolver(K1K2)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.verdict.startswith("not reliable: "), res.verdict


def test_rig_lm_derivatives_match_finite_differences():
    from ccs_kornia.modules.rig.rig_lm import _equations, rig_layout

    s = scene(3, frames=4, seed=110, noise=0.5)
    models = list(s.cameras.models)
    layout = rig_layout(models)
    intr, ext, G = layout
    params = [cam.params * 1.001 for cam in s.cameras]
    R = exp_so3(ROT[:3] + 0.01)[None]
    R[0, 0] = torch.eye(3, dtype=D)
    T = (TRANS[:3] + 0.003)[None]
    Rf = exp_so3(s.board_rvec + 0.01)[None]
    tf = s.board_tvec[None] + 0.002
    w = s.valid[None].to(D) * 2.0
    on = w > 0
    obs = torch.where(on[..., None], s.corners[None], 0.0)
    obj = s.object_points
    used = on.any(-1).any(1)
    eye6 = torch.eye(6, dtype=D)
    _, _, _, _, eg, ep, _ = _equations(models, params, R, T, Rf, tf, obj, obs, w.sqrt(), on, layout, used, eye6)

    def cost(dg, dp):
        p = [params[c] + dg[intr[c]][None] for c in range(3)]
        R2, T2 = R.clone(), T.clone()
        for c in (1, 2):
            R2[0, c] = exp_so3(dg[ext[c]][:3]) @ R[0, c]
            T2[0, c] = T[0, c] + dg[ext[c]][3:]
        Rf2, tf2 = exp_so3(dp[..., :3]) @ Rf, tf + dp[..., 3:]
        return float(_equations(models, p, R2, T2, Rf2, tf2, obj, obs, w.sqrt(), on, layout, used, eye6,
                                jacobians=False)[0])

    zg, zp = torch.zeros(G, dtype=D), torch.zeros(1, 4, 6, dtype=D)
    for i in range(G):
        h = 1e-6 * max(1.0, float(torch.cat(params, -1).flatten()[i].abs())) if i < intr[-1].stop else 1e-7
        dg = zg.clone()
        dg[i] = h
        num = (cost(dg, zp) - cost(-dg, zp)) / (2 * h)
        assert abs(num - 2 * float(eg[0, i])) <= 1e-5 * max(1.0, abs(num)), (i, num, 2 * float(eg[0, i]))
    for f in range(4):
        for k in range(6):
            dp = zp.clone()
            dp[0, f, k] = 1e-7
            num = (cost(zg, dp) - cost(zg, -dp)) / 2e-7
            assert abs(num - 2 * float(ep[0, f, k])) <= 1e-5 * max(1.0, abs(num)), (f, k, num)


def test_camera_with_few_frames_is_calibrated_through_the_rig():
    s = scene(2, models=[K1K2, K1K2], frames=10, seed=120)
    valid = s.valid.clone()
    valid[1, 2:] = False  # camera 1 sees 2 frames only: too few for its own full calibration
    corners = torch.where(valid[..., None], s.corners, float("nan"))
    res = RigSolver(K1K2, folds=0)(corners, valid, s.object_points, s.image_sizes)
    assert res.success, res.reason
    assert int(res.used[1].sum()) == 2
    assert rot_err_deg(res.R[1], s.R[1]) < 1e-5 and float((res.T[1] - s.T[1]).norm()) < 1e-7


def _renumber(s, turns, cols, rows):
    """Corners of each camera x frame numbered as a detector that starts from another corner of a symmetric grid:
    the grid turned by ``turns[c, f]`` quarter turns (2: reversed order)."""
    corners, valid = s.corners.clone(), s.valid.clone()
    for c in range(turns.shape[0]):
        for f in range(turns.shape[1]):
            k = int(turns[c, f])
            grid = s.corners[c, f].reshape(rows, cols, 2)
            vgrid = s.valid[c, f].reshape(rows, cols)
            corners[c, f] = torch.rot90(grid, k, (0, 1)).reshape(-1, 2)
            valid[c, f] = torch.rot90(vgrid, k, (0, 1)).reshape(-1)
    return corners, valid


def test_symmetric_board_numbered_differently_per_camera_and_frame():
    s = scene(3, frames=12, seed=130, drop=0.1)
    g = torch.Generator().manual_seed(0)
    turns = 2 * (torch.rand(3, 12, generator=g) < 0.4).long()  # reversed order in 40 % of the observations
    turns[1] = 2  # a camera whose detector always starts from the other end
    corners, valid = _renumber(s, turns, 7, 5)
    models = list(s.cameras.models)
    res = RigSolver(models, folds=0)(corners, valid, s.object_points, s.image_sizes)
    assert res.success, res.reason
    for c in range(3):
        assert rot_err_deg(res.R[c], s.R[c]) < 1e-6 and float((res.T[c] - s.T[c]).norm()) < 1e-8
    assert res.rms < 1e-6 and bool(res.used.sum() >= s.valid.any(-1).sum() - 2)
    # after the renumbering every camera of a frame numbers the board alike
    final = (turns + 2 * res.corner_order) % 4
    for f in range(12):
        assert final[res.used[:, f], f].unique().numel() <= 1
    assert bool(res.corner_order.any())
    with pytest.raises(AssertionError):  # without the renumbering the rig cannot be fitted
        off = RigSolver(models, folds=0, symmetric_board=False)(corners, valid, s.object_points, s.image_sizes)
        assert off.success and off.rms < 1e-3 and rot_err_deg(off.R[1], s.R[1]) < 1e-3


def test_square_board_quarter_turns():
    s = render_rig(cameras(CAMERAS[:2], [SIZE] * 2), exp_so3(ROT[:2]), TRANS[:2], num_frames=10, seed=131, board=(5, 5))
    g = torch.Generator().manual_seed(1)
    turns = torch.randint(0, 4, (2, 10), generator=g)
    corners, valid = _renumber(s, turns, 5, 5)
    res = RigSolver(list(s.cameras.models), folds=0)(corners, valid, s.object_points, s.image_sizes)
    assert res.success and res.rms < 1e-6
    assert rot_err_deg(res.R[1], s.R[1]) < 1e-6 and float((res.T[1] - s.T[1]).norm()) < 1e-8


def test_cameras_of_different_image_sizes():
    K_big = torch.tensor([[1100.0, 0, 650], [0, 1100, 395], [0, 0, 1]], dtype=D)
    cams = [CAMERAS[0], (K1K2, K_big, torch.tensor([-0.05, 0.01], dtype=D))]
    sizes = [SIZE, (1280, 800)]
    s = render_rig(cameras(cams, sizes), exp_so3(ROT[:2]), TRANS[:2], num_frames=10, seed=140, noise_px=0.1)
    res = RigSolver([OPENCV5, K1K2])(s.corners, s.valid, s.object_points, sizes)
    assert res.success and res.image_sizes == sizes
    assert float((res.cameras[1].K - K_big).abs().max()) < 3.0
    assert rot_err_deg(res.R[1], s.R[1]) < 0.3 and float((res.T[1] - s.T[1]).norm()) / float(s.T[1].norm()) < 0.01


def test_verdict_thresholds_scale_with_image_diagonal():
    from ccs_kornia.modules.rig import rig_verdict

    z = torch.zeros(2, 2)
    base = (torch.tensor([0.0, 0.2]), torch.tensor([0.0, 1e-4]), torch.tensor([0.0, 0.01]))
    rms = torch.tensor([1.5, 0.2])  # px: above 1 px per 1000 px of diagonal at 640x480, below it at 1920x1080
    small = rig_verdict(["a", "b"], [(640, 480)] * 2, rms, z, z + 0.1, *base)
    large = rig_verdict(["a", "b"], [(1920, 1080)] * 2, rms, z, z + 0.1, *base)
    assert small[0] == "usable" and "a: reprojection RMS 1.50 px is high" in small[1]
    assert large == ("good", [])
    held = z + 2.0  # held-out epipolar RMS 2 px: above 2 px per 1000 px at 640x480 (1.6 px)
    assert rig_verdict(["a", "b"], [(640, 480)] * 2, rms * 0.1, z, held, *base)[0].startswith(
        "not reliable: a-b's held-out epipolar RMS 2.00 px is over 1.60 px: add frames")
    assert rig_verdict(["a", "b"], [(1920, 1080)] * 2, rms * 0.1, z, held, *base)[0] == "good"


def test_verdict_advice_names_the_figure_that_failed():
    from ccs_kornia.modules.rig import rig_verdict

    z, rms, sizes = torch.zeros(2, 2), torch.tensor([0.2, 0.2]), [(1280, 720)] * 2
    baseline = torch.tensor([0.0, 0.5])
    # the rotation's 1-sigma fails, the baseline's does not: the advice says which
    verdict, reasons = rig_verdict(["cam0", "cam1"], sizes, rms, z, z + 0.2, baseline, torch.tensor([0.0, 1e-3]),
                                   torch.tensor([0.0, 0.70]))
    assert verdict.startswith("not reliable: cam1's rotation 1-sigma 0.70 deg is over 0.5 deg: add frames")
    assert "baseline" not in verdict and "cam1: baseline 1-sigma 0.20 %, rotation 1-sigma 0.700 deg" in reasons
    verdict, _ = rig_verdict(["cam0", "cam1"], sizes, rms, z, z + 0.2, baseline, torch.tensor([0.0, 0.05]),
                             torch.tensor([0.0, 0.01]))
    assert verdict.startswith("not reliable: cam1's baseline 1-sigma 10.00 % is over 2 %: add frames")


def test_batch_heldout_per_rig():
    few, many = scene(2, models=[K1K2] * 2, frames=8, seed=150), scene(2, models=[K1K2] * 2, frames=8, seed=151)
    valid = torch.stack([few.valid, many.valid])
    valid[0, :, 3:] = False  # the first rig keeps 3 frames: too few to hold some out
    corners = torch.where(valid[..., None], torch.stack([few.corners, many.corners]), float("nan"))
    out = RigSolver(K1K2)(corners, valid, few.object_points, few.image_sizes)
    assert bool(out[0].heldout_epipolar_rms[0, 1].isnan()) and bool(out[1].heldout_epipolar_rms[0, 1].isfinite())


def test_reported_uncertainty_matches_the_spread_over_noise_draws():
    base = render_rig(cameras(CAMERAS[:2], [SIZE] * 2), exp_so3(ROT[:2]), TRANS[:2], num_frames=12, seed=170)
    B = 24
    g = torch.Generator().manual_seed(5)
    corners = base.exact[None] + 0.3 * torch.randn((B,) + base.exact.shape, generator=g, dtype=D)
    valid = base.valid[None].expand(B, -1, -1, -1)
    out = RigSolver(list(base.cameras.models), folds=0)(corners, valid, base.object_points, base.image_sizes)
    baseline = torch.tensor([float(r.T[1].norm()) for r in out])
    ratio = float(baseline.std()) / float(torch.tensor([float(r.baseline_std[1]) for r in out]).mean())
    assert 0.6 < ratio < 1.6, ratio
    rot = torch.stack([log_so3(r.R[1] @ base.R[1].T) for r in out]).norm(dim=-1).square().mean().sqrt()
    ratio = float(rot) * 180 / math.pi / float(torch.tensor([float(r.rotation_std_deg[1]) for r in out]).mean())
    assert 0.6 < ratio < 1.6, ratio


def test_epipolar_distance_of_fisheye_rays_beyond_the_limit_is_nan():
    from ccs_kornia.modules.rig import epipolar_distances

    cam = Camera.from_opencv(FISHEYE, K_FISH)
    X = torch.tensor([[0.1, 0.0, 1.0], [1.0, 0.0, 0.1], [0.2, -0.1, 1.0]], dtype=D)  # the second is 84 deg off axis
    T = torch.tensor([-0.1, 0.0, 0.0], dtype=D)
    uv1 = cam.project(X[None])[0]
    uv2 = cam.project((X + T)[None])[0]
    d = epipolar_distances(cam, cam, torch.eye(3, dtype=D), T, uv1, uv2)
    assert bool(d[1].isnan()) and float(d[[0, 2]].abs().max()) < 1e-9


def test_camera_that_sees_no_board_fails_naming_it():
    s = scene(3, models=[K1K2] * 3, frames=6, seed=180)
    valid = s.valid.clone()
    valid[2] = False
    corners = torch.where(valid[..., None], s.corners, float("nan"))
    res = RigSolver(K1K2)(corners, valid, s.object_points, s.image_sizes, names=["a", "b", "top"])
    assert not res.success and res.reason.startswith("top: the camera alone could not be calibrated")
    assert res.verdict.startswith("not reliable: ")


def test_joint_fit_options_of_the_lm_core():
    from ccs_kornia.geometry.camera import project_points
    from ccs_kornia.modules.rig.rig_lm import rig_levenberg_marquardt
    from ccs_kornia.modules.rig.rig_state import RigObservations, RigState

    s = scene(2, models=[PINHOLE, PINHOLE], frames=6, seed=2)
    obj = s.object_points
    g = torch.Generator().manual_seed(0)
    rv = 0.3 * torch.randn(2, 6, 3, generator=g, dtype=D)
    tv = torch.tensor([-0.1, -0.1, 1.2], dtype=D) + 0.05 * torch.randn(2, 6, 3, generator=g, dtype=D)
    T1 = torch.tensor([-0.12, 0.0, 0.0], dtype=D)
    corners = torch.stack([project_points(obj.expand(6, -1, -1), K_WIDE.expand(6, 3, 3), None, rv[b], tv[b] + t)
                           for b in range(2) for t in (torch.zeros(3, dtype=D), T1)]).view(2, 2, 6, -1, 2)
    p0 = torch.tensor([[560.0, 640.0, 310.0, 260.0]], dtype=D).expand(2, 4)
    args = (RigState([PINHOLE] * 2, [p0, p0], torch.eye(3, dtype=D).expand(2, 2, 3, 3),
                     torch.stack([torch.zeros(2, 3, dtype=D), torch.stack([T1 * 0.8] * 2)], 1), exp_so3(rv), tv),
            RigObservations(obj, corners, torch.ones(corners.shape[:-1], dtype=D)))
    ref = rig_levenberg_marquardt(*args, lambda_init=1e4)  # heavy damping: many short steps
    assert (ref.iterations > 10).all() and (ref.status == LMStatus.CONVERGED).all()
    assert torch.allclose(ref.state.T[:, 1], T1.expand(2, 3), atol=1e-8)
    sparse = rig_levenberg_marquardt(*args, lambda_init=1e4, check_every=4)  # fewer host checks: the same answer
    assert torch.equal(sparse.iterations, ref.iterations)
    assert torch.allclose(sparse.state.T, ref.state.T, rtol=0, atol=1e-15)
    stalled = rig_levenberg_marquardt(*args, lambda_init=1e4, stall_tol=1e300)  # every window of 10 "stalls"
    assert (stalled.iterations == 10).all() and (stalled.status == LMStatus.STALLED).all()
    assert RigSolver(K1K2).stall_tol == 0.0  # the rig's default: no stall stop
