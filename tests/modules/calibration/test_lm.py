"""The LM core: recovery, batching, weights and covariance, parameter basis, wrappers against a dense reference."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import axis_angle_to_rotation_matrix, project_points
from ccs_kornia.geometry.models import (
    FISHEYE,
    K1K2,
    OPENCV5,
    PINHOLE,
    CentredRadialModel,
    KannalaBrandtModel,
)
from ccs_kornia.modules.calibration.lm import (
    LevenbergMarquardt,
    levenberg_marquardt,
    parameter_basis,
)
from ccs_kornia.modules.calibration.schur_lm import LMStatus

F64 = torch.float64
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
OBJ = board_object_points(9, 6, 0.03, dtype=F64)


def _poses(C, V, seed=0, depth=0.5):
    g = torch.Generator().manual_seed(seed)
    axis = torch.nn.functional.normalize(torch.randn(C, V, 3, generator=g, dtype=F64), dim=-1)
    rvec = axis * (0.15 + 0.5 * torch.rand(C, V, 1, generator=g, dtype=F64))
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(C, V, 3, 3)
    off = torch.cat([(torch.rand(C, V, 2, generator=g, dtype=F64) - 0.5) * 0.1,
                     depth * (0.8 + 0.4 * torch.rand(C, V, 1, generator=g, dtype=F64))], -1)
    return rvec, off - R @ OBJ.mean(0)


def _opencv_set(C=2, V=10, noise=0.0, seed=0, variant=OPENCV5):
    m = variant
    base = torch.tensor([520.0, 515.0, 322.0, 238.0, -0.25, 0.08, 1e-3, -8e-4, -0.02], dtype=F64)
    p = torch.stack([base * (1 + 0.02 * c) for c in range(C)])
    p = m.params_from(torch.stack([torch.tensor([[q[0], 0, q[2]], [0, q[1], q[3]], [0, 0, 1]]) for q in p]).to(F64),
                      p[:, 4:])
    rvec, tvec = _poses(C, V, seed)
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(C, V, 3, 3)
    Xc = torch.einsum("cvij,nj->cvni", R, OBJ) + tvec[:, :, None]
    uv = m.project(Xc, p, False)[0]
    g = torch.Generator().manual_seed(seed + 100)
    return m, p, rvec, tvec, uv + noise * torch.randn(uv.shape, generator=g, dtype=F64)


def _perturbed(p, rvec, tvec):
    p0 = p.clone()
    p0[:, :4] *= torch.tensor([1.02, 0.985, 1.01, 0.99], dtype=F64)
    p0[:, 4:] = 0
    return p0, rvec + 0.02, tvec * 1.02


def test_recovers_exact_camera_and_shapes():
    m, p, rvec, tvec, uv = _opencv_set()
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    res = levenberg_marquardt(m, p0, r0, t0, OBJ, uv)
    torch.testing.assert_close(res.params, p, atol=1e-6, rtol=1e-9)
    torch.testing.assert_close(res.rvec, rvec, atol=1e-9, rtol=0)
    assert bool((res.rms < 1e-8).all()) and bool((res.status == LMStatus.CONVERGED).all())
    C, V, P = 2, 10, 9
    assert res.covariance.shape == (C, P, P) and res.param_covariance.shape == (C, P, P) and res.basis.shape == (C, P, P)
    assert res.view_rms.shape == (C, V) and res.cost.shape == (C,) and res.num_points.tolist() == [540, 540]
    assert res.param_std.shape == (C, P) and res.iterations.dtype == torch.long and res.view_used.all()


@pytest.mark.parametrize("model_name", [FISHEYE, "centred_radial"])
def test_recovers_other_models(model_name):
    rvec, tvec = _poses(1, 8, seed=3, depth=0.35)
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(1, 8, 3, 3)
    Xc = torch.einsum("cvij,nj->cvni", R, OBJ) + tvec[:, :, None]
    if model_name == FISHEYE:
        m, p = KannalaBrandtModel(), torch.tensor([[300.0, 302.0, 321.0, 238.0, 0.02, -0.01, 0.002, -0.0005]], dtype=F64)
        free = None
    else:
        m = CentredRadialModel((640, 480))
        p = torch.tensor([[400.0, 405.0, 330.0, 232.0, -0.3, 0.08, 0.0, 6.0, -4.0]], dtype=F64)
        free = [True] * 6 + [False, True, True]  # k3 fixed at its true value, free centre
    uv = m.project(Xc, p, False)[0]
    p0 = p.clone()
    p0[:, :4] *= 1.01
    p0[:, 4:7] = 0
    p0[:, 7:] = 0
    res = levenberg_marquardt(m, p0, rvec + 0.01, tvec, OBJ, uv, free=free)
    assert float(res.rms) < 1e-7
    torch.testing.assert_close(res.params, p, atol=1e-5, rtol=1e-7)


def test_batch_equals_separate_calls_and_check_interval():
    m, p, rvec, tvec, uv = _opencv_set(C=3, noise=0.1)
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    valid = torch.ones(uv.shape[:-1])
    valid[1, 2] = 0  # a whole view missing on camera 1
    valid[2, 4, :30] = 0
    res = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, valid)
    for c in range(3):
        one = levenberg_marquardt(m, p0[c:c + 1], r0[c:c + 1], t0[c:c + 1], OBJ, uv[c:c + 1], valid[c:c + 1])
        torch.testing.assert_close(one.params[0], res.params[c], atol=1e-9, rtol=1e-12)
        torch.testing.assert_close(one.covariance[0], res.covariance[c], atol=1e-12, rtol=1e-8)
        assert int(one.iterations) == int(res.iterations[c])
    assert not bool(res.view_used[1, 2]) and bool(res.view_rms[1, 2].isnan())
    torch.testing.assert_close(res.rvec[1, 2], r0[1, 2])  # an unused view keeps its pose
    ten = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, valid, check_every=10)
    torch.testing.assert_close(ten.params, res.params, atol=0, rtol=0)
    assert torch.equal(ten.iterations, res.iterations)


def test_groups_stop_a_start_far_above_a_converged_one():
    """Two starts of one problem (``groups``): the far one, still 60x the near one's RMS when that converges, stops
    there instead of crawling on to ``max_iters``; the near one's solution is unchanged, and starts of different
    groups are left alone."""
    m, p, rvec, tvec, uv = _opencv_set(C=1, noise=0.1)
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    far = p0.clone()
    far[:, :2] *= 4.0
    args = (m, torch.cat([p0, far]), torch.cat([r0, r0 + 0.8]), torch.cat([t0, 1.5 * t0]), OBJ,
            uv.expand(2, -1, -1, -1))
    free = levenberg_marquardt(*args)
    grouped = levenberg_marquardt(*args, groups=torch.tensor([0, 0]))
    apart = levenberg_marquardt(*args, groups=torch.tensor([0, 1]))
    assert free.iterations.tolist()[1] == 100 and free.status.tolist() == [LMStatus.CONVERGED, LMStatus.MAX_ITERATIONS]
    assert grouped.iterations.tolist() == [free.iterations.tolist()[0]] * 2
    assert grouped.status.tolist() == [LMStatus.CONVERGED, LMStatus.DOMINATED]
    assert float(grouped.rms[1]) > 10 * float(grouped.rms[0])
    torch.testing.assert_close(grouped.params[0], free.params[0], atol=1e-9, rtol=1e-12)
    assert torch.equal(apart.iterations, free.iterations)
    torch.testing.assert_close(apart.params, free.params, atol=1e-9, rtol=1e-12)


def test_weights_and_covariance():
    m, p, rvec, tvec, uv = _opencv_set(C=1, V=8, noise=0.2, seed=4)
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    w = torch.ones(uv.shape[:-1], dtype=F64)
    res = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, w)
    # zero weights ignore garbage; a global scale of the weights changes neither solution nor covariance
    bad = uv.clone()
    bad[0, 0, :5] = float("nan")
    bad[0, 1, :5] += 40.0
    w0 = w.clone()
    w0[0, :2, :5] = 0
    ref = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, w0)
    got = levenberg_marquardt(m, p0, r0, t0, OBJ, bad, w0)
    torch.testing.assert_close(got.params, ref.params, atol=1e-9, rtol=0)
    assert int(got.num_points) == 8 * 54 - 10
    scaled = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, 4.0 * w)
    torch.testing.assert_close(scaled.params, res.params, atol=1e-9, rtol=0)
    torch.testing.assert_close(scaled.covariance, res.covariance, rtol=1e-6, atol=0)
    # absolute weights (inverse variances): covariance (J^T W J)^-1, no sigma^2
    absw = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, w / 0.2**2, absolute_weights=True)
    assert float(absw.sigma2) == 1.0
    ratio = absw.covariance.diagonal(dim1=-2, dim2=-1) / res.covariance.diagonal(dim1=-2, dim2=-1)
    torch.testing.assert_close(ratio, torch.full_like(ratio, 0.2**2 / float(res.sigma2)), rtol=1e-6, atol=0)
    # the marginal covariance is the camera block of the dense inverse over camera + all poses
    x = torch.cat([res.params[0], torch.zeros(8 * 6, dtype=F64)])
    R0 = axis_angle_to_rotation_matrix(res.rvec[0])

    def resid(z):
        dR = axis_angle_to_rotation_matrix(z[9:].view(8, 6)[:, :3])
        Xc = torch.einsum("vij,vjk,nk->vni", dR, R0, OBJ) + (res.tvec[0] + z[9:].view(8, 6)[:, 3:])[:, None]
        return (m.project(Xc[None], z[None, :9], False)[0] - uv).flatten()

    J = torch.func.jacfwd(resid)(x)
    cov = torch.linalg.inv(J.T @ J)[:9, :9] * res.sigma2
    torch.testing.assert_close(res.covariance[0], cov, rtol=1e-6, atol=1e-12)


def test_basis_fixes_and_ties_parameters():
    m, p, rvec, tvec, uv = _opencv_set(C=2, noise=0.1)
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    res = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, fix_aspect_ratio=True, free=["fx", "fy", "k1", "k2", "k3"])
    torch.testing.assert_close(res.params[:, 0] / res.params[:, 1], p0[:, 0] / p0[:, 1])
    torch.testing.assert_close(res.params[:, [2, 3, 6, 7]], p0[:, [2, 3, 6, 7]], atol=0, rtol=0)
    std = res.param_std
    assert bool((std[:, [2, 3, 6, 7]] == 0).all()) and bool((std[:, [0, 1, 4, 5, 8]] > 0).all())
    assert res.covariance.shape == (2, 4, 4)
    poses_only = levenberg_marquardt(m, p, r0, t0, OBJ, uv, free=[False] * 9)
    assert torch.equal(poses_only.params, p) and poses_only.covariance.shape == (2, 0, 0)
    assert float(poses_only.rms.max()) < 0.2
    B = parameter_basis(m, p0, free=[True] * 9)
    tied = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, basis=B)
    free = levenberg_marquardt(m, p0, r0, t0, OBJ, uv)
    torch.testing.assert_close(tied.params, free.params, atol=1e-9, rtol=0)


def test_module_and_exceptions():
    m, p, rvec, tvec, uv = _opencv_set(C=1, V=4)
    lm = LevenbergMarquardt(m, max_iters=50)
    before = dict(lm.__dict__)
    res = lm(p, rvec, tvec, OBJ, uv)
    assert float(res.rms) < 1e-8 and lm.__dict__.keys() == before.keys() and lm.max_iters == 50
    # the module passes the stall rule on (test_refine.py checks the rule itself)
    from ccs_kornia.modules.calibration import lm as lm_module

    seen = {}

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return levenberg_marquardt(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(lm_module, "levenberg_marquardt", spy)
        LevenbergMarquardt(m, max_iters=50, stall_tol=1e-4)(p, rvec, tvec, OBJ, uv)
    assert seen["stall_tol"] == 1e-4 and LevenbergMarquardt(m).stall_tol == 0.0
    with pytest.raises(ValueError, match="corners"):
        levenberg_marquardt(m, p, rvec, tvec, OBJ, uv[0])
    with pytest.raises(ValueError, match="params"):
        levenberg_marquardt(m, p[:, :5], rvec, tvec, OBJ, uv)
    with pytest.raises(ValueError, match="rvec"):
        levenberg_marquardt(m, p, rvec[:, :2], tvec, OBJ, uv)
    with pytest.raises(ValueError, match="object_points"):
        levenberg_marquardt(m, p, rvec, tvec, OBJ[:10], uv)
    with pytest.raises(ValueError, match="weights"):
        levenberg_marquardt(m, p, rvec, tvec, OBJ, uv, torch.ones(1, 4, 3))
    with pytest.raises(ValueError, match="basis"):
        levenberg_marquardt(m, p, rvec, tvec, OBJ, uv, basis=torch.zeros(1, 4, 2, dtype=F64))
    with pytest.raises(ValueError, match="Unknown parameter"):
        parameter_basis(m, p, free=["fx", "k9"])
    with pytest.raises(ValueError, match="fix_aspect_ratio"):
        parameter_basis(m, p, free=["fx", "cx"], fix_aspect_ratio=True)
    with pytest.raises(ValueError, match="free"):
        parameter_basis(m, p, free=[True, False])
    with pytest.raises(TypeError, match="CameraModel"):
        levenberg_marquardt("opencv5", p, rvec, tvec, OBJ, uv)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_device_and_input_dtype(device, dtype):
    m, p, rvec, tvec, uv = _opencv_set(C=2, V=6, noise=0.05)
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    ref = levenberg_marquardt(m, p0, r0, t0, OBJ, uv)
    to = dict(device=device, dtype=dtype)
    res = levenberg_marquardt(m, p0.to(**to), r0.to(**to), t0.to(**to), OBJ.to(**to), uv.to(**to))
    assert res.params.dtype == F64 and res.params.device.type == device  # solved in float64 on the device
    tol = 1e-6 if dtype == F64 else 2e-2
    torch.testing.assert_close(res.params.cpu(), ref.params, atol=tol, rtol=1e-4 if dtype == torch.float32 else 1e-9)


# ------------------------------------------------------------------ wrappers against an independent reference
def _reference_lsq(residual, x0, dof_params):
    """Dense reference solve: MINPACK's LM (scipy) on ``residual`` (any parametrisation, autodiff Jacobian), and
    the Gauss-Newton covariance ``sigma^2 (J^T J)^+`` at its solution."""
    from scipy.optimize import least_squares
    from torch.func import jacfwd

    f = lambda x: residual(torch.from_numpy(x)).numpy()  # noqa: E731
    jac = lambda x: jacfwd(residual)(torch.from_numpy(x)).numpy()  # noqa: E731
    sol = least_squares(f, x0.numpy(), jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)
    x = torch.from_numpy(sol.x)
    J, r = jacfwd(residual)(x), residual(x)
    cost = float(r @ r)
    cov = torch.linalg.pinv(J.T @ J) * cost / max(dof_params, 1)
    return x, r, cov


@pytest.mark.parametrize("model", [PINHOLE, K1K2, OPENCV5])
@pytest.mark.parametrize("flags", [{}, {"fix_aspect_ratio": True}, {"fix_principal_point": True},
                                   {"fix_intrinsics": True}, {"fix_distortion": True}])
def test_joint_refinement_matches_a_dense_reference(model, flags):
    """The OpenCV wrapper on the core against a dense LM over OpenCV's projection (kornia) in axis-angle poses."""
    from ccs_kornia.modules.calibration.refinement import joint_refinement

    g = torch.Generator().manual_seed(1)
    _, p, rvec, tvec, uv = _opencv_set(C=2, V=8, noise=0.1, seed=2)
    K = torch.zeros(2, 3, 3, dtype=F64)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = p[:, 0] * 1.02, p[:, 1] * 1.02, p[:, 2] + 3, p[:, 3] - 2, 1
    valid = torch.rand(uv.shape[:-1], generator=g) > 0.1
    valid[1, 3] = False
    b = joint_refinement(uv, valid, OBJ, K, rvec + 0.01, tvec, None, None, model=model, **flags)
    idx = list(model.coeff_index)
    D = 0 if model == PINHOLE else 5
    for c in range(2):
        used = valid[c].any(-1)
        w = valid[c][used].to(F64)[..., None]
        Vu = int(used.sum())
        fixed_k = [float(K[c, 0, 0]), float(K[c, 1, 1]), float(K[c, 0, 2]), float(K[c, 1, 2])]
        aspect = fixed_k[0] / fixed_k[1]
        free_k = [] if flags.get("fix_intrinsics") else (
            ["fy"] if flags.get("fix_aspect_ratio") else ["fx", "fy"]) + ([] if flags.get("fix_principal_point") else ["cx", "cy"])
        nd = 0 if flags.get("fix_distortion") else len(idx)

        def unpack(x):
            named = dict(zip(["fx", "fy", "cx", "cy"], fixed_k))
            vals = dict(zip(free_k, x[: len(free_k)]))
            fy = vals.get("fy", torch.tensor(named["fy"], dtype=F64))
            fx = aspect * fy if flags.get("fix_aspect_ratio") else vals.get("fx", torch.tensor(named["fx"], dtype=F64))
            cx, cy = (vals.get(k, torch.tensor(named[k], dtype=F64)) for k in ("cx", "cy"))
            z, o = torch.zeros((), dtype=F64), torch.ones((), dtype=F64)
            Km = torch.stack([torch.stack([fx, z, cx]), torch.stack([z, fy, cy]), torch.stack([z, z, o])])
            d8 = torch.zeros(8, dtype=F64)
            if nd:
                d8 = d8.index_put((torch.tensor(idx),), x[len(free_k): len(free_k) + nd])
            poses = x[len(free_k) + nd:].reshape(Vu, 6)
            return Km, d8, poses

        def residual(x):
            Km, d8, poses = unpack(x)
            proj = project_points(OBJ.expand(Vu, -1, -1), Km.expand(Vu, 3, 3), d8[:D].expand(Vu, D) if D else None,
                                  poses[:, :3], poses[:, 3:])
            return ((proj - uv[c][used]) * w).reshape(-1)

        x0 = torch.cat([torch.tensor([fixed_k[["fx", "fy", "cx", "cy"].index(k)] for k in free_k], dtype=F64),
                        torch.zeros(nd, dtype=F64), torch.cat([rvec[c][used] + 0.01, tvec[c][used]], -1).reshape(-1)])
        n_free = len(free_k) + nd + 6 * Vu
        x, r, cov = _reference_lsq(residual, x0, int(2 * valid[c].sum()) - n_free)
        Km, d8, _ = unpack(x)
        # the core stops at a relative cost decrease of 1e-12 (the reference at 1e-15): ~1e-8 relative in a flat valley
        torch.testing.assert_close(b.K[c], Km, atol=2e-5, rtol=0)
        torch.testing.assert_close(b.dist[c], d8[:D], atol=1e-5, rtol=0)  # k3 is weakly determined
        std = cov.diagonal().clamp_min(0).sqrt()
        std_k = dict(zip(free_k, std[: len(free_k)]))
        if flags.get("fix_aspect_ratio"):
            std_k["fx"] = aspect * std_k["fy"]
        ref_std_k = torch.stack([std_k.get(k, torch.zeros((), dtype=F64)) for k in ("fx", "fy", "cx", "cy")])
        torch.testing.assert_close(b.std_intrinsics[c], ref_std_k, atol=1e-9, rtol=1e-5)
        ref_std_d = torch.zeros(8, dtype=F64)
        if nd:
            ref_std_d[idx] = std[len(free_k): len(free_k) + nd]
        torch.testing.assert_close(b.std_dist[c], ref_std_d[:D], atol=1e-9, rtol=1e-5)
        view_rms = (r.reshape(Vu, -1, 2) ** 2).sum((-1, -2)) / valid[c][used].sum(-1)
        torch.testing.assert_close(b.view_rms[c][used], view_rms.sqrt(), atol=1e-7, rtol=0)
        assert bool(b.view_rms[c][~used].isnan().all()) and int(b.num_points[c]) == int(valid[c].sum())
    # the full covariance agrees with the standard deviations; unbatched input
    torch.testing.assert_close(b.cov_camera.diagonal(dim1=-2, dim2=-1).sqrt(), torch.cat([b.std_intrinsics, b.std_dist], -1))
    c1 = joint_refinement(uv[0], valid[0], OBJ, K[0], rvec[0] + 0.01, tvec[0], None, None, model=model, **flags)
    torch.testing.assert_close(c1.K, b.K[0], atol=1e-9, rtol=0)


def test_refine_centred_radial_matches_a_dense_reference():
    """The paper's radial model on the core against a dense LM over the same projection written with kornia."""
    from ccs_kornia.modules.calibration.centred_radial import (
        centred_radial_distort,
        refine_centred_radial,
    )

    K = torch.tensor([[430.0, 0.0, 329.0], [0.0, 433.0, 233.0], [0.0, 0.0, 1.0]], dtype=F64)
    rvec, tvec = _poses(2, 8, seed=5, depth=0.45)
    ideal = project_points(OBJ.expand(2, 8, -1, -1), K.expand(2, 8, 3, 3), None, rvec, tvec)
    uv = centred_radial_distort(ideal.reshape(2, -1, 2), torch.tensor([[-0.4, 0.1, 0.0], [-0.2, 0.0, 0.0]], dtype=F64),
                                (640, 480), torch.tensor([[9.0, -8.0], [0.0, 0.0]], dtype=F64)).reshape(2, 8, 54, 2)
    uv = uv + 0.03 * torch.randn(uv.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    valid = torch.ones(uv.shape[:-1], dtype=torch.bool)
    K0 = (torch.diag(torch.tensor([1.02, 0.99, 1.0], dtype=F64)) @ K).expand(2, 3, 3)
    for fc in (False, True):
        b = refine_centred_radial(uv, valid, OBJ, K0, rvec, tvec, torch.zeros(2, 3), (640, 480), free_centre=fc,
                                  covariance=True)
        nc = 2 if fc else 0
        for c in range(2):
            def residual(x):
                fx, fy, cx, cy = x[:4]
                z, o = torch.zeros((), dtype=F64), torch.ones((), dtype=F64)
                Km = torch.stack([torch.stack([fx, z, cx]), torch.stack([z, fy, cy]), torch.stack([z, z, o])])
                poses = x[7 + nc:].reshape(8, 6)
                proj = project_points(OBJ.expand(8, -1, -1), Km.expand(8, 3, 3), None, poses[:, :3], poses[:, 3:])
                off = x[7:9][None] if fc else None
                return (centred_radial_distort(proj.reshape(1, -1, 2), x[4:7][None], (640, 480), off).reshape(8, 54, 2)
                        - uv[c]).reshape(-1)

            x0 = torch.cat([K0[c, 0, 0:1], K0[c, 1, 1:2], K0[c, :2, 2], torch.zeros(3 + nc, dtype=F64),
                            torch.cat([rvec[c], tvec[c]], -1).reshape(-1)])
            x, r, cov = _reference_lsq(residual, x0, 2 * 8 * 54 - x0.numel())
            torch.testing.assert_close(b[0][c], torch.tensor([[x[0], 0, x[2]], [0, x[1], x[3]], [0, 0, 1]], dtype=F64),
                                       atol=1e-6, rtol=0)  # K
            torch.testing.assert_close(b[1][c], x[4:7], atol=1e-6, rtol=0)  # k1..k3 (k3 ~ -4.2, weakly determined)
            torch.testing.assert_close(b[4][c], (r @ r / (8 * 54)).sqrt(), atol=1e-9, rtol=0)  # rms
            torch.testing.assert_close(b[5][c], x[7:9] if fc else torch.zeros(2, dtype=F64), atol=1e-6, rtol=0)
            torch.testing.assert_close(b[6][c], cov.diagonal()[:4].sqrt(), rtol=1e-5, atol=0)  # std of fx, fy, cx, cy
            s_ = cov.diagonal()[: 7 + nc].sqrt()
            diff = (b[7][c, : 7 + nc, : 7 + nc] - cov[: 7 + nc, : 7 + nc]) / (s_[:, None] * s_[None, :])
            assert float(diff.abs().max()) < 1e-4  # the full covariance, in units of the standard deviations
    few = valid.clone()
    few[1] = False
    few[1, 0, :7] = True  # camera 1 has fewer than 8 corners: left unchanged, NaN rms
    out = refine_centred_radial(uv, few, OBJ, K0, rvec, tvec, torch.zeros(2, 3), (640, 480))
    assert bool(out[4][1].isnan()) and torch.equal(out[0][1], K0[1]) and bool(out[4][0] < 0.1)


def test_status_of_each_camera():
    """A camera that fits converges, one without a weighted corner has no data (NaN RMS, its start kept), and an
    iteration limit below what a camera needs leaves it at the limit."""
    m, p, rvec, tvec, uv = _opencv_set()
    p0, r0, t0 = _perturbed(p, rvec, tvec)
    w = torch.ones(uv.shape[:-1], dtype=F64)
    w[1] = 0
    res = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, w)
    assert res.status.tolist() == [LMStatus.CONVERGED, LMStatus.NO_DATA] and int(res.iterations[1]) == 0
    assert bool(res.rms[1].isnan()) and torch.equal(res.params[1], p0[1])
    capped = levenberg_marquardt(m, p0, r0, t0, OBJ, uv, max_iters=2)
    assert (capped.status == LMStatus.MAX_ITERATIONS).all() and (capped.iterations == 2).all()
