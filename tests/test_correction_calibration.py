"""Tests of the pieces the distortion-corrected calibration is built from: pooled corrections, OpenCV-model
undistortion, the image-centred radial refinement and the solver's warm starts."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.camera import board_object_points, project_points, radial_undistort_points
from ccs_kornia.data.scenes import make_calibration_set
from ccs_kornia.metrics import e_ip
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.centred_radial import (
    centred_radial_distort,
    radial_from_correction,
    refine_centred_radial,
)
from ccs_kornia.modules.correction.pooling import aggregate_corrections, correction_displacement
from ccs_kornia.modules.correction.radial_warp import correct_points
from ccs_kornia.modules.correction.correction_fit import fit_correction_to_points
from ccs_kornia.modules.correction.opencv_warp import (
    opencv_distorted_frame,
    opencv_undistort_image,
    opencv_undistorted_frame,
)

SIZE = (640, 480)
OBJ = board_object_points(9, 6, 0.025, dtype=torch.float64)


def _views(K: torch.Tensor, num: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    rvec = 0.6 * (torch.rand(num, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.stack([0.1 * (torch.rand(num, generator=g, dtype=torch.float64) - 0.5) - 0.1,
                        0.1 * (torch.rand(num, generator=g, dtype=torch.float64) - 0.5) - 0.06,
                        0.35 + 0.1 * torch.rand(num, generator=g, dtype=torch.float64)], -1)
    return rvec, tvec


# ----------------------------------------------------------------------------------------------
# pooled corrections
# ----------------------------------------------------------------------------------------------


def test_aggregate_is_robust_to_one_bad_view_and_masks():
    good = torch.tensor([1.0, 0.0, 0.25, 0.0, 0.05], dtype=torch.float64)
    views = good.expand(1, 5, 5).clone()
    views[0, 2] = torch.tensor([1.0, 0.0, -0.8, 0.0, 0.0])  # one wild view
    pooled = aggregate_corrections(views, SIZE)
    assert pooled.shape == (1, 5)
    r = torch.linspace(0, 0.62, 20, dtype=torch.float64)
    poly = lambda c: r * (c[0] + r * (c[1] + r * (c[2] + r * (c[3] + r * c[4]))))  # noqa: E731
    assert float((poly(pooled[0]) - poly(good)).abs().max()) < 1e-6  # the median ignores it
    mask = torch.tensor([[False] * 5])
    torch.testing.assert_close(aggregate_corrections(views, SIZE, mask), torch.tensor([[1.0, 0, 0, 0, 0]], dtype=torch.float64))
    with pytest.raises(ValueError, match="corrections"):
        aggregate_corrections(torch.zeros(3, 5), SIZE)
    with pytest.raises(ValueError, match="mask"):
        aggregate_corrections(views, SIZE, torch.ones(2, 5, dtype=torch.bool))


def test_correction_displacement():
    ident = torch.tensor([[1.0, 0, 0, 0, 0]])
    assert float(correction_displacement(ident, SIZE)) == 0.0
    c = torch.tensor([[1.0, 0.0, 0.2, 0.0, 0.0]], dtype=torch.float64)
    corner = torch.tensor([[[0.0, 0.0]]], dtype=torch.float64)
    moved = float((correct_points(corner, c, SIZE) - corner).norm())
    assert float(correction_displacement(c, SIZE)) == pytest.approx(moved, rel=1e-3)


def test_fit_correction_to_points_recovers_coefficients_and_fixes_k0():
    g = torch.Generator().manual_seed(0)
    c = torch.tensor([[1.0, 0.05, 0.3, -0.1, 0.2], [1.0, 0.0, -0.1, 0.0, 0.0]], dtype=torch.float64)
    p = torch.rand(2, 80, 2, generator=g, dtype=torch.float64) * torch.tensor([639.0, 479.0], dtype=torch.float64)
    torch.testing.assert_close(fit_correction_to_points(p, correct_points(p, c, SIZE), SIZE), c)
    zoomed = c.clone()
    zoomed[:, 0] = 1.1
    free = fit_correction_to_points(p, correct_points(p, zoomed, SIZE), SIZE, fix_k0=False)
    torch.testing.assert_close(free, zoomed)
    assert bool((fit_correction_to_points(p, correct_points(p, zoomed, SIZE), SIZE)[:, 0] == 1).all())


# ----------------------------------------------------------------------------------------------
# OpenCV-model undistortion
# ----------------------------------------------------------------------------------------------


def test_opencv_undistort_image_matches_cv2():
    K = torch.tensor([[[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    dist = torch.tensor([[-0.3, 0.1, 0.001, -0.0005, 0.0]], dtype=torch.float64)
    s = make_calibration_set(K[0].float(), (9, 6), 0.025, SIZE, num_views=1, supersample=1, seed=3)
    img = s.images[0, 0].numpy()
    ours = opencv_undistort_image(s.images, K, dist)[0, 0].numpy()
    ref = cv2.undistort(img.astype(np.float32), K[0].numpy(), dist[0].numpy())
    inner = (slice(40, 440), slice(40, 600))
    assert np.abs(ours[inner] - ref[inner]).mean() < 2e-3


def test_opencv_frame_maps_round_trip_and_zoom():
    K = torch.tensor([[[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    dist = torch.tensor([[-0.3, 0.1, 0.001, -0.0005, 0.0]], dtype=torch.float64)
    p = torch.tensor([[[100.0, 80.0], [320.0, 240.0], [600.0, 400.0]]], dtype=torch.float64)
    for zoom in (1.0, 0.7):
        u = opencv_undistorted_frame(p, K, dist, zoom)
        torch.testing.assert_close(opencv_distorted_frame(u, K, dist, zoom), p, atol=1e-6, rtol=0)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    ref = cv2.undistortPoints(p[0].numpy().reshape(-1, 1, 2), K[0].numpy(), dist[0].numpy(), R=None, P=K[0].numpy(),
                              criteria=criteria)
    np.testing.assert_allclose(opencv_undistorted_frame(p, K, dist)[0].numpy(), ref.reshape(-1, 2), atol=1e-4)


# ----------------------------------------------------------------------------------------------
# image-centred radial refinement
# ----------------------------------------------------------------------------------------------


def _centred_set(K, k, offset, views=12, seed=0, noise=0.0):
    rvec, tvec = _views(K, views, seed)
    ideal = project_points(OBJ.expand(views, -1, -1), K.expand(views, 3, 3), None, rvec, tvec)
    off = None if offset is None else torch.tensor([offset], dtype=torch.float64)
    uv = centred_radial_distort(ideal.reshape(1, -1, 2), torch.tensor([k], dtype=torch.float64), SIZE, off)
    uv = uv.reshape(1, views, -1, 2)
    if noise:
        uv = uv + noise * torch.randn(uv.shape, generator=torch.Generator().manual_seed(seed + 1), dtype=torch.float64)
    return uv, rvec[None], tvec[None]


def test_centred_radial_recovers_camera_with_and_without_free_centre():
    K = torch.tensor([[430.0, 0.0, 329.0], [0.0, 433.0, 233.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    uv, rvec, tvec = _centred_set(K, [-0.5, 0.1, 0.0], None)
    valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
    K0 = (torch.diag(torch.tensor([1.03, 0.98, 1.0], dtype=torch.float64)) @ K)[None]
    K1, k1, rv, tv, rms, centre, std = refine_centred_radial(uv, valid, OBJ, K0, rvec, tvec, torch.zeros(1, 3), SIZE)
    assert float(e_ip(K1, K[None])) < 1e-4 and float(rms) < 1e-6 and float(centre.abs().max()) == 0
    assert rv.shape == (1, 12, 3) and std.shape == (1, 4)
    # a distortion centred 12 px off the image centre is found with free_centre (exact data: exactly) ...
    uv, rvec, tvec = _centred_set(K, [-0.5, 0.1, 0.0], [9.0, -8.0])
    K1, _, _, _, rms, centre, _ = refine_centred_radial(uv, valid, OBJ, K0, rvec, tvec, torch.zeros(1, 3), SIZE,
                                                        free_centre=True)
    assert float(e_ip(K1, K[None])) < 1e-3 and float(rms) < 1e-6
    torch.testing.assert_close(centre, torch.tensor([[9.0, -8.0]], dtype=torch.float64), atol=1e-3, rtol=0)
    # ... and with noise the estimate stays within a few standard deviations (the centre costs precision)
    uv, rvec, tvec = _centred_set(K, [-0.5, 0.1, 0.0], [9.0, -8.0], noise=0.02)
    K1, _, _, _, rms, centre, std = refine_centred_radial(uv, valid, OBJ, K0, rvec, tvec, torch.zeros(1, 3), SIZE,
                                                          free_centre=True)
    err = (K1[0, [0, 1, 0, 1], [0, 1, 2, 2]] - K[[0, 1, 0, 1], [0, 1, 2, 2]]).abs()
    assert float(rms) < 0.03 and bool((std > 0).all()) and bool((err < 4 * std[0] + 1e-3).all()), (err, std)


def test_centred_radial_batch_and_exceptions():
    K = torch.tensor([[430.0, 0.0, 319.5], [0.0, 430.0, 239.5], [0.0, 0.0, 1.0]], dtype=torch.float64)
    a = _centred_set(K, [-0.3, 0.0, 0.0], None, views=6, seed=1)
    b = _centred_set(K, [-0.1, 0.0, 0.0], None, views=6, seed=2)
    uv, rv, tv = (torch.cat([x, y]) for x, y in zip(a, b))
    valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
    valid[1, 0] = False  # a missing view
    Ks = K.expand(2, 3, 3).clone()
    K1, k1, *_ = refine_centred_radial(uv, valid, OBJ, Ks, rv, tv, torch.zeros(2, 3), SIZE)
    torch.testing.assert_close(k1[:, 0], torch.tensor([-0.3, -0.1], dtype=torch.float64), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="corners"):
        refine_centred_radial(uv[0], valid, OBJ, Ks, rv, tv, torch.zeros(2, 3), SIZE)
    with pytest.raises(ValueError, match="valid"):
        refine_centred_radial(uv, valid[:, :2], OBJ, Ks, rv, tv, torch.zeros(2, 3), SIZE)
    with pytest.raises(ValueError, match="radial"):
        refine_centred_radial(uv, valid, OBJ, Ks, rv, tv, torch.zeros(2, 5), SIZE)


def test_radial_from_correction_inverts_the_paper_model():
    # the paper's distortion (k0 = 1) and the correction fitted to it: back to the same coefficients
    from ccs_kornia.camera import fit_radial_correction

    k = torch.tensor([[1.0, -0.3, -0.05]], dtype=torch.float64)
    corr = fit_radial_correction(k, SIZE)
    back = radial_from_correction(corr, SIZE)
    p = torch.tensor([[[20.0, 30.0], [600.0, 50.0], [330.0, 250.0]]], dtype=torch.float64)
    ideal = radial_undistort_points(p, k, SIZE)
    # a start for the refinement, not exact: the 5-term correction polynomial only approximates the inverse
    err = (centred_radial_distort(ideal, back, SIZE) - p).norm(dim=-1)
    assert float(err[0, 2]) < 0.05 and float(err.max()) < 2.0, err


# ----------------------------------------------------------------------------------------------
# solver warm starts
# ----------------------------------------------------------------------------------------------


def test_solver_init_corners_initial_and_fixed_intrinsics():
    K = torch.tensor([[430.0, 0.0, 322.0], [0.0, 433.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    dist = torch.tensor([-0.35, 0.12, 0.0, 0.0, -0.02], dtype=torch.float64)
    rvec, tvec = _views(K, 12, 4)
    ideal = project_points(OBJ.expand(12, -1, -1), K.expand(12, 3, 3), None, rvec, tvec)
    uv = project_points(OBJ.expand(12, -1, -1), K.expand(12, 3, 3), dist.expand(12, 5), rvec, tvec)
    valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
    solver = CalibrationSolver()
    plain = solver(uv, valid, OBJ, SIZE)
    started = solver(uv, valid, OBJ, SIZE, init_corners=ideal)
    for r in (plain, started):
        assert float(e_ip(r.K, K)) < 1e-4 and float(r.rms) < 1e-6
    warm = solver(uv, valid, OBJ, SIZE, initial=started)
    torch.testing.assert_close(warm.K, started.K)
    shifted = started.K.clone()
    shifted[0, 0] += 2.0
    from dataclasses import replace

    fixed = solver(uv, valid, OBJ, SIZE, initial=replace(started, K=shifted), fix_intrinsics=True)
    assert float(fixed.K[0, 0]) == float(shifted[0, 0]) and float(fixed.rms) > 1e-3
    with pytest.raises(ValueError, match="fix_intrinsics"):
        solver(uv, valid, OBJ, SIZE, fix_intrinsics=True)
    with pytest.raises(ValueError, match="init_corners"):
        solver(uv, valid, OBJ, SIZE, init_corners=ideal[:3])
