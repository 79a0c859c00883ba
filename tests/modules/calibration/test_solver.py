"""Tests of the image-level RANSAC and the calibration solver, against OpenCV on rendered and real sets."""

from __future__ import annotations

import glob
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from _board_views import all_valid, synthetic
from _real_data import REAL_DATA

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models import K1K2, OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.modules.calibration.homography import find_homographies
from ccs_kornia.modules.calibration.ransac import ImageRansac
from ccs_kornia.modules.calibration.result import VIEW_REASONS, ViewReason
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.calibration.solver import CalibrationSolver

F64 = torch.float64
IMAGE_SIZE = (640, 480)
DIST5 = torch.tensor([-0.28, 0.09, 1e-3, -8e-4, -0.02], dtype=F64)


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
        rejected = ViewReason.RANSAC_REJECTED
        assert res.view_reason[0, 3] == rejected and res.view_reason[1, 7] == rejected and res.used.sum() == 28
        assert VIEW_REASONS[ViewReason.RANSAC_REJECTED].startswith("rejected")
        # without RANSAC the post-refinement check still finds them (but the corrupted LM start is worse)
        res_nr = CalibrationSolver(use_ransac=False)(bad, valid, obj, IMAGE_SIZE)
        assert not res_nr.used[0, 3] and not res_nr.used[1, 7] and (res_nr.K - K).abs().max() < 1e-6

    def test_ransac_shortcut_gives_the_full_ransac_result(self):
        from ccs_kornia.modules.calibration.ransac import image_ransac

        for dist, noise, seed in [(None, 0.1, 3), (DIST5, 0.3, 5), (DIST5 * 3, 0.1, 7)]:
            K, obj, uv, _, _ = synthetic(C=3, V=12, dist=dist, noise=noise, seed=seed)
            H = find_homographies(obj[:, :2], uv, all_valid(uv))
            for views in (uv, corrupt(uv)):  # all views consistent (shortcut), and gross outliers (full RANSAC)
                args = (H, views, all_valid(views), obj, None, IMAGE_SIZE)
                fast = image_ransac(*args, generator=torch.Generator().manual_seed(0))
                full = image_ransac(*args, generator=torch.Generator().manual_seed(0), early_accept=False)
                assert torch.equal(fast[0], full[0])
                torch.testing.assert_close(fast[1], full[1], atol=1e-9, rtol=1e-12)

    def test_ransac_result_of_a_camera_does_not_depend_on_the_batch(self):
        # strict thresholds make the inliers depend on the random subsets: a camera must get the same ones alone,
        # in a batch with other cameras, and padded with empty views (calibrate vs calibrate-many, ragged sets)
        from ccs_kornia.modules.calibration.ransac import image_ransac

        K, obj, uv, _, _ = synthetic(C=3, V=12, dist=DIST5 * 1.5, noise=0.2, seed=12)
        valid = all_valid(uv)
        H = find_homographies(obj[:, :2], uv, valid)
        strict = dict(image_size=IMAGE_SIZE, abs_threshold=0.0, rel_threshold=1.0, early_accept=False)
        alone = image_ransac(H[:1], uv[:1], valid[:1], obj, generator=torch.Generator().manual_seed(0), **strict)
        batch = image_ransac(H, uv, valid, obj, generator=torch.Generator().manual_seed(0), **strict)
        pad = lambda x, fill: torch.cat([x, torch.full((3, 3, *x.shape[2:]), fill, dtype=x.dtype)], 1)  # noqa: E731
        padded = image_ransac(pad(H, float("nan")), pad(uv, 0.0), pad(valid, False), obj,
                              generator=torch.Generator().manual_seed(0), **strict)
        assert 3 <= int(alone[0].sum()) < 12  # the subsets matter here
        assert torch.equal(alone[0][0], batch[0][0]) and torch.equal(alone[0][0], padded[0][0, :12])
        assert not padded[0][:, 12:].any()
        torch.testing.assert_close(alone[1][0], batch[1][0], atol=1e-9, rtol=1e-12)
        torch.testing.assert_close(alone[1][0], padded[1][0], atol=1e-9, rtol=1e-12)

    def test_no_per_call_state(self):
        K, obj, uv, _, _ = synthetic(C=1, V=10, dist=DIST5, noise=0.1, seed=4)
        solver = CalibrationSolver()
        before = dict(solver.__dict__)
        first = solver(uv, None, obj, IMAGE_SIZE)
        solver(uv, None, obj, IMAGE_SIZE, initial=first, fix_intrinsics=True)
        assert solver.__dict__.keys() == before.keys() and not hasattr(solver, "_fix_intrinsics")
        assert all(solver.__dict__[k] is v for k, v in before.items() if k != "_modules")
        again = solver(uv, None, obj, IMAGE_SIZE)  # a fixed-intrinsics call leaves nothing behind
        torch.testing.assert_close(again.K, first.K, atol=0, rtol=0)
        assert not first.K.is_inference()  # results are ordinary tensors (the solve runs in inference mode)

    def test_views_rejected_for_unmodelled_distortion_are_readmitted(self):
        K, obj, uv, _, _ = synthetic(C=2, V=12, dist=DIST5 * 1.5, seed=12)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        strict = dict(abs_threshold=0.0, rel_threshold=1.0)  # rejects about half the (good) views
        inliers, _ = ImageRansac(**strict)(H[0], uv[0], all_valid(uv[0]), obj, image_size=IMAGE_SIZE)
        assert inliers.shape == (12,) and 3 <= int(inliers.sum()) < 12  # unbatched input works too
        res = CalibrationSolver(ransac_abs_threshold=0.0, ransac_rel_threshold=1.0)(uv, all_valid(uv), obj, IMAGE_SIZE)
        assert res.used.all() and (res.K - K).abs().max() < 1e-6 and res.rms.max() < 1e-6

    @pytest.mark.parametrize("model,dist", [(PINHOLE, None), (OPENCV5, DIST5)])
    def test_exact_batch(self, model, dist):
        K, obj, uv, _, _ = synthetic(C=4, V=15, dist=dist, seed=4)
        res = CalibrationSolver(model=model)(uv, all_valid(uv), obj, IMAGE_SIZE)
        assert res.success.all() and res.used.all() and (res.lm_status == LMStatus.CONVERGED).all()
        assert (res.K - K).abs().max() < 1e-3 and res.rms.max() < 1e-6
        assert res.dist.shape == (4, 5 if model == OPENCV5 else 0) and res.camera.model == model

    def test_rational_exact(self):
        dist8 = torch.tensor([-0.2, 0.05, 1e-3, -2e-3, 0.01, 0.05, 0.01, 0.002], dtype=F64)
        K, obj, uv, _, _ = synthetic(C=1, V=15, dist=dist8, seed=6)
        res = CalibrationSolver(model=RATIONAL)(uv[0], all_valid(uv[0]), obj, IMAGE_SIZE)
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
        # camera 1's two views fit (too few to use them), camera 3 has nothing to fit
        assert res.lm_status.tolist() == [LMStatus.CONVERGED] * 3 + [LMStatus.NO_DATA]
        assert res.K[[1, 3]].isnan().all() and res.K[[0, 2]].isfinite().all()
        assert (res.K[0] - K[0]).abs().max() < 1e-6 and not res.used[3].any()
        few = ViewReason.TOO_FEW_CORNERS
        assert res.view_reason[1, 2:].eq(few).all() and res.view_reason[2, 0] == few and res.used[2].sum() == 3
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
            CalibrationSolver(model="kannala")

    def test_opencv_flags_agree_on_noisy_corners(self):
        K, obj, uv, _, _ = synthetic(C=1, V=15, dist=DIST5, noise=0.1, seed=9)
        o = obj.numpy().astype(np.float32)
        ip = [p.numpy().astype(np.float32).reshape(-1, 1, 2) for p in uv[0]]
        K_init = np.array([[1.0, 0, 319.5], [0, 1.0, 239.5], [0, 0, 1]])
        flags = cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_PRINCIPAL_POINT
        rms_cv, K_cv, *_ = cv2.calibrateCamera([o] * 15, ip, IMAGE_SIZE, K_init, None, flags=flags)
        res = CalibrationSolver(fix_aspect_ratio=True, fix_principal_point=True)(uv, all_valid(uv), obj, IMAGE_SIZE)
        assert np.abs(res.K[0].numpy() - K_cv).max() < 1e-3 and abs(float(res.rms[0]) / rms_cv - 1) < 1e-5


REAL_SETS = [
    # set, board, square (mm), our model, OpenCV flags, key in opencv_results.json
    ("opencv_left", (9, 6), 25.0, OPENCV5, 0, "calib_classic_default"),
    ("boofcv_sony_hx5v", (4, 6), 30.0, K1K2, cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
     "calib_classic_k1k2_notan"),
    ("boofcv_bumblebee2_left", (4, 6), 30.0, K1K2, cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
     "calib_classic_k1k2_notan"),
]


@pytest.fixture(scope="module")
def real_root() -> Path:
    root = REAL_DATA
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
