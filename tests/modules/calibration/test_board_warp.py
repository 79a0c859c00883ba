"""The board's sag (mrcal's two-parameter bend): its shape as mrcal defines it, recovered jointly by the camera's LM on
rendered bent boards with its 1-sigma (OpenCV and fisheye models), and kept by the held-out rule only where the board
is bent."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.board_warp import board_warp_basis, warped_board
from ccs_kornia.geometry.camera import Camera, project_points
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5
from ccs_kornia.modules.calibration.board_flatness import (
    choose_board_warp,
    split_halves,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver

SIZE = (640, 480)


def _views(warp, V=16, noise=0.03, seed=0):
    obj = board_object_points(8, 6, 0.04, dtype=torch.float64)
    K = torch.tensor([[700.0, 0, 320], [0, 700, 240], [0, 0, 1]], dtype=torch.float64)
    dist = torch.tensor([-0.2, 0.05, 0, 0, 0], dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    rvec = 0.9 * (torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.14, -0.1, 0.5], dtype=torch.float64) + 0.1 * torch.rand(V, 3, generator=g,
                                                                                       dtype=torch.float64)
    bent = warped_board(obj, torch.tensor(warp, dtype=torch.float64))
    uv = project_points(bent.expand(V, -1, -1), K.expand(V, 3, 3), dist.expand(V, 5), rvec, tvec)
    return obj, K, uv + noise * torch.randn(uv.shape, generator=g, dtype=torch.float64)


def test_shape_is_mrcals():
    # mrcal: dz = c_x * 4 xr (1 - xr) + c_y * 4 yr (1 - yr), xr = i / (W - 1), yr = j / (H - 1)
    W, H = 10, 7
    obj = board_object_points(W, H, 0.077, dtype=torch.float64)
    j, i = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    xr, yr = i.flatten() / (W - 1), j.flatten() / (H - 1)
    expected = torch.stack([4 * xr * (1 - xr), 4 * yr * (1 - yr)], -1)
    assert torch.allclose(board_warp_basis(obj), expected, atol=1e-12)
    bent = warped_board(obj, torch.tensor([-0.001, 0.0005], dtype=torch.float64))
    assert torch.allclose(bent[:, 2], expected @ torch.tensor([-0.001, 0.0005], dtype=torch.float64))
    assert torch.equal(bent[:, :2], obj[:, :2])


def test_rendered_bent_board_is_recovered_with_its_sigma():
    truth = [-0.0015, 0.0008]
    obj, _, uv = _views(truth)
    flat = CalibrationSolver(model=OPENCV5)(uv, None, obj, SIZE)
    res = CalibrationSolver(model=OPENCV5, board_warp=True)(uv, None, obj, SIZE)
    assert flat.board_warp is None and bool(res.success)
    err = (res.board_warp - torch.tensor(truth, dtype=torch.float64)).abs()
    assert (err < 4 * res.std_board_warp).all() and (res.std_board_warp < 2e-5).all()
    # the flat board's fit is biased, the bent one's is not
    assert abs(res.K[0, 0] - 700) < 4 * res.std_intrinsics[0] < abs(flat.K[0, 0] - 700)
    assert res.rms < 0.06 < flat.rms


def test_held_out_views_keep_the_sag_only_where_the_board_is_bent():
    solver = CalibrationSolver(model=K1K2)
    for warp, kept in (([-0.0015, 0.0008], True), ([0.0, 0.0], False)):
        obj, _, uv = _views(warp, seed=1)
        valid = uv.isfinite().all(-1)[None]
        usual = solver(uv[None], valid, obj, SIZE)
        choice = choose_board_warp(solver, usual, uv[None], valid, obj, SIZE)
        assert bool(choice.kept[0]) is kept
        record = choice.record(0)
        assert record["kept"] is kept and len(record["warp_m"]) == 2
        if kept:
            assert choice.heldout_warp[0] < 0.5 * choice.heldout_flat[0]
            assert torch.allclose(choice.result.board_warp[0], choice.warp[0])
            assert choice.result.rms[0] < usual.rms[0]
        else:
            assert torch.equal(choice.result.K, usual.K) and (choice.result.board_warp == 0).all()


def test_halves_alternate_over_the_used_views():
    used = torch.tensor([[True, True, False, True, True, True]])
    a, b = split_halves(used)
    assert (a | b).equal(used) and not (a & b).any()
    assert a.sum() == 3 and b.sum() == 2


def _fisheye_views(warp, V=10, seed=0):
    obj = board_object_points(8, 6, 0.04, dtype=torch.float64)
    K = torch.tensor([[200.0, 0, 322], [0, 201, 237], [0, 0, 1]], dtype=torch.float64)
    D = torch.tensor([0.02, -0.01, 0.002, 0.0], dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    rvec = 0.9 * (torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5)
    u = torch.rand(V, 3, generator=g, dtype=torch.float64)
    tvec = torch.stack([-0.14 + 0.3 * (u[:, 0] - 0.5), -0.1 + 0.3 * (u[:, 1] - 0.5), 0.25 + 0.1 * u[:, 2]], -1)
    bent = warped_board(obj, torch.tensor(warp, dtype=torch.float64))
    uv = Camera.from_opencv(FISHEYE, K, D).project(bent, rvec[None], tvec[None])
    return obj, uv + 0.05 * torch.randn(uv.shape, generator=g, dtype=torch.float64)


def test_fisheye_bent_board_is_recovered_and_kept():
    truth = torch.tensor([-0.002, 0.001], dtype=torch.float64)
    obj, uv = _fisheye_views(truth.tolist())
    solver = CalibrationSolver(model=FISHEYE)
    usual = solver(uv, None, obj, SIZE)
    choice = choose_board_warp(solver, usual, uv, uv.isfinite().all(-1), obj, SIZE)
    assert bool(choice.kept[0]) and usual.board_warp is None
    assert ((choice.warp[0] - truth).abs() < 4 * choice.std[0]).all() and (choice.std[0] < 1e-4).all()
    assert choice.heldout_warp[0] < 0.5 * choice.heldout_flat[0]
    assert choice.result.rms[0] < 0.5 * usual.rms[0]
    assert torch.allclose(choice.result.board_warp[0], choice.warp[0])


def test_fisheye_flat_board_stays_flat():
    obj, uv = _fisheye_views([0.0, 0.0])
    solver = CalibrationSolver(model=FISHEYE)
    usual = solver(uv, None, obj, SIZE)
    choice = choose_board_warp(solver, usual, uv, uv.isfinite().all(-1), obj, SIZE)
    assert not bool(choice.kept[0])
    assert torch.equal(choice.result.camera.params, usual.camera.params) and (choice.result.board_warp == 0).all()
    assert torch.equal(choice.result.rvec, usual.rvec) and torch.equal(choice.result.tvec, usual.tvec)
