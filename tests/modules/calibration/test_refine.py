"""Tests of the joint Levenberg-Marquardt refinement (the LM core with the OpenCV model) and its analytic Jacobians."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from _board_views import all_valid, synthetic

from ccs_kornia.geometry.camera import axis_angle_to_rotation_matrix
from ccs_kornia.geometry.metrics import e_ip
from ccs_kornia.geometry.models import K1K2, OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.modules.calibration.refinement import JointRefinement, joint_refinement
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.calibration.solver import CalibrationSolver

F64 = torch.float64
IMAGE_SIZE = (640, 480)
DIST5 = torch.tensor([-0.28, 0.09, 1e-3, -8e-4, -0.02], dtype=F64)


def _pose_jacobian(q: torch.Tensor, Jx: torch.Tensor) -> torch.Tensor:
    """d uv / d (w, dt) for ``R <- exp(w) R, t <- t + dt`` at 0, as the LM core builds it from d uv / d Xc."""
    return torch.cat([torch.linalg.cross(q[..., None, :].expand_as(Jx), Jx, dim=-1), Jx], -1)


class TestRefinement:
    def test_projection_and_jacobians(self):
        dist8 = torch.tensor([-0.2, 0.05, 1e-3, -2e-3, 0.01, 0.01, 2e-3, 3e-3], dtype=F64)
        K, obj, uv, rvec, tvec = synthetic(C=2, V=3, dist=dist8)
        R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(2, 3, 3, 3)
        q = torch.einsum("cvij,nj->cvni", R, obj)
        m = RATIONAL
        p = m.params_from(K, dist8.expand(2, 8))
        out, J, Jx = m.project(q + tvec[:, :, None], p)
        assert (out - uv).abs().max() < 1e-9  # same model as camera.project_points (kornia distort_points)
        J_ad = torch.autograd.functional.jacobian(lambda p_: m.project(q + tvec[:, :, None], p_, False)[0], p)
        assert torch.allclose(J_ad[1, :, :, :, 1, :4], J[1, ..., :4], atol=1e-9)
        assert torch.allclose(J_ad[0, :, :, :, 0, 4:], J[0, ..., 4:], atol=1e-7)

        def moved(pose):
            dR = axis_angle_to_rotation_matrix(pose[..., :3].reshape(-1, 3)).reshape(2, 3, 3, 3)
            q_moved = torch.einsum("cvij,cvnj->cvni", dR, q)
            return m.project(q_moved + (tvec + pose[..., 3:])[:, :, None], p, False)[0]

        Jp_ad = torch.autograd.functional.jacobian(moved, torch.full((2, 3, 6), 1e-30, dtype=F64))
        assert torch.allclose(Jp_ad[1, 2, :, :, 1, 2], _pose_jacobian(q, Jx)[1, 2], atol=1e-7)

    def test_gradcheck_projection_residual(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=1)
        q = obj[None, None, :6] @ axis_angle_to_rotation_matrix(rvec[0]).transpose(-1, -2)
        p = torch.tensor([[600.0, 610.0, 320.0, 240.0, -0.1, 0.02, 1e-3, 1e-3, 0.0]], dtype=F64, requires_grad=True)
        m = OPENCV5
        res = lambda p_: m.project(q + tvec[:, :, None], p_, False)[0] - uv[:, :, :6]  # noqa: E731
        assert torch.autograd.gradcheck(res, (p,))

    @pytest.mark.parametrize(
        "model,dist", [(PINHOLE, None), (OPENCV5, DIST5), (K1K2, DIST5 * torch.tensor([1, 1, 0, 0, 0]))]
    )
    def test_exact_recovery_from_perturbed_start(self, model, dist, device):
        K, obj, uv, rvec, tvec = synthetic(C=3, V=15, dist=dist)
        K0 = K.clone()
        K0[:, 0, 0] *= 1.03
        K0[:, 1, 1] *= 0.98
        K0[:, :2, 2] += 6.0
        inputs = (uv, all_valid(uv), obj, K0, rvec + 0.02, tvec * 1.02)
        res = JointRefinement(model=model)(*(x.to(device) for x in inputs))
        assert res.K.device.type == device.type
        res = type(res)(**{k: None if v is None else v.cpu() for k, v in res.__dict__.items()})
        assert (res.status == LMStatus.CONVERGED).all()
        assert (res.K - K).abs().max() < 1e-6 and res.rms.max() < 1e-6
        if dist is not None:
            assert (res.dist - dist).abs().max() < 1e-8
        assert res.view_rms.shape == (3, 15) and res.std_intrinsics.shape == (3, 4)

    def test_a_crawl_stops_where_the_cost_stalls(self):
        # the rational model on 8 noisy views of a narrow lens: its extra coefficients are barely determined and
        # the LM crawls (to fx = 714 +- 2095 px after 1000 iterations on seed 1; the truth is 524): the stall rule
        # stops it where 10 iterations change the cost by < 1e-4, within the camera's uncertainty of the long run
        K, obj, uv, rv, tv = synthetic(C=1, V=8, dist=DIST5, noise=0.2, seed=1)
        kw = dict(model=RATIONAL, max_iters=100, ftol=1e-10, lambda_init=1e-5)
        crawl = joint_refinement(uv, all_valid(uv), obj, K * 1.02, rv, tv, **kw)
        stop = joint_refinement(uv, all_valid(uv), obj, K * 1.02, rv, tv, stall_tol=1e-4, **kw)
        assert int(crawl.iterations.max()) == 100 and int(stop.iterations.max()) <= 50
        assert (crawl.status == LMStatus.MAX_ITERATIONS).all() and (stop.status == LMStatus.STALLED).all()
        assert ((stop.rms - crawl.rms) / crawl.rms).abs().max() < 5e-3
        assert ((stop.K - crawl.K)[:, :2].abs().amax((-1, -2)) < 3 * stop.std_intrinsics.amax(-1)).all()

    def test_the_stall_rule_lets_a_converging_fit_finish(self):
        # 3 views, exact corners, OpenCV's five coefficients: 40 iterations of steady progress, cost to ~0
        K, obj, uv, rv, tv = synthetic(C=1, V=3, dist=DIST5, seed=8)
        res = joint_refinement(uv, all_valid(uv), obj, K * 1.02, rv, tv, model=OPENCV5, max_iters=100, ftol=1e-10,
                               lambda_init=1e-5, stall_tol=1e-4)
        assert bool(res.rms.max() < 1e-6)

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
            uv[0], valid[0], obj, K[0] * 1.01, rvec[0], tvec[0], view_mask=view_mask[0], model=PINHOLE
        )
        assert res.K.shape == (3, 3) and res.rms < 1e-6 and (res.K - K[0]).abs().max() < 1e-6
        assert res.view_rms[5].isnan() and res.view_rms.isfinite().sum() == 7
        # fixed aspect ratio and principal point keep their values
        K0 = K[0].clone()
        K0[0, 0] = K0[1, 1] = 700.0
        res = joint_refinement(uv[0], valid[0], obj, K0, rvec[0], tvec[0], view_mask=view_mask[0], model=PINHOLE,
                               fix_aspect_ratio=True, fix_principal_point=True)
        assert res.K[0, 0] == res.K[1, 1] and res.K[0, 2] == K0[0, 2] and res.std_intrinsics[2] == 0

    def test_std_matches_opencv(self):
        K, obj, uv, _, _ = synthetic(C=1, V=12, dist=DIST5, noise=0.2, seed=7)
        o = obj.numpy().astype(np.float32)
        ip = [p.numpy().astype(np.float32).reshape(-1, 1, 2) for p in uv[0]]
        ret = cv2.calibrateCameraExtended([o] * 12, ip, IMAGE_SIZE, None, None)
        rms_cv, K_cv, std_cv = ret[0], ret[1], ret[5].ravel()
        res = CalibrationSolver()(uv[0], all_valid(uv[0]), obj, IMAGE_SIZE)
        assert abs(float(res.rms) / rms_cv - 1) < 1e-5
        assert np.abs(res.K.numpy() - K_cv).max() < 1e-3
        ours = np.r_[res.std_intrinsics.numpy(), res.std_dist.numpy()]
        assert np.allclose(ours, std_cv[:9], rtol=2e-3)

    def test_many_views_single_camera(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=500, noise=0.1, seed=11)
        res = JointRefinement(model=PINHOLE)(uv, all_valid(uv), obj, K * 1.01, rvec, tvec)
        assert (res.status == LMStatus.CONVERGED).all() and e_ip(res.K, K).item() < 0.1
