"""Fisheye calibration: ray-DLT poses, focal hypotheses, calibrate_fisheye against cv2.fisheye and the real sets."""

from __future__ import annotations

import glob
import math
import os

import cv2
import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import (
    Camera,
    rotation_matrix_to_axis_angle,
    transform_points_rt,
)
from ccs_kornia.geometry.models import FISHEYE, K1K2
from ccs_kornia.modules.calibration.fisheye_calibration import (
    FisheyeCalibrator,
    calibrate_fisheye,
)
from ccs_kornia.modules.calibration.fisheye_init import (
    board_to_ray_poses,
    focal_hypotheses,
    init_fisheye,
)
from ccs_kornia.modules.calibration.result import ViewReason
from ccs_kornia.modules.calibration.schur_lm import LMStatus

F64 = torch.float64
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
OBJ = board_object_points(9, 6, 0.03, dtype=F64)
SIZE = (640, 480)
REAL = str(REAL_DATA)  # $CCS_REAL_DATA, else ../shared/data/real beside the checkout


def _camera(fov_deg=190.0, D=(0.02, -0.01, 0.002, -0.0005)):
    D = torch.tensor(D, dtype=F64)
    t = math.radians(fov_deg) / 2
    f = 320.0 / (t * (1 + D[0] * t**2 + D[1] * t**4 + D[2] * t**6 + D[3] * t**8))
    return torch.tensor([[f, 0, 322.0], [0, f * 1.005, 236.0], [0, 0, 1]], dtype=F64), D


def _views(K, D, V=12, seed=0, min_theta=0.0, max_theta=None):
    """Random board views inside the image, directions up to the rim (beyond 90 degrees for wide lenses)."""
    g = torch.Generator().manual_seed(seed)
    if max_theta is None:  # about the horizontal half field of view (equidistant estimate)
        max_theta = min(1.75, 330.0 / float(K[0, 0]))
    rv, tv, uv = [], [], []
    while len(rv) < V:
        th = torch.empty(1, dtype=F64).uniform_(min_theta, max_theta, generator=g)
        ph = torch.empty(1, dtype=F64).uniform_(0, 2 * math.pi, generator=g)
        d = torch.cat([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()])
        tilt = torch.empty(1, dtype=F64).uniform_(0, 1.1, generator=g)
        axis = torch.nn.functional.normalize(torch.linalg.cross(d, torch.randn(3, generator=g, dtype=F64)), dim=0)
        e3 = d * tilt.cos() + torch.linalg.cross(axis, d) * tilt.sin()
        a = torch.randn(3, generator=g, dtype=F64)
        e1 = torch.nn.functional.normalize(a - (a @ e3) * e3, dim=0)
        R = torch.stack([e1, torch.linalg.cross(e3, e1), e3], -1)
        t = d * float(torch.empty(1, dtype=F64).uniform_(0.25, 0.5, generator=g)) - R @ OBJ.mean(0)
        r = rotation_matrix_to_axis_angle(R[None])[0]
        p = Camera.from_opencv(FISHEYE, K, D).project(OBJ[None], r[None], t[None])[0]
        if bool(((p[:, 0] > 5) & (p[:, 0] < 634) & (p[:, 1] > 5) & (p[:, 1] < 474)).all()):
            grid = p.view(6, 9, 2)
            if min(float((grid[:, 1:] - grid[:, :-1]).norm(dim=-1).min()), float((grid[1:] - grid[:-1]).norm(dim=-1).min())) > 4:
                rv.append(r), tv.append(t), uv.append(p)
    return torch.stack(rv), torch.stack(tv), torch.stack(uv)


def _max_theta(rv, tv):
    Xc = transform_points_rt(OBJ, rv, tv)
    return torch.atan2(Xc[..., :2].norm(dim=-1), Xc[..., 2]).amax(-1)


def test_board_to_ray_poses_beyond_90_degrees_and_masks():
    K, D = _camera()
    rv = torch.tensor([[0.1, 1.7, 0.2], [0.3, -0.2, 0.1], [2.0, 0.3, -0.4]], dtype=F64)
    tv = torch.tensor([[0.5, 0.0, 0.1], [-0.1, -0.1, 0.4], [0.0, 0.4, -0.05]], dtype=F64)
    assert bool((_max_theta(rv, tv) > math.pi / 2).any())
    rays = transform_points_rt(OBJ, rv, tv) * 3.0  # any ray length
    r, t, ok = board_to_ray_poses(rays, OBJ[:, :2])
    assert ok.all() and r.shape == (3, 3)
    torch.testing.assert_close(r, rv, atol=1e-9, rtol=0)
    torch.testing.assert_close(t, tv, atol=1e-9, rtol=0)
    bad = rays.clone()
    bad[0, :10] = float("nan")
    w = torch.ones(3, 54)
    w[0, :10] = 0
    w[2, 3:] = 0  # three corners: not enough
    r2, t2, ok2 = board_to_ray_poses(bad, OBJ[:, :2], w)
    assert ok2.tolist() == [True, True, False] and bool(r2.isfinite().all())
    torch.testing.assert_close(r2[0], rv[0], atol=1e-9, rtol=0)
    with pytest.raises(ValueError, match="rays"):
        board_to_ray_poses(rays[..., :2], OBJ[:, :2])


def test_focal_hypotheses_and_init_find_the_focal_length():
    f = focal_hypotheses(SIZE, 32)
    assert f.shape == (32,) and bool((f[1:] > f[:-1]).all())
    K, D = _camera(190.0)
    rv, tv, uv = _views(K, D, V=10, seed=1)
    params, r0, t0, view_rms, score = init_fisheye(uv[None], torch.ones(1, 10, 54), OBJ, SIZE, keep=3)
    assert params.shape == (1, 3, 8) and r0.shape == (1, 3, 10, 3) and view_rms.shape == (1, 3, 10) and score.shape == (1, 3)
    assert abs(float(params[0, 0, 0]) / float(K[0, 0]) - 1) < 0.1
    with pytest.raises(ValueError, match="weights"):
        init_fisheye(uv[None], torch.ones(1, 9, 54), OBJ, SIZE)


@pytest.mark.parametrize("fov", [120.0, 190.0])
def test_calibrate_fisheye_exact_data_and_batch(fov):
    cams = [_camera(fov), _camera(fov + 10, (-0.03, 0.004, -0.001, 0.0002))]
    data = [_views(K, D, V=8, seed=s) for s, (K, D) in enumerate(cams)]
    if fov > 180:  # two views at the rim of the field of view, beyond 90 degrees from the axis
        rim = [_views(K, D, V=2, seed=s + 10, min_theta=1.5, max_theta=1.7) for s, (K, D) in enumerate(cams)]
        data = [tuple(torch.cat([a, b]) for a, b in zip(d, r)) for d, r in zip(data, rim)]
    else:
        data = [tuple(torch.cat([a, b]) for a, b in zip(d, _views(K, D, V=2, seed=s + 10)))
                for s, (d, (K, D)) in enumerate(zip(data, cams))]
    uv = torch.stack([d[2] for d in data])
    res = calibrate_fisheye(uv, None, OBJ, SIZE)
    assert res.success.all() and res.used.all() and bool((res.rms < 1e-6).all())
    assert (res.lm_status == LMStatus.CONVERGED).all()
    for c, (K, D) in enumerate(cams):
        torch.testing.assert_close(res.K[c], K, atol=1e-6, rtol=0)
        torch.testing.assert_close(res.D[c], D, atol=1e-8, rtol=0)
        one = calibrate_fisheye(uv[c], None, OBJ, SIZE)  # unbatched input
        torch.testing.assert_close(one.K, res.K[c], atol=1e-9, rtol=0)
        assert one.covariance.shape == (8, 8) and one.view_rms.shape == (10,)
    if fov > 180:
        assert bool((_max_theta(data[0][0], data[0][1]) > math.pi / 2).any())


def test_calibrate_fisheye_noise_outliers_and_uncertainty():
    K, D = _camera(170.0)
    rv, tv, uv = _views(K, D, V=14, seed=4)
    g = torch.Generator().manual_seed(0)
    uvn = uv + 0.1 * torch.randn(uv.shape, generator=g, dtype=F64)
    valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
    uvn[3] += 25.0 * torch.randn(54, 2, generator=g, dtype=F64)  # a view of garbage corners
    valid[5, 4:] = False  # a view with too few corners
    res = calibrate_fisheye(uvn, valid, OBJ, SIZE)
    assert bool(res.success) and not bool(res.used[3]) and not bool(res.used[5]) and int(res.used.sum()) == 12
    assert bool(res.candidate_rms[3] > 5) and bool(res.candidate_rms[5].isnan())
    err = (res.K[[0, 1, 0, 1], [0, 1, 2, 2]] - K[[0, 1, 0, 1], [0, 1, 2, 2]]).abs()
    assert bool((err < 5 * res.std_intrinsics + 1e-3).all()), (err, res.std_intrinsics)
    assert 0.08 < float(res.rms) < 0.16
    torch.testing.assert_close(res.covariance.diagonal()[:4].sqrt(), res.std_intrinsics)


def test_warm_start_from_the_full_calibration_matches_the_cold_start():
    # cross-validation calibrates subsets of the views starting from the calibration of all of them
    K, D = _camera(170.0)
    _, _, uv = _views(K, D, V=12, seed=5)
    uvn = uv + 0.1 * torch.randn(uv.shape, generator=torch.Generator().manual_seed(2), dtype=F64)
    full = calibrate_fisheye(uvn, None, OBJ, SIZE)
    subset = torch.arange(12) % 3 != 0  # 8 of the 12 views
    valid = subset[:, None].expand(12, 54)
    cold = calibrate_fisheye(uvn[None].expand(2, -1, -1, -1), valid[None].expand(2, -1, -1), OBJ, SIZE)
    nan_K = torch.stack([full.K, torch.full_like(full.K, float("nan"))])  # camera 1: no finite start -> hypotheses
    initial = (nan_K, full.D.expand(2, 4), full.rvec.expand(2, -1, -1), full.tvec.expand(2, -1, -1),
               (full.used & subset).expand(2, -1))
    warm = calibrate_fisheye(uvn[None].expand(2, -1, -1, -1), valid[None].expand(2, -1, -1), OBJ, SIZE,
                             initial=initial)
    assert bool(warm.success.all()) and torch.equal(warm.used, cold.used) and int(warm.used[0].sum()) == 8
    torch.testing.assert_close(warm.K, cold.K, atol=1e-6, rtol=0)
    torch.testing.assert_close(warm.D, cold.D, atol=1e-8, rtol=0)
    torch.testing.assert_close(warm.rms, cold.rms, atol=1e-9, rtol=0)
    one = calibrate_fisheye(uvn, valid, OBJ, SIZE, initial=tuple(x[0] for x in initial))  # unbatched
    torch.testing.assert_close(one.K, cold.K[0], atol=1e-6, rtol=0)


def test_against_cv2_fisheye_where_opencv_works():
    K, D = _camera(150.0)
    rv, tv, uv = _views(K, D, V=10, seed=7)
    uvn = uv + 0.1 * torch.randn(uv.shape, generator=torch.Generator().manual_seed(1), dtype=F64)
    o = OBJ.numpy().reshape(1, -1, 3)
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS
    rms, Kc, Dc, _, _ = cv2.fisheye.calibrate([o] * 10, [p.numpy().reshape(1, -1, 2) for p in uvn], SIZE, K.numpy().copy(),
                                              np.zeros(4), flags=flags, criteria=(3, 200, 1e-15))
    res = calibrate_fisheye(uvn, None, OBJ, SIZE)
    assert bool(res.used.all()) and float(res.rms) <= rms + 1e-7
    np.testing.assert_allclose(res.K.numpy(), Kc, atol=1e-3)
    np.testing.assert_allclose(res.D.numpy(), Dc.ravel(), atol=1e-5)


def test_module_and_exceptions():
    K, D = _camera(150.0)
    _, _, uv = _views(K, D, V=4, seed=2)
    mod = FisheyeCalibrator(keep=2)
    res = mod(uv, None, OBJ, SIZE)
    assert bool(res.success) and mod.keep == 2
    with pytest.raises(ValueError, match="corners"):
        calibrate_fisheye(uv[..., :1], None, OBJ, SIZE)
    with pytest.raises(ValueError, match="valid"):
        calibrate_fisheye(uv, torch.ones(4, 3, dtype=torch.bool), OBJ, SIZE)
    with pytest.raises(ValueError, match="object_points"):
        calibrate_fisheye(uv, None, OBJ[:5], SIZE)
    fixed = calibrate_fisheye(uv, None, OBJ, SIZE, fix=("k3", "k4"))
    assert bool(fixed.success) and bool((fixed.D[2:] == 0).all()) and bool((fixed.std_dist[2:] == 0).all())
    with pytest.raises(ValueError, match="fix"):
        calibrate_fisheye(uv, None, OBJ, SIZE, fix=("k5",))
    # too few views: failure with NaN values, no exception
    out = calibrate_fisheye(uv[:2], None, OBJ, SIZE)
    assert not bool(out.success) and bool(out.K.isnan().all())


@pytest.mark.parametrize("device", DEVICES)
def test_device(device):
    K, D = _camera(185.0)
    _, _, uv = _views(K, D, V=8, seed=3)
    res = calibrate_fisheye(uv.to(device), None, OBJ.to(device), SIZE)
    assert res.K.device.type == device and bool(res.success)
    torch.testing.assert_close(res.K.cpu(), K, atol=1e-6, rtol=0)


# ------------------------------------------------------------------------------------------------ real fisheye sets
def _classic_corners(folder, cols, rows):
    files = sorted(glob.glob(os.path.join(folder, "*.png")) + glob.glob(os.path.join(folder, "*.jpg")))
    out, size = [], None
    for f in files:
        g = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        size = (g.shape[1], g.shape[0])
        ok, c = cv2.findChessboardCorners(g, (cols, rows), cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE)
        assert ok, f
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
        out.append(cv2.cornerSubPix(g, c, (5, 5), (-1, -1), crit).reshape(-1, 2))
    return torch.tensor(np.stack(out), dtype=F64), size


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir(os.path.join(REAL, "ros_fisheye_mono")), reason="real data not present")
def test_ros_fisheye_mono_matches_reference():
    uv, size = _classic_corners(os.path.join(REAL, "ros_fisheye_mono"), 8, 6)
    res = calibrate_fisheye(uv, None, board_object_points(8, 6, 1.0, dtype=F64), size)
    ref = torch.tensor([290.050152, 289.392837, 399.938345, 273.885669], dtype=F64)
    assert bool(res.used.all()) and uv.shape[0] == 24
    assert bool(((res.K[[0, 1, 0, 1], [0, 1, 2, 2]] - ref).abs() < 2.0).all()), res.K
    assert float(res.rms) < 0.55


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir(os.path.join(REAL, "boofcv_fisheye_chessboard")), reason="real data not present")
def test_boofcv_fisheye_uses_every_board():
    uv, size = _classic_corners(os.path.join(REAL, "boofcv_fisheye_chessboard"), 6, 4)
    res = calibrate_fisheye(uv, None, board_object_points(6, 4, 0.03, dtype=F64), size)
    assert uv.shape[0] == 26 and bool(res.used.all()) and float(res.rms) < 0.25
    assert abs(float(res.K[0, 0]) - 190.15) < 2 and abs(float(res.K[0, 2]) - 318.6) < 2


# ------------------------------------------------------------------------------------- through CalibrationSolver
def test_solver_fisheye_model_and_checks():
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    K, D = _camera(170.0)
    _, _, uv = _views(K, D, V=8, seed=4)
    res = CalibrationSolver(model=FISHEYE)(uv, None, OBJ, SIZE)
    assert res.camera.model == FISHEYE and bool(res.success) and res.dist.shape == (4,)
    torch.testing.assert_close(res.K, K, atol=1e-6, rtol=0)
    torch.testing.assert_close(res.dist, D, atol=1e-7, rtol=0)
    assert res.cov_camera.shape == (8, 8) and bool((res.view_reason == ViewReason.USED).all())
    # copies of one view are refused before the fisheye solve, as for the pinhole models
    copies = uv[:1].expand(4, -1, -1)
    refused = CalibrationSolver(model=FISHEYE)(copies, None, OBJ, SIZE)
    assert not bool(refused.success) and bool((refused.view_reason[1:] == ViewReason.DUPLICATE).all())
    assert any(i["check"] == "duplicate_views" for i in refused.issues()[0])
    # batched over cameras, a failed camera beside a good one
    batch = torch.stack([uv, uv.clone().fill_(float("nan"))])
    both = CalibrationSolver(model=FISHEYE)(batch, None, OBJ, SIZE)
    assert both.success.tolist() == [True, False] and bool(both.K[1].isnan().all())
    # warm start from a fisheye result (the same camera back), and only from a fisheye result
    again = CalibrationSolver(model=FISHEYE)(uv, None, OBJ, SIZE, initial=res)
    torch.testing.assert_close(again.K, res.K, atol=1e-6, rtol=0)
    pinhole = CalibrationSolver(model=K1K2)(uv, None, OBJ, SIZE)
    with pytest.raises(ValueError, match="fisheye calibration"):
        CalibrationSolver(model=FISHEYE)(uv, None, OBJ, SIZE, initial=pinhole)


def test_diagnostics_of_a_fisheye_calibration():
    """Quality figures with the Kannala-Brandt model: rays beyond 90 degrees, held-out poses on the LM core."""
    from ccs_kornia.modules.calibration.quality.diagnostics import diagnose
    from ccs_kornia.modules.calibration.quality.uncertainty import projection_difference
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    K, D = _camera(190.0)
    _, _, uv = _views(K, D, V=12, seed=5)
    uv = uv + 0.2 * torch.randn(uv.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    solver = CalibrationSolver(model=FISHEYE)
    res = solver(uv, None, OBJ, SIZE)
    q = diagnose(res, uv, None, OBJ, SIZE, solver=solver)[0]
    assert q["success"] and 0.1 < q["heldout_rms_px"] < 0.4  # about the 0.2 px noise per axis
    assert 0 < q["uncertainty_centre_px"] < 0.5 and q["cv_rms_px"] is not None
    # the same camera against itself: no difference, also for pixels beyond 90 degrees
    px = torch.tensor([[320.0, 240.0], [5.0, 240.0], [630.0, 20.0]], dtype=F64)
    d = projection_difference(res.camera, res.camera, px)
    assert bool((d.nan_to_num(0.0) < 1e-6).all()) and bool(d[0, :2].isfinite().all())
