import pytest
import torch
from torch.func import jacfwd

from ccs_kornia.geometry.so3 import (
    exp_so3,
    log_so3,
    right_jacobian,
    right_jacobian_inverse,
    skew,
)
from ccs_kornia.geometry.spline import (
    SE3Spline,
    fit_r3_spline,
    r3_spline,
    segment_of,
    so3_spline,
    spline_basis,
)


def _spline(M=10, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    R = exp_so3(torch.randn(M, 3, generator=g, dtype=dtype).cumsum(0) * 0.3)
    p = torch.randn(M, 3, generator=g, dtype=dtype)
    return SE3Spline(0.0, 0.1, R, p)


class TestSpline:
    def test_basis_partition_of_unity_and_cumulative(self):
        u = torch.linspace(0, 1, 7, dtype=torch.float64)
        torch.testing.assert_close(spline_basis(u).sum(-1), torch.ones_like(u))
        torch.testing.assert_close(spline_basis(u, 0, cumulative=True)[:, 0], torch.ones_like(u))
        torch.testing.assert_close(spline_basis(u, 1).sum(-1), torch.zeros_like(u))
        with pytest.raises(ValueError):
            spline_basis(u, 3)

    def test_segments(self):
        i, u = segment_of(torch.tensor([0.0, 0.05, 0.31, 5.0], dtype=torch.float64), 0.0, 0.1, 8)
        assert i.tolist() == [0, 0, 3, 4]
        assert float(u[1]) == pytest.approx(0.5) and float(u[3]) > 1

    def test_continuous_across_knots(self):
        s = _spline()
        for k in (0.3, 0.4, 0.5):
            a, pa = s.pose(torch.tensor([k - 1e-12], dtype=torch.float64))
            b, pb = s.pose(torch.tensor([k + 1e-12], dtype=torch.float64))
            assert float((a - b).abs().max()) < 1e-9 and float((pa - pb).abs().max()) < 1e-9

    def test_derivatives_match_finite_differences(self):
        s = _spline()
        t = torch.linspace(0.02, 0.68, 30, dtype=torch.float64)
        h = 1e-6
        Ra, _ = s.pose(t - h)
        Rb, _ = s.pose(t + h)
        torch.testing.assert_close(log_so3(Ra.mT @ Rb) / (2 * h), s.angular_velocity(t), atol=1e-7, rtol=1e-7)
        h = 1e-4
        _, pa = s.pose(t - h)
        _, p0 = s.pose(t)
        _, pb = s.pose(t + h)
        torch.testing.assert_close((pa + pb - 2 * p0) / h**2, s.acceleration(t), atol=1e-4, rtol=1e-5)

    def test_control_point_jacobians_match_autodiff(self):
        g = torch.Generator().manual_seed(1)
        Rl = exp_so3(torch.randn(6, 4, 3, generator=g, dtype=torch.float64).cumsum(1) * 0.3)
        u = torch.rand(6, generator=g, dtype=torch.float64)
        R, _w, E, Dw = so3_spline(Rl, u, 0.05, jacobians=True)
        for n in range(6):
            def f(delta, n=n):
                return so3_spline(Rl[n] @ exp_so3(delta), u[n], 0.05)

            dR, dw = jacfwd(f)(torch.zeros(4, 3, dtype=torch.float64))
            M = torch.einsum("ab,ackl->bckl", R[n], dR)  # R^T dR: the right perturbation
            eps = torch.stack([M[2, 1], M[0, 2], M[1, 0]], 0).permute(1, 0, 2)
            torch.testing.assert_close(eps, E[n])
            torch.testing.assert_close(dw.permute(1, 0, 2), Dw[n])

    def test_fit_recovers_a_polynomial(self):
        t = torch.linspace(0, 1, 80, dtype=torch.float64)
        x = torch.stack([t**2, 1 - t, 3 * t**3], -1)
        p = fit_r3_spline(t, x, 0.0, 0.1, 13)
        i, u = segment_of(t, 0.0, 0.1, 13)
        fit = r3_spline(p[i[:, None] + torch.arange(4)], u, 0.1)
        assert float((fit - x).abs().max()) < 1e-5

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_dtype_and_batch(self, dtype):
        s = _spline(dtype=dtype)
        R, p = s.pose(torch.rand(2, 5, dtype=dtype) * 0.6)
        assert R.shape == (2, 5, 3, 3) and p.shape == (2, 5, 3) and R.dtype == dtype


class TestSO3Jacobians:
    def test_right_jacobian_definition(self):
        w = torch.tensor([[0.3, -0.2, 0.5], [1e-9, 0.0, 0.0], [2.0, 1.0, -0.5]], dtype=torch.float64)
        d = torch.tensor([1e-7, -2e-7, 1.5e-7], dtype=torch.float64)
        lhs = exp_so3(w + d)
        rhs = exp_so3(w) @ exp_so3((right_jacobian(w) @ d[:, None])[..., 0])
        assert float((lhs - rhs).abs().max()) < 1e-13
        torch.testing.assert_close(right_jacobian_inverse(w) @ right_jacobian(w), torch.eye(3, dtype=torch.float64).expand(3, 3, 3))

    def test_skew(self):
        a, b = torch.randn(4, 3, dtype=torch.float64), torch.randn(4, 3, dtype=torch.float64)
        torch.testing.assert_close((skew(a) @ b[..., None])[..., 0], torch.linalg.cross(a, b))

    def test_exp_has_finite_derivatives_at_zero(self):
        J = jacfwd(exp_so3)(torch.zeros(3, dtype=torch.float64))
        assert torch.isfinite(J).all()
        torch.testing.assert_close(J[..., 0], skew(torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)))
