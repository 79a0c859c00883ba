"""Inverses of the LM core's normal matrices: Cholesky for SPD blocks, a clamped eigen-decomposition where they are
singular (covariances of parameters the data does not determine: finite and huge, never a crash)."""

from __future__ import annotations

import torch

__all__ = ["LARGE_SYSTEM", "cholesky_inverse", "pseudo_inverse", "spd_inverse"]


def spd_inverse(A: torch.Tensor, fail: float = float("nan")) -> torch.Tensor:
    """Inverse of SPD matrices with Jacobi scaling; failures give ``fail`` (NaN)."""
    d = A.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).rsqrt()
    dd = d[..., :, None] * d[..., None, :]
    L, info = torch.linalg.cholesky_ex(A * dd)
    bad = (info != 0)[..., None, None]
    L = L.masked_fill(bad, 0.0) + torch.diag_embed(bad[..., 0].to(A.dtype).expand(d.shape))
    return (cholesky_inverse(L) * dd).masked_fill(bad, fail)


#: above this size a Cholesky factor is inverted by triangular solves (torch's ``cholesky_inverse`` takes seconds on a
#: spline's thousand parameters, where two solves take a tenth of that); below, as it always was
LARGE_SYSTEM = 64


def cholesky_inverse(L: torch.Tensor) -> torch.Tensor:
    """``(L L^T)^-1`` of Cholesky factors :math:`(*, F, F)` (``torch.cholesky_inverse``; by solves where ``F`` is
    above :data:`LARGE_SYSTEM`)."""
    if L.shape[-1] <= LARGE_SYSTEM:
        return torch.cholesky_inverse(L)
    eye = torch.eye(L.shape[-1], dtype=L.dtype, device=L.device).expand(L.shape)
    return torch.cholesky_solve(eye, L)


def pseudo_inverse(A: torch.Tensor, rcond: float = 1e-15) -> torch.Tensor:
    """Inverse of symmetric PSD matrices (Jacobi-scaled) with eigenvalues clamped at ``rcond`` times the largest:
    finite, and huge along (nearly) null directions."""
    diag = A.diagonal(dim1=-2, dim2=-1)
    # a parameter with no information at all keeps unit scale (its rsqrt would overflow)
    d = torch.where(diag > 1e-200, diag.clamp_min(1e-200).rsqrt(), torch.ones_like(diag))
    scaled = A * d[..., :, None] * d[..., None, :]
    # non-finite systems (a diverged camera) are replaced by the identity for the decomposition, NaN after
    bad = ~scaled.isfinite().flatten(-2).all(-1)
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    scaled = torch.where(bad[..., None, None], eye, scaled)
    try:
        ev, U = torch.linalg.eigh(scaled)
    except torch.linalg.LinAlgError:  # LAPACK gave up on some matrix: decompose one by one, the failures NaN
        flat = scaled.reshape(-1, *scaled.shape[-2:])
        evs, Us, fails = [], [], []
        for m in flat:
            try:
                e, u = torch.linalg.eigh(m)
                fails.append(False)
            except torch.linalg.LinAlgError:
                e, u = torch.ones_like(m[0]), eye
                fails.append(True)
            evs.append(e)
            Us.append(u)
        ev, U = torch.stack(evs).reshape(d.shape), torch.stack(Us).reshape(scaled.shape)
        bad = bad | torch.tensor(fails, device=A.device).reshape(bad.shape)
    ev = ev.clamp_min(rcond * ev.amax(-1, keepdim=True).clamp_min(1e-300))
    out = (U / ev[..., None, :]) @ U.transpose(-1, -2) * d[..., :, None] * d[..., None, :]
    return out.masked_fill(bad[..., None, None], float("nan"))
