"""Tests of the calibration solver stages: homography, Zhang, LM refinement, image RANSAC, solver, metrics."""

from __future__ import annotations

import glob
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.camera import axis_angle_to_rotation_matrix, board_object_points, project_points
from ccs_kornia.metrics import e_fl, e_ip, e_pp, per_view_rms, rms
from ccs_kornia.modules.calibration.result import VIEW_REASONS
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.calibration.homography import BatchedHomography, find_homographies
from ccs_kornia.modules.calibration.ransac import ImageRansac
from ccs_kornia.modules.calibration.refine import JointRefinement, joint_refinement
from ccs_kornia.modules.calibration.projection import project_with_jacobians
from ccs_kornia.modules.calibration.zhang import ZhangInit, extrinsics_from_homography, zhang_intrinsics

F64 = torch.float64
IMAGE_SIZE = (640, 480)
DIST5 = torch.tensor([-0.28, 0.09, 1e-3, -8e-4, -0.02], dtype=F64)


def synthetic(C=1, V=15, cols=9, rows=6, square=0.03, dist=None, noise=0.0, seed=0):
    """Random cameras and board poses (board inside a 640x480 image); float64 ground truth."""
    g = torch.Generator().manual_seed(seed)

    def rand(*s):
        return torch.rand(*s, generator=g, dtype=F64)

    fx = 500 + 400 * rand(C)
    K = torch.zeros(C, 3, 3, dtype=F64)
    K[:, 0, 0], K[:, 1, 1] = fx, fx * (0.95 + 0.1 * rand(C))
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = 320 + 30 * (rand(C) - 0.5), 240 + 30 * (rand(C) - 0.5), 1
    obj = board_object_points(cols, rows, square, dtype=F64)
    axis = torch.nn.functional.normalize(torch.randn(C, V, 3, generator=g, dtype=F64), dim=-1)
    rvec = axis * (0.15 + 0.55 * rand(C, V))[..., None]
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(C, V, 3, 3)
    depth = (fx[:, None] / 500) * 0.5 * (0.8 + 0.5 * rand(C, V)) * (cols * square / 0.27)
    tvec = torch.cat([(rand(C, V, 2) - 0.5) * 0.1, depth[..., None]], -1) - R @ obj.mean(0)
    d = None if dist is None else dist.to(F64).expand(C, -1)[:, None].expand(C, V, -1)
    uv = project_points(obj.expand(C, V, -1, -1), K[:, None].expand(C, V, 3, 3), d, rvec, tvec)
    uv = uv + noise * torch.randn(uv.shape, generator=g, dtype=F64)
    return K, obj, uv, rvec, tvec


def all_valid(uv):
    return torch.ones(uv.shape[:-1], dtype=torch.bool)


# --------------------------------------------------------------------------------------------- homography
class TestHomography:
    def test_exact_and_shapes(self):
        K, obj, uv, rvec, tvec = synthetic(C=2, V=3)
        H, ok = find_homographies(obj[:, :2], uv, all_valid(uv), return_ok=True)
        assert H.shape == (2, 3, 3, 3) and ok.shape == (2, 3) and ok.all()
        xy1 = torch.cat([obj[:, :2], torch.ones(54, 1, dtype=F64)], -1)
        p = torch.einsum("cvij,nj->cvni", H, xy1)
        assert (p[..., :2] / p[..., 2:] - uv).abs().max() < 1e-8
        # unbatched and module form agree
        H1 = BatchedHomography()(obj[:, :2], uv[0, 1], None)
        assert torch.allclose(H1, H[0, 1], atol=1e-9)

    def test_weights_ignore_masked_garbage(self):
        K, obj, uv, _, _ = synthetic(C=1, V=2)
        valid = all_valid(uv)
        bad = uv.clone()
        bad[0, 0, :10] = float("nan")
        bad[0, 1, :10] += 50.0
        valid[:, :, :10] = False
        H = find_homographies(obj[:, :2], bad, valid)
        H_ref = find_homographies(obj[:, :2], uv, all_valid(uv))
        assert H.isfinite().all() and torch.allclose(H, H_ref, atol=1e-7)

    def test_too_few_points_gives_identity_and_flag(self):
        K, obj, uv, _, _ = synthetic(C=1, V=3)
        valid = all_valid(uv)
        valid[0, 1, 3:] = False  # 3 points
        valid[0, 2] = False  # no points (padded view)
        uv[0, 2] = float("nan")
        H, ok = find_homographies(obj[:, :2], uv, valid, return_ok=True)
        assert ok.tolist() == [[True, False, False]]
        assert H.isfinite().all() and torch.equal(H[0, 1], torch.eye(3, dtype=F64))

    def test_exceptions(self):
        with pytest.raises(ValueError):
            find_homographies(torch.zeros(5, 2), torch.zeros(4, 2))
        with pytest.raises(ValueError):
            find_homographies(torch.zeros(3, 2), torch.zeros(3, 2))
        with pytest.raises(ValueError):
            find_homographies(torch.zeros(5, 2), torch.zeros(5, 3))

    def test_gradcheck(self):
        obj = board_object_points(3, 2, 1.0, dtype=F64)[:, :2]
        img = (obj * 40 + torch.tensor([100.0, 80.0], dtype=F64)).requires_grad_(True)
        img2 = img.detach() + torch.randn(6, 2, generator=torch.Generator().manual_seed(0), dtype=F64)
        img2.requires_grad_(True)
        assert torch.autograd.gradcheck(lambda p: find_homographies(obj, p), (img2,))


# --------------------------------------------------------------------------------------------- zhang
class TestZhang:
    def test_exact_batch(self):
        K, obj, uv, rvec, tvec = synthetic(C=3, V=10)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        K0, ok = zhang_intrinsics(H, image_size=IMAGE_SIZE, return_ok=True)
        assert ok.all() and (K0 - K).abs().max() < 1e-6
        # float32 homographies still give a usable K
        K32 = zhang_intrinsics(H.float(), image_size=IMAGE_SIZE)
        assert K32.dtype == torch.float32 and (K32.double() - K).abs().max() < 1.0
        r, t = extrinsics_from_homography(K0, H)
        assert (r - rvec).abs().max() < 1e-8 and (t - tvec).abs().max() < 1e-8

    def test_few_views_and_modes(self):
        K, obj, uv, _, _ = synthetic(C=2, V=4, seed=3)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        K2 = zhang_intrinsics(H[:, :2], image_size=IMAGE_SIZE, principal_point="estimate")
        assert (K2 - K).abs().max() < 1e-5  # zero skew: two views determine the camera
        # one view: principal point assumed at the centre, focal lengths still sensible
        K1, ok = zhang_intrinsics(H[:, :1], image_size=IMAGE_SIZE, return_ok=True)
        assert ok.all() and torch.allclose(K1[:, :2, 2], torch.tensor([319.5, 239.5], dtype=F64).expand(2, 2))
        assert ((K1[:, 0, 0] / K[:, 0, 0]) - 1).abs().max() < 0.2
        # fixed aspect ratio
        Kfa = zhang_intrinsics(H, image_size=IMAGE_SIZE, fix_aspect_ratio=True)
        assert torch.allclose(Kfa[:, 0, 0], Kfa[:, 1, 1])
        # the mask removes garbage views; no views at all -> finite fallback, not ok
        Hg = H.clone()
        Hg[:, 3] = torch.randn(2, 3, 3, dtype=F64)
        mask = torch.tensor([[True, True, True, False], [False, False, False, False]])
        Km, okm = zhang_intrinsics(Hg, mask, image_size=IMAGE_SIZE, return_ok=True)
        assert okm.tolist() == [True, False] and Km.isfinite().all()
        assert (Km[0] - K[0]).abs().max() < 1e-5
        with pytest.raises(ValueError):
            zhang_intrinsics(H, principal_point="centre")
        with pytest.raises(ValueError):
            zhang_intrinsics(H[0, 0])

    def test_module_and_board_in_front(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=5)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        K0, r, t, ok = ZhangInit()(-H, image_size=IMAGE_SIZE)  # homographies are defined up to sign
        assert ok.all() and (t[..., 2] > 0).all() and (t - tvec).abs().max() < 1e-8


# --------------------------------------------------------------------------------------------- refinement
class TestRefinement:
    def test_projection_and_jacobians(self):
        dist8 = torch.tensor([-0.2, 0.05, 1e-3, -2e-3, 0.01, 0.01, 2e-3, 3e-3], dtype=F64)
        K, obj, uv, rvec, tvec = synthetic(C=2, V=3, dist=dist8)
        R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(2, 3, 3, 3)
        q = torch.einsum("cvij,nj->cvni", R, obj)
        intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
        d = dist8.expand(2, 8).clone()
        out, Ji, Jd, Jp = project_with_jacobians(q, tvec, intr, d)
        assert (out - uv).abs().max() < 1e-9  # same model as camera.project_points (kornia distort_points)
        Ji_ad, Jd_ad = torch.autograd.functional.jacobian(
            lambda i, k: project_with_jacobians(q, tvec, i, k, False)[0], (intr, d)
        )
        assert torch.allclose(Ji_ad[1, :, :, :, 1], Ji[1], atol=1e-9)
        assert torch.allclose(Jd_ad[0, :, :, :, 0], Jd[0], atol=1e-7)

        def moved(pose):
            dR = axis_angle_to_rotation_matrix(pose[..., :3].reshape(-1, 3)).reshape(2, 3, 3, 3)
            q_moved = torch.einsum("cvij,cvnj->cvni", dR, q)
            return project_with_jacobians(q_moved, tvec + pose[..., 3:], intr, d, False)[0]

        Jp_ad = torch.autograd.functional.jacobian(moved, torch.full((2, 3, 6), 1e-30, dtype=F64))
        assert torch.allclose(Jp_ad[1, 2, :, :, 1, 2], Jp[1, 2], atol=1e-7)

    def test_gradcheck_projection_residual(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=1)
        q = obj[None, None, :6] @ axis_angle_to_rotation_matrix(rvec[0]).transpose(-1, -2)
        intr = torch.tensor([[600.0, 610.0, 320.0, 240.0]], dtype=F64, requires_grad=True)
        d = torch.tensor([[-0.1, 0.02, 1e-3, 1e-3, 0.0, 0.0, 0.0, 0.0]], dtype=F64, requires_grad=True)
        res = lambda i, k: project_with_jacobians(q, tvec, i, k, False)[0] - uv[:, :, :6]  # noqa: E731
        assert torch.autograd.gradcheck(res, (intr, d))

    @pytest.mark.parametrize(
        "model,dist", [("none", None), ("opencv5", DIST5), ("k1k2", DIST5 * torch.tensor([1, 1, 0, 0, 0]))]
    )
    def test_exact_recovery_from_perturbed_start(self, model, dist):
        K, obj, uv, rvec, tvec = synthetic(C=3, V=15, dist=dist)
        K0 = K.clone()
        K0[:, 0, 0] *= 1.03
        K0[:, 1, 1] *= 0.98
        K0[:, :2, 2] += 6.0
        res = JointRefinement(model=model)(uv, all_valid(uv), obj, K0, rvec + 0.02, tvec * 1.02)
        assert res.converged.all()
        assert (res.K - K).abs().max() < 1e-6 and res.rms.max() < 1e-6
        if dist is not None:
            assert (res.dist - dist).abs().max() < 1e-8
        assert res.view_rms.shape == (3, 15) and res.std_intrinsics.shape == (3, 4)

    def test_masks_unbatched_and_fixed_parameters(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=8, seed=5)
        valid = all_valid(uv)
        uv = uv.clone()
        uv[0, 2, :20] = float("nan")
        valid[0, 2, :20] = False
        view_mask = torch.ones(1, 8, dtype=torch.bool)
        view_mask[0, 5] = False
        uv[0, 5] += 100.0  # unused view: garbage must not matter
        res = joint_refinement(
            uv[0], valid[0], obj, K[0] * 1.01, rvec[0], tvec[0], view_mask=view_mask[0], model="none"
        )
        assert res.K.shape == (3, 3) and res.rms < 1e-6 and (res.K - K[0]).abs().max() < 1e-6
        assert res.view_rms[5].isnan() and res.view_rms.isfinite().sum() == 7
        # fixed aspect ratio and principal point keep their values
        K0 = K[0].clone()
        K0[0, 0] = K0[1, 1] = 700.0
        res = joint_refinement(uv[0], valid[0], obj, K0, rvec[0], tvec[0], view_mask=view_mask[0], model="none",
                               fix_aspect_ratio=True, fix_principal_point=True)
        assert res.K[0, 0] == res.K[1, 1] and res.K[0, 2] == K0[0, 2] and res.std_intrinsics[2] == 0

    def test_std_matches_opencv(self):
        K, obj, uv, _, _ = synthetic(C=1, V=12, dist=DIST5, noise=0.2, seed=7)
        o = obj.numpy().astype(np.float32)
        ip = [p.numpy().astype(np.float32).reshape(-1, 1, 2) for p in uv[0]]
        ret = cv2.calibrateCameraExtended([o] * 12, ip, IMAGE_SIZE, None, None)
        rms_cv, K_cv, D_cv, std_cv = ret[0], ret[1], ret[2], ret[5].ravel()
        res = CalibrationSolver()(uv[0], all_valid(uv[0]), obj, IMAGE_SIZE)
        assert abs(float(res.rms) / rms_cv - 1) < 1e-5
        assert np.abs(res.K.numpy() - K_cv).max() < 1e-3
        ours = np.r_[res.std_intrinsics.numpy(), res.std_dist.numpy()]
        assert np.allclose(ours, std_cv[:9], rtol=2e-3)

    def test_many_views_single_camera(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=500, noise=0.1, seed=11)
        res = JointRefinement(model="none")(uv, all_valid(uv), obj, K * 1.01, rvec, tvec)
        assert res.converged.all() and e_ip(res.K, K).item() < 0.1


# --------------------------------------------------------------------------------------------- ransac + solver
def corrupt(uv, cols=9, rows=6):
    """Camera 0 view 3: rows 3..5 shifted by one square (grid mis-organised); camera 1 view 7: scrambled order."""
    bad = uv.clone()
    step = uv[0, 3, 1] - uv[0, 3, 0]
    bad[0, 3, 3 * cols :] = uv[0, 3, 3 * cols :] + step
    perm = torch.randperm(cols * rows, generator=torch.Generator().manual_seed(0))
    bad[1, 7] = uv[1, 7, perm]
    return bad


class TestRansacAndSolver:
    def test_ransac_rejects_gross_views(self):
        K, obj, uv, _, _ = synthetic(C=2, V=15, dist=DIST5, seed=2)
        bad = corrupt(uv)
        valid = all_valid(bad)
        H = find_homographies(obj[:, :2], bad, valid)
        ransac = ImageRansac(seed=0)
        inliers, K0 = ransac(H, bad, valid, obj, image_size=IMAGE_SIZE)
        assert not inliers[0, 3] and not inliers[1, 7] and inliers.sum() == 28
        inliers2, K02 = ransac(H, bad, valid, obj, image_size=IMAGE_SIZE)
        assert torch.equal(inliers, inliers2) and torch.equal(K0, K02)  # seeded
        res = CalibrationSolver()(bad, valid, obj, IMAGE_SIZE)
        assert res.success.all() and (res.K - K).abs().max() < 1e-6 and res.rms.max() < 1e-6
        assert res.view_reason[0, 3] == 3 and res.view_reason[1, 7] == 3 and res.used.sum() == 28
        assert VIEW_REASONS[3].startswith("rejected")
        # without RANSAC the post-refinement check still finds them (but the corrupted LM start is worse)
        res_nr = CalibrationSolver(use_ransac=False)(bad, valid, obj, IMAGE_SIZE)
        assert not res_nr.used[0, 3] and not res_nr.used[1, 7] and (res_nr.K - K).abs().max() < 1e-6

    def test_views_rejected_for_unmodelled_distortion_are_readmitted(self):
        K, obj, uv, _, _ = synthetic(C=2, V=12, dist=DIST5 * 1.5, seed=12)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        strict = dict(abs_threshold=0.0, rel_threshold=1.0)  # rejects about half the (good) views
        inliers, _ = ImageRansac(**strict)(H[0], uv[0], all_valid(uv[0]), obj, image_size=IMAGE_SIZE)
        assert inliers.shape == (12,) and 3 <= int(inliers.sum()) < 12  # unbatched input works too
        res = CalibrationSolver(ransac_abs_threshold=0.0, ransac_rel_threshold=1.0)(uv, all_valid(uv), obj, IMAGE_SIZE)
        assert res.used.all() and (res.K - K).abs().max() < 1e-6 and res.rms.max() < 1e-6

    @pytest.mark.parametrize("model,dist", [("none", None), ("opencv5", DIST5)])
    def test_exact_batch(self, model, dist):
        K, obj, uv, _, _ = synthetic(C=4, V=15, dist=dist, seed=4)
        res = CalibrationSolver(model=model)(uv, all_valid(uv), obj, IMAGE_SIZE)
        assert res.success.all() and res.used.all()
        assert (res.K - K).abs().max() < 1e-3 and res.rms.max() < 1e-6
        assert res.dist.shape == (4, 5 if model == "opencv5" else 0) and res.model == model

    def test_rational_exact(self):
        dist8 = torch.tensor([-0.2, 0.05, 1e-3, -2e-3, 0.01, 0.05, 0.01, 0.002], dtype=F64)
        K, obj, uv, _, _ = synthetic(C=1, V=15, dist=dist8, seed=6)
        res = CalibrationSolver(model="rational")(uv[0], all_valid(uv[0]), obj, IMAGE_SIZE)
        assert res.dist.shape == (8,) and res.rms < 1e-6 and (res.K - K[0]).abs().max() < 1e-3

    def test_failed_cameras_and_padding(self):
        K, obj, uv, _, _ = synthetic(C=4, V=6, dist=DIST5, seed=8)
        valid = all_valid(uv)
        uv = uv.clone()
        valid[1, 2:] = False  # camera 1: only 2 views
        uv[1, 2:] = float("nan")
        valid[2, 4:] = False  # camera 2: padded views, still 4 usable
        valid[2, 0, 3:] = False  # and one view with 3 corners
        valid[3] = False  # camera 3: nothing at all
        res = CalibrationSolver()(uv, valid, obj, IMAGE_SIZE)
        assert res.success.tolist() == [True, False, True, False]
        assert res.K[[1, 3]].isnan().all() and res.K[[0, 2]].isfinite().all()
        assert (res.K[0] - K[0]).abs().max() < 1e-6 and not res.used[3].any()
        assert res.view_reason[1, 2:].eq(1).all() and res.view_reason[2, 0] == 1 and res.used[2].sum() == 3
        assert res.view_rms[2, 4:].isnan().all() and res.rms[2] < 1e-6

    def test_malformed_shapes(self):
        obj = board_object_points(9, 6, 1.0, dtype=F64)
        solver = CalibrationSolver()
        with pytest.raises(ValueError):
            solver(torch.zeros(2, 3, 54, 3), None, obj, IMAGE_SIZE)
        with pytest.raises(ValueError):
            solver(torch.zeros(2, 3, 54, 2), torch.ones(2, 3, 50, dtype=torch.bool), obj, IMAGE_SIZE)
        with pytest.raises(ValueError):
            solver(torch.zeros(2, 3, 54, 2), None, obj[:50], IMAGE_SIZE)
        with pytest.raises(ValueError):
            CalibrationSolver(model="fisheye")

    def test_opencv_flags_agree_on_noisy_corners(self):
        K, obj, uv, _, _ = synthetic(C=1, V=15, dist=DIST5, noise=0.1, seed=9)
        o = obj.numpy().astype(np.float32)
        ip = [p.numpy().astype(np.float32).reshape(-1, 1, 2) for p in uv[0]]
        K_init = np.array([[1.0, 0, 319.5], [0, 1.0, 239.5], [0, 0, 1]])
        flags = cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_PRINCIPAL_POINT
        rms_cv, K_cv, *_ = cv2.calibrateCamera([o] * 15, ip, IMAGE_SIZE, K_init, None, flags=flags)
        res = CalibrationSolver(fix_aspect_ratio=True, fix_principal_point=True)(uv, all_valid(uv), obj, IMAGE_SIZE)
        assert np.abs(res.K[0].numpy() - K_cv).max() < 1e-3 and abs(float(res.rms[0]) / rms_cv - 1) < 1e-5


# --------------------------------------------------------------------------------------------- real images
REAL_SETS = [
    # set, board, square (mm), our model, OpenCV flags, key in opencv_results.json
    ("opencv_left", (9, 6), 25.0, "opencv5", 0, "calib_classic_default"),
    ("boofcv_sony_hx5v", (4, 6), 30.0, "k1k2", cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
     "calib_classic_k1k2_notan"),
    ("boofcv_bumblebee2_left", (4, 6), 30.0, "k1k2", cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
     "calib_classic_k1k2_notan"),
]


@pytest.fixture(scope="module")
def real_root() -> Path:
    root = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
    if not root.is_dir():
        pytest.skip(f"real image sets not available at {root}")
    return root


def detect_classic(setdir: Path, size):
    """Exactly as shared/data/real/verify_opencv.py (classic detector + cornerSubPix)."""
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    out = []
    for f in sorted(glob.glob(os.path.join(setdir, "*.jpg"))):
        gray = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(gray, size, cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            out.append(cv2.cornerSubPix(gray, c, (11, 11), (-1, -1), crit).reshape(-1, 2))
    return np.stack(out)


@pytest.mark.parametrize("name,size,square,model,flags,key", REAL_SETS)
def test_real_sets_match_opencv(real_root, name, size, square, model, flags, key):
    corners = detect_classic(real_root / name, size)
    ref = json.loads((real_root / name / "opencv_results.json").read_text())[key]
    assert len(corners) == ref["n_views"]
    o = np.zeros((size[0] * size[1], 3), np.float32)
    o[:, :2] = np.mgrid[0 : size[0], 0 : size[1]].T.reshape(-1, 2) * square
    rms_cv, K_cv, D_cv, _, _ = cv2.calibrateCamera(
        [o] * len(corners), [c.reshape(-1, 1, 2) for c in corners], IMAGE_SIZE, None, None, flags=flags
    )
    obj = board_object_points(size[0], size[1], square, dtype=F64)
    res = CalibrationSolver(model=model)(torch.from_numpy(corners).double(), None, obj, IMAGE_SIZE)
    ours = res.K.numpy()
    params = np.array([ours[0, 0], ours[1, 1], ours[0, 2], ours[1, 2]])
    live = np.array([K_cv[0, 0], K_cv[1, 1], K_cv[0, 2], K_cv[1, 2]])
    stored = np.array([ref["fx"], ref["fy"], ref["cx"], ref["cy"]])
    assert bool(res.success) and bool(res.used.all())  # no real view is a gross outlier
    assert abs(float(res.rms) / rms_cv - 1) < 0.01 and abs(float(res.rms) / ref["rms"] - 1) < 0.01
    assert np.abs(params - live).max() < 0.2 and np.abs(params - stored).max() < 0.2
    assert np.abs(res.dist.numpy() - D_cv.ravel()[:5]).max() < 1e-3


# --------------------------------------------------------------------------------------------- metrics
def test_metrics():
    K = torch.tensor([[502.0, 0, 321], [0, 497, 238], [0, 0, 1]])
    K_true = torch.tensor([500.0, 500.0, 320.0, 240.0])
    assert e_fl(K, K_true) == 5 and e_pp(K, K_true) == 3 and e_ip(K, K_true) == 4
    assert e_ip(K[None].expand(3, 3, 3), K_true).shape == (3,)
    proj = torch.zeros(2, 4, 2)
    obs = torch.zeros(2, 4, 2)
    obs[0, 0] = torch.tensor([3.0, 4.0])
    obs[1, 3] = float("nan")
    valid = torch.ones(2, 4, dtype=torch.bool)
    valid[1, 3] = False
    assert torch.isclose(rms(proj, obs, valid), torch.tensor((25 / 7) ** 0.5))
    assert torch.allclose(per_view_rms(proj, obs, valid), torch.tensor([2.5, 0.0]))
    with pytest.raises(ValueError):
        e_ip(torch.zeros(3), K_true)
