r"""Solves with block-banded symmetric positive definite matrices, batched: the item blocks of a problem whose items
couple their neighbours (a spline's control points), in time linear in the number of items.

The matrix has ``V`` diagonal blocks :math:`D_i` (``k x k``) and, for ``j = 1 .. w``, the blocks :math:`E_{i,j}`
coupling item ``i`` with item ``i + j`` (zero past the end). Grouping ``w`` consecutive items into one super-block
leaves couplings between neighbouring super-blocks only: a block-tridiagonal matrix, solved by block cyclic reduction
(:func:`block_tridiagonal_solve`: every other block eliminated at once, ``log2`` of the blocks' count levels of
batched dense operations, instead of a loop over the blocks). A problem whose matrix is not definite is flagged, and
its solutions are zero.

Example:
    >>> D = torch.eye(2, dtype=torch.float64).expand(1, 5, 2, 2) * 4
    >>> E = torch.eye(2, dtype=torch.float64).expand(1, 5, 1, 2, 2).clone()
    >>> A = block_banded_dense(D, E)
    >>> b = torch.arange(10.0, dtype=torch.float64).view(1, 5, 2, 1)
    >>> x, failed = block_banded_solve(D, E, b)
    >>> torch.allclose(A[0] @ x.flatten(), b.flatten()), failed.tolist()
    (True, [False])
"""

from __future__ import annotations

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["block_banded_dense", "block_banded_solve", "block_tridiagonal_solve"]


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


def _spd_solve(A: torch.Tensor, b: torch.Tensor, failed: torch.Tensor) -> torch.Tensor:
    """``A^-1 b`` of SPD blocks :math:`(B, n, s, s)`; ``failed`` :math:`(B,)` (updated) flags the problems with a block
    that is not definite (its factor replaced by the identity)."""
    L, info = torch.linalg.cholesky_ex(A)
    bad = info != 0
    if bool(bad.any()):
        failed |= bad.any(-1)
        L = torch.where(bad[..., None, None], torch.eye(A.shape[-1], dtype=A.dtype, device=A.device), L)
    return torch.cholesky_solve(b, L)


def _reduce(D, C, b, failed):
    """Cyclic reduction of one level (see :func:`block_tridiagonal_solve`)."""
    n = D.shape[1]
    if n == 1:
        return _spd_solve(D, b, failed)
    s, r = D.shape[-1], b.shape[-1]
    even, odd = D[:, 0::2], D[:, 1::2]
    ne, no = even.shape[1], odd.shape[1]
    left = C[:, 0::2]  # A[2k, 2k + 1]: odd block k's coupling to the even block on its left
    right = C[:, 1::2]  # A[2k + 1, 2k + 2]: to the even block on its right (none for a last odd block)
    has_right = right.shape[1]
    # odd block k: Y_l = D^-1 A[2k+1, 2k], Y_r = D^-1 A[2k+1, 2k+2], y = D^-1 b
    rhs = [left.transpose(-1, -2)]
    if has_right:
        rhs.append(torch.cat([right, right.new_zeros(right.shape[0], no - has_right, s, s)], 1))
    rhs.append(b[:, 1::2])
    Z = _spd_solve(odd, torch.cat(rhs, -1), failed)
    Yl, y = Z[..., :s], Z[..., -r:]
    Yr = Z[..., s:2 * s] if has_right else None
    # the even blocks' system
    D2 = even.clone()
    b2 = b[:, 0::2].clone()
    D2[:, :no] -= left @ Yl  # A[2k, 2k+1] D^-1 A[2k+1, 2k]
    b2[:, :no] -= left @ y
    if has_right:
        # even block k + 1 sees odd block k on its left
        D2[:, 1:1 + has_right] -= right.transpose(-1, -2) @ Yr[:, :has_right]
        b2[:, 1:1 + has_right] -= right.transpose(-1, -2) @ y[:, :has_right]
    C2 = -(left[:, : ne - 1] @ Yr[:, : ne - 1]) if ne > 1 else C[:, :0]
    x_even = _reduce(D2, C2, b2, failed)
    # back: odd block k from its neighbours
    x_odd = y - Yl @ x_even[:, :no]
    if has_right:
        x_odd[:, :has_right] -= Yr[:, :has_right] @ x_even[:, 1:1 + has_right]
    x = D.new_empty(D.shape[0], n, s, r)
    x[:, 0::2], x[:, 1::2] = x_even, x_odd
    return x


def block_tridiagonal_solve(D: torch.Tensor, C: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve block-tridiagonal SPD systems by block cyclic reduction.

    Args:
        D: :math:`(B, n, s, s)` the diagonal blocks.
        C: :math:`(B, n - 1, s, s)` the blocks right of them: ``C[:, i] = A[i, i + 1]``.
        b: :math:`(B, n, s, r)` right-hand sides.

    Returns:
        ``(x, failed)``: :math:`(B, n, s, r)` (zero where failed) and :math:`(B,)` bool, the systems that are not
        (numerically) definite.

    Example:
        >>> D = 4 * torch.eye(1, dtype=torch.float64).expand(1, 6, 1, 1)
        >>> C = torch.ones(1, 5, 1, 1, dtype=torch.float64)
        >>> x, _ = block_tridiagonal_solve(D, C, torch.ones(1, 6, 1, 1, dtype=torch.float64))
        >>> A = torch.diag(torch.full((6,), 4.0, dtype=torch.float64)) + torch.diag(torch.ones(5, dtype=torch.float64), 1) + torch.diag(torch.ones(5, dtype=torch.float64), -1)
        >>> torch.allclose(A @ x.flatten(), torch.ones(6, dtype=torch.float64))
        True
    """
    check_tensor(D, "D", ["B", "n", "s", "s"])
    B, n, s, _ = D.shape
    check_tensor(C, "C", [B, n - 1, s, s])
    check_tensor(b, "b", [B, n, s, "r"])
    failed = torch.zeros(B, dtype=torch.bool, device=D.device)
    x = _reduce(D, C, b, failed)
    return x.masked_fill(failed[:, None, None, None] | ~x.isfinite(), 0.0), failed


def block_banded_solve(D: torch.Tensor, E: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve block-banded SPD systems.

    Args:
        D: :math:`(B, V, k, k)` the diagonal blocks.
        E: :math:`(B, V, w, k, k)`: ``E[:, i, j - 1]`` couples item ``i`` (rows) with item ``i + j`` (columns); entries
            past the last item are ignored.
        b: :math:`(B, V, k, r)` right-hand sides, item by item.

    Returns:
        ``(x, failed)``: :math:`(B, V, k, r)` (zero where failed) and :math:`(B,)` bool.
    """
    check_tensor(D, "D", ["B", "V", "k", "k"])
    B, V, k, _ = D.shape
    check_tensor(E, "E", [B, V, "w", k, k])
    check_tensor(b, "b", [B, V, k, "r"])
    w, r = E.shape[2], b.shape[-1]
    # couplings past the end are dropped here, so callers may leave them as they are
    last = torch.arange(V, device=D.device)[:, None] + torch.arange(1, w + 1, device=D.device) >= V
    E = E.masked_fill(last[None, :, :, None, None], 0.0)
    diag, right = _super_blocks(D, E)
    n = diag.shape[1]
    pad = n * w - V
    if pad:
        b = torch.cat([b, b.new_zeros(B, pad, k, r)], 1)
    x, failed = block_tridiagonal_solve(diag, right[:, :-1], b.reshape(B, n, w * k, r))
    return x.reshape(B, n * w, k, r)[:, :V], failed


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
