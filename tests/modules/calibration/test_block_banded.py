import pytest
import torch

from ccs_kornia.modules.calibration.block_banded import (
    block_banded_dense,
    block_banded_solve,
    block_tridiagonal_solve,
)
from ccs_kornia.modules.calibration.schur_lm import (
    NormalEquations,
    schur_lm,
    schur_step,
)


def _banded(B, V, k, w, dtype=torch.float64, seed=0):
    """Random block-banded SPD matrices: ``J^T J`` of a Jacobian whose rows touch ``w + 1`` consecutive items."""
    g = torch.Generator().manual_seed(seed)
    rows = []
    for i in range(V):
        J = torch.zeros(B, 2 * k, V * k, dtype=dtype)
        hi = min(V, i + w + 1)
        J[:, :, i * k: hi * k] = torch.randn(B, 2 * k, (hi - i) * k, generator=g, dtype=dtype)
        rows.append(J)
    J = torch.cat(rows, 1)
    A = (J.mT @ J).view(B, V, k, V, k)
    D = torch.stack([A[:, i, :, i] for i in range(V)], 1)
    E = torch.zeros(B, V, w, k, k, dtype=dtype)
    for i in range(V):
        for j in range(1, w + 1):
            if i + j < V:
                E[:, i, j - 1] = A[:, i, :, i + j]
    return D, E, A.reshape(B, V * k, V * k)


class TestBlockBanded:
    @pytest.mark.parametrize("B,V,k,w", [(1, 1, 3, 3), (2, 7, 3, 2), (1, 10, 12, 3), (3, 9, 6, 1)])
    def test_solve_matches_dense(self, B, V, k, w):
        D, E, A = _banded(B, V, k, w)
        torch.testing.assert_close(block_banded_dense(D, E), A)
        b = torch.randn(B, V, k, 4, dtype=torch.float64)
        x, failed = block_banded_solve(D, E, b)
        assert not bool(failed.any())
        torch.testing.assert_close(x.reshape(B, V * k, 4), torch.linalg.solve(A, b.reshape(B, V * k, 4)))

    def test_indefinite_problem_gives_zero_and_others_unaffected(self):
        D, E, A = _banded(2, 5, 3, 2)
        D[1, 2] = -D[1, 2]
        b = torch.randn(2, 5, 3, 1, dtype=torch.float64)
        x, failed = block_banded_solve(D, E, b)
        assert failed.tolist() == [False, True]
        assert bool((x[1] == 0).all())
        torch.testing.assert_close(x[0].reshape(-1, 1), torch.linalg.solve(A[0], b[0].reshape(-1, 1)))

    def test_couplings_past_the_end_are_ignored(self):
        D, E, _ = _banded(1, 4, 2, 2)
        E2 = E.clone()
        E2[:, -1] = 5.0
        E2[:, -2, 1] = 7.0
        b = torch.randn(1, 4, 2, 1, dtype=torch.float64)
        torch.testing.assert_close(block_banded_solve(D, E2, b)[0], block_banded_solve(D, E, b)[0])

    def test_shapes_checked(self):
        D, E, _ = _banded(1, 4, 2, 2)
        with pytest.raises(ValueError):
            block_banded_solve(D, E[:, :3], torch.zeros(1, 4, 2, 1, dtype=torch.float64))

    @pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 8, 13])
    def test_tridiagonal_any_length(self, n):
        D, E, A = _banded(2, n, 3, 1, seed=n)
        x, failed = block_tridiagonal_solve(D, E[:, : n - 1, 0], torch.ones(2, n, 3, 2, dtype=torch.float64))
        assert not bool(failed.any())
        torch.testing.assert_close(A @ x.reshape(2, 3 * n, 2), torch.ones(2, 3 * n, 2, dtype=torch.float64))


class TestBandedSchur:
    def test_step_matches_dense_solve(self):
        B, V, k, w, G = 2, 6, 4, 3, 3
        D, E, A = _banded(B, V, k, w, seed=1)
        g = torch.Generator().manual_seed(2)
        W = torch.randn(B, V, G, k, generator=g, dtype=torch.float64)
        Wf = W.permute(0, 2, 1, 3).reshape(B, G, V * k)
        U = Wf @ torch.linalg.solve(A, Wf.mT) + torch.eye(G, dtype=torch.float64) * 3
        eg, ep = torch.randn(B, G, dtype=torch.float64), torch.randn(B, V, k, dtype=torch.float64)
        full = torch.cat([torch.cat([U, Wf], -1), torch.cat([Wf.mT, A], -1)], -2)
        x = torch.linalg.solve(full, -torch.cat([eg, ep.flatten(1)], -1))
        dg, dp = schur_step(U, W, D, eg, ep, torch.ones(B, V, dtype=torch.bool), Vband=E)
        torch.testing.assert_close(dg, x[:, :G])
        torch.testing.assert_close(dp.flatten(1), x[:, G:])

    def test_lm_on_a_smoothed_curve(self):
        # items: values on a chain, coupled by second differences (a banded prior); global: an offset
        class Chain:
            def __init__(self, y):
                self.y = y  # (B, V, 1)
                B, V = y.shape[:2]
                self.mask = (torch.arange(V) % 2 == 0)[None, :, None]
                self.used = torch.ones(B, V, dtype=torch.bool)
                self.num_residuals = torch.full((B,), 2 * V - 2)
                self.floor = torch.full((B,), 1e-30, dtype=y.dtype)

            def linearize(self, s):
                x, c = s["x"], s["c"]  # (B, V, 1), (B, 1)
                m = self.mask.to(x)  # the offset applies to every other item (so it is determined)
                r1 = x + c[:, None] * m - self.y  # data
                r2 = x[:, :-2] - 2 * x[:, 1:-1] + x[:, 2:]  # smoothness
                B, V = x.shape[:2]
                D = torch.ones(B, V, 1, 1, dtype=x.dtype)
                E = torch.zeros(B, V, 2, 1, 1, dtype=x.dtype)
                coef = torch.tensor([1.0, -2.0, 1.0], dtype=x.dtype)
                for i in range(V - 2):
                    for a in range(3):
                        D[:, i + a] += coef[a] ** 2
                        for b in range(a + 1, 3):
                            E[:, i + a, b - a - 1] += coef[a] * coef[b]
                ep = r1.clone()
                for a in range(3):
                    ep[:, a: V - 2 + a] += coef[a] * r2
                return NormalEquations(cost=(r1**2).sum((1, 2)) + (r2**2).sum((1, 2)),
                                       U=(m * m).sum((1, 2)).expand(B)[:, None, None].clone(),
                                       eg=(r1 * m).sum((1, 2))[:, None], W=m.expand(B, V, 1)[..., None].clone(),
                                       V=D, ep=ep, Vband=E)

            def retract(self, s, dg, dp):
                return {"x": s["x"] + dp, "c": s["c"] + dg}

            def scale(self, s):
                return torch.ones(s["c"].shape[0], dtype=s["c"].dtype)

            def take(self, keep):
                return Chain(self.y[keep])

        y = torch.randn(2, 12, 1, dtype=torch.float64)
        res = schur_lm(Chain(y), {"x": torch.zeros_like(y), "c": torch.zeros(2, 1, dtype=torch.float64)})
        # a linear least-squares problem: LM ends at its stationary point, with a finite covariance of the offset
        eq = Chain(y).linearize(res.unknowns)
        assert float(eq.ep.abs().max()) < 1e-8 and float(eq.eg.abs().max()) < 1e-8
        assert bool((res.status == 1).all()) and torch.isfinite(res.covariance).all()
