r"""Solves with block-banded symmetric positive definite matrices, batched: the item blocks of a problem whose items
couple their neighbours (a spline's control points), in time linear in the number of items.

The matrix has ``V`` diagonal blocks :math:`D_i` (``k x k``) and, for ``j = 1 .. w``, the blocks :math:`E_{i,j}`
coupling item ``i`` with item ``i + j`` (zero past the end). Grouping ``w`` consecutive items into one super-block
leaves couplings between neighbouring super-blocks only: a block-tridiagonal matrix, whose Cholesky factor is computed
super-block after super-block (:func:`block_banded_cholesky`) and solved forward and back
(:func:`block_banded_solve`). A problem whose matrix is not definite is flagged, and its solutions are zero.

Example:
    >>> D = torch.eye(2, dtype=torch.float64).expand(1, 5, 2, 2) * 4
    >>> E = torch.eye(2, dtype=torch.float64).expand(1, 5, 1, 2, 2).clone()
    >>> E[:, -1] = 0
    >>> A = block_banded_dense(D, E)
    >>> b = torch.arange(10.0, dtype=torch.float64).view(1, 5, 2, 1)
    >>> x = block_banded_solve(block_banded_cholesky(D, E), b)
    >>> torch.allclose(A[0] @ x.flatten(), b.flatten())
    True
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["BlockBandedCholesky", "block_banded_cholesky", "block_banded_dense", "block_banded_solve"]


@dataclass
class BlockBandedCholesky:
    """The Cholesky factor of ``B`` block-banded matrices, by super-blocks of ``w`` items.

    Attributes:
        L: :math:`(B, n, s, s)` the factors of the ``n`` diagonal super-blocks (``s = w k``).
        C: :math:`(B, n, s, s)` the factor's block below each diagonal one (``C[:, -1]`` is zero).
        failed: :math:`(B,)` bool, matrices that are not (numerically) definite.
        items: ``V``, the items before padding to whole super-blocks. size: ``k``.
    """

    L: torch.Tensor
    C: torch.Tensor
    failed: torch.Tensor
    items: int
    size: int


def _super_blocks(D: torch.Tensor, E: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The diagonal super-blocks and the ones right of them, :math:`(B, n, wk, wk)` each."""
    B, V, k, _ = D.shape
    w = E.shape[2]
    n = -(-V // w)
    pad = n * w - V
    if pad:
        eye = torch.eye(k, dtype=D.dtype, device=D.device).expand(B, pad, k, k)
        D = torch.cat([D, eye], 1)
        E = torch.cat([E, E.new_zeros(B, pad, w, k, k)], 1)
    Dg, Eg = D.view(B, n, w, k, k), E.view(B, n, w, w, k, k)
    diag = D.new_zeros(B, n, w, w, k, k)
    right = D.new_zeros(B, n, w, w, k, k)
    for a in range(w):
        diag[:, :, a, a] = Dg[:, :, a]
        for j in range(1, w + 1):
            b = a + j
            if b < w:
                diag[:, :, a, b] = Eg[:, :, a, j - 1]
                diag[:, :, b, a] = Eg[:, :, a, j - 1].transpose(-1, -2)
            else:
                right[:, :, a, b - w] = Eg[:, :, a, j - 1]
    s = w * k
    return (diag.transpose(3, 4).reshape(B, n, s, s), right.transpose(3, 4).reshape(B, n, s, s))


def block_banded_cholesky(D: torch.Tensor, E: torch.Tensor) -> BlockBandedCholesky:
    """The Cholesky factor of block-banded SPD matrices.

    Args:
        D: :math:`(B, V, k, k)` the diagonal blocks.
        E: :math:`(B, V, w, k, k)`: ``E[:, i, j - 1]`` couples item ``i`` (rows) with item ``i + j`` (columns); entries
            past the last item are ignored.

    Returns:
        :class:`BlockBandedCholesky`.
    """
    check_tensor(D, "D", ["B", "V", "k", "k"])
    B, V, k, _ = D.shape
    check_tensor(E, "E", [B, V, "w", k, k])
    # couplings past the end are dropped here, so callers may leave them as they are
    w = E.shape[2]
    last = torch.arange(V, device=D.device)[:, None] + torch.arange(1, w + 1, device=D.device) >= V
    E = E.masked_fill(last[None, :, :, None, None], 0.0)
    diag, right = _super_blocks(D, E)
    n, s = diag.shape[1], diag.shape[-1]
    eye = torch.eye(s, dtype=D.dtype, device=D.device)
    L, C = torch.empty_like(diag), torch.empty_like(right)
    failed = torch.zeros(B, dtype=torch.bool, device=D.device)
    below = None
    for j in range(n):
        A = diag[:, j] if below is None else diag[:, j] - below @ below.transpose(-1, -2)
        Lj, info = torch.linalg.cholesky_ex(A)
        bad = info != 0
        failed |= bad
        Lj = torch.where(bad[:, None, None], eye, Lj)
        L[:, j] = Lj
        # the block below: C_j = E_j^T L_j^{-T}
        below = torch.linalg.solve_triangular(Lj, right[:, j], upper=False).transpose(-1, -2)
        C[:, j] = below
    return BlockBandedCholesky(L=L, C=C, failed=failed, items=V, size=k)


def block_banded_solve(factor: BlockBandedCholesky, b: torch.Tensor) -> torch.Tensor:
    """Solve ``A x = b`` with the factor of ``A``.

    Args:
        factor: :func:`block_banded_cholesky`'s.
        b: :math:`(B, V, k, r)` right-hand sides, item by item.

    Returns:
        :math:`(B, V, k, r)` (zero for the matrices that failed).
    """
    B, n, s, _ = factor.L.shape
    V, k = factor.items, factor.size
    check_tensor(b, "b", [B, V, k, "r"])
    r = b.shape[-1]
    pad = n * (s // k) - V
    if pad:
        b = torch.cat([b, b.new_zeros(B, pad, k, r)], 1)
    y = b.reshape(B, n, s, r)
    ys = []
    prev = None
    for j in range(n):
        rhs = y[:, j] if prev is None else y[:, j] - factor.C[:, j - 1] @ prev
        prev = torch.linalg.solve_triangular(factor.L[:, j], rhs, upper=False)
        ys.append(prev)
    xs = [None] * n
    nxt = None
    for j in range(n - 1, -1, -1):
        rhs = ys[j] if nxt is None else ys[j] - factor.C[:, j].transpose(-1, -2) @ nxt
        nxt = torch.linalg.solve_triangular(factor.L[:, j].transpose(-1, -2), rhs, upper=True)
        xs[j] = nxt
    x = torch.stack(xs, 1).reshape(B, n * (s // k), k, r)[:, :V]
    return x.masked_fill(factor.failed[:, None, None, None] | ~x.isfinite(), 0.0)


def block_banded_dense(D: torch.Tensor, E: torch.Tensor) -> torch.Tensor:
    """The dense :math:`(B, Vk, Vk)` matrix of diagonal blocks ``D`` :math:`(B, V, k, k)` and couplings ``E``
    :math:`(B, V, w, k, k)` (as :func:`block_banded_cholesky`'s): for tests and small problems."""
    B, V, k, _ = D.shape
    A = D.new_zeros(B, V, k, V, k)
    i = torch.arange(V, device=D.device)
    A[:, i, :, i, :] = D.transpose(0, 1)
    for j in range(1, E.shape[2] + 1):
        a = i[: V - j]
        A[:, a, :, a + j, :] = E[:, : V - j, j - 1].transpose(0, 1)
        A[:, a + j, :, a, :] = E[:, : V - j, j - 1].transpose(-1, -2).transpose(0, 1)
    return A.reshape(B, V * k, V * k)
