"""Zhang's closed-form initialisation from board homographies, batched over cameras.

Zero skew is always assumed (every modern sensor; it also lets two views determine the camera). The
homographies are first moved to a normalised image frame (origin at the image centre, unit = max(W, H))
so the 5x5 normal matrix is well conditioned, and each view's rows are scaled to unit norm so that no
view dominates through the arbitrary scale of its homography.
"""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.runtime.checks import broadcast_shapes, check_tensor

__all__ = ["zhang_intrinsics", "extrinsics_from_homography", "rotation_translation_from_homography", "ZhangInit"]

_PP_MODES = ("auto", "estimate", "centre")


def _v_rows(H: torch.Tensor, i: int, j: int) -> torch.Tensor:
    """Zhang's v_ij row for the zero-skew unknowns (B11, B22, B13, B23, B33); H (..., 3, 3)."""
    hi, hj = H[..., :, i], H[..., :, j]
    return torch.stack(
        [
            hi[..., 0] * hj[..., 0],
            hi[..., 1] * hj[..., 1],
            hi[..., 2] * hj[..., 0] + hi[..., 0] * hj[..., 2],
            hi[..., 2] * hj[..., 1] + hi[..., 1] * hj[..., 2],
            hi[..., 2] * hj[..., 2],
        ],
        -1,
    )


def _smallest_eigvec(M: torch.Tensor) -> torch.Tensor:
    """Null vector of symmetric PSD (C, P, P) matrices; NaN/inf rows are neutralised first."""
    finite = M.flatten(-2).isfinite().all(-1)
    eye = torch.eye(M.shape[-1], dtype=M.dtype, device=M.device)
    M = torch.where(finite[:, None, None], M, eye)
    # relative scaling keeps eigh happy when a camera has no views (M == 0)
    scale = M.diagonal(dim1=-2, dim2=-1).abs().amax(-1).clamp_min(1e-300)
    M = M / scale[:, None, None]
    _, vecs = torch.linalg.eigh(M)
    return vecs[..., 0]


def zhang_intrinsics(
    H: torch.Tensor,
    view_mask: torch.Tensor | None = None,
    image_size: tuple[int, int] | None = None,
    principal_point: str = "auto",
    fix_aspect_ratio: bool = False,
    min_views_principal_point: int = 3,
    return_ok: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Closed-form zero-skew camera matrix from board-to-image homographies.

    Args:
        H: :math:`(C, V, 3, 3)` homographies (board plane to pixels), or :math:`(V, 3, 3)`.
        view_mask: :math:`(C, V)` bool, views to use (default all).
        image_size: ``(W, H)``; needed for ``principal_point="centre"`` and for the ``auto`` fall-back;
            also sets the normalisation (without it the homographies' own translations are used).
        principal_point: ``"estimate"`` (Zhang with zero skew, 5 unknowns: needs >= 2 views),
            ``"centre"`` (principal point fixed at the image centre ``((W-1)/2, (H-1)/2)``, only focal
            lengths: one view suffices), or ``"auto"``: estimate when a camera has at least
            ``min_views_principal_point`` views and the estimate is a valid camera, centre otherwise.
        fix_aspect_ratio: assume ``fx == fy`` (one fewer unknown).
        min_views_principal_point: views needed by ``auto`` to estimate the principal point.
        return_ok: also return the :math:`(C,)` flags of cameras with a valid (positive focal) solution.

    Returns:
        :math:`(C, 3, 3)` camera matrices (never NaN; a failed camera gets ``f = max(W, H)`` at the centre
        and ``ok = False``).

    Example:
        >>> K = torch.tensor([[800., 0, 320], [0, 780, 240], [0, 0, 1]], dtype=torch.float64)
        >>> R = torch.eye(3, dtype=torch.float64)
        >>> Hs = torch.stack([K @ torch.stack([R[:, 0], R[:, 1], t], -1) for t in
        ...     torch.tensor([[0.1, 0.0, 2.0], [0.0, 0.2, 3.0]], dtype=torch.float64)])
        >>> zhang_intrinsics(Hs[None], image_size=(640, 480), principal_point="centre").shape
        torch.Size([1, 3, 3])
    """
    if principal_point not in _PP_MODES:
        raise ValueError(f"principal_point must be one of {_PP_MODES}, got {principal_point!r}.")
    unbatched = H.dim() == 3
    if unbatched:
        H = H[None]
        view_mask = None if view_mask is None else view_mask[None]
    check_tensor(H, "H", ["C", "V", "3", "3"], ["V", "3", "3"])
    C, V = H.shape[:2]
    if view_mask is None:
        view_mask = torch.ones(C, V, dtype=torch.bool, device=H.device)
    check_tensor(view_mask, "view_mask", [C, V])
    if principal_point == "centre" and image_size is None:
        raise ValueError("principal_point='centre' needs image_size.")
    dtype = H.dtype if H.dtype in (torch.float32, torch.float64) else torch.float64
    H = H.to(dtype)
    mask = view_mask.bool() & H.flatten(-2).isfinite().all(-1)
    H = torch.where(mask[..., None, None], H, torch.eye(3, dtype=dtype, device=H.device))
    n_views = mask.sum(-1)

    # normalising frame: pixels -> (p - c0) / s
    if image_size is not None:
        w, h = image_size
        c0 = torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], dtype=dtype, device=H.device).expand(C, 2)
        s = torch.full((C,), float(max(w, h)), dtype=dtype, device=H.device)
    else:
        t = H[..., :2, 2] / H[..., 2:, 2].clamp_min(1e-12)
        m = mask.to(dtype)[..., None]
        c0 = (t * m).sum(1) / m.sum(1).clamp_min(1)
        s = ((t - c0[:, None]).norm(dim=-1) * m[..., 0]).sum(1) / m[..., 0].sum(1).clamp_min(1)
        s = torch.where(s > 0, s, torch.ones_like(s)) * 4
    N = torch.zeros(C, 3, 3, dtype=dtype, device=H.device)
    N[:, 0, 0] = 1 / s
    N[:, 1, 1] = 1 / s
    N[:, :2, 2] = -c0 / s[:, None]
    N[:, 2, 2] = 1
    Hn = N[:, None] @ H
    Hn = Hn / Hn.flatten(-2).norm(dim=-1)[..., None, None]

    v12 = _v_rows(Hn, 0, 1)
    vdiff = _v_rows(Hn, 0, 0) - _v_rows(Hn, 1, 1)
    rows = torch.stack([v12, vdiff], -2)  # (C, V, 2, 5)
    rows = rows / rows.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    rows = rows * mask.to(dtype)[..., None, None]
    rows = rows.reshape(C, 2 * V, 5)
    if fix_aspect_ratio:  # B11 == B22
        rows = torch.cat([rows[..., :1] + rows[..., 1:2], rows[..., 2:]], -1)

    def expand_fa(b: torch.Tensor) -> torch.Tensor:
        return torch.cat([b[..., :1], b], -1) if fix_aspect_ratio else b

    # full zero-skew solution: b = (B11, B22, B13, B23, B33)
    b = expand_fa(_smallest_eigvec(rows.transpose(-1, -2) @ rows))
    b = b * torch.where(b[:, 0] < 0, -1.0, 1.0)[:, None]
    B11, B22, B13, B23, B33 = b.unbind(-1)
    safe11, safe22 = B11.clamp_min(1e-300), B22.clamp_min(1e-300)
    cxn, cyn = -B13 / safe11, -B23 / safe22
    lam = B33 - B13 * B13 / safe11 - B23 * B23 / safe22
    fxn2, fyn2 = lam / safe11, lam / safe22
    ok_full = (B11 > 0) & (B22 > 0) & (fxn2 > 0) & (fyn2 > 0) & (n_views >= 2)
    ok_full = ok_full & (cxn.abs() < 1e3) & (cyn.abs() < 1e3)
    full = torch.stack([fxn2.clamp_min(1e-300).sqrt(), fyn2.clamp_min(1e-300).sqrt(), cxn, cyn], -1)

    # principal point at the normalised origin: B13 = B23 = 0, unknowns (B11, B22, B33)
    rows_c = rows[..., [0, 3]] if fix_aspect_ratio else rows[..., [0, 1, 4]]  # (B11 = B22, B33)
    bc = _smallest_eigvec(rows_c.transpose(-1, -2) @ rows_c)
    bc = torch.cat([bc[..., :1], bc], -1) if fix_aspect_ratio else bc
    bc = bc * torch.where(bc[:, 2] < 0, -1.0, 1.0)[:, None]
    fxc2, fyc2 = bc[:, 2] / bc[:, 0], bc[:, 2] / bc[:, 1]
    ok_c = (fxc2 > 0) & (fyc2 > 0) & fxc2.isfinite() & fyc2.isfinite() & (n_views >= 1)
    zero = torch.zeros_like(fxc2)
    centre = torch.stack([fxc2.clamp_min(1e-300).sqrt(), fyc2.clamp_min(1e-300).sqrt(), zero, zero], -1)

    if principal_point == "estimate" or image_size is None:
        use_full, ok = torch.ones_like(ok_full), ok_full
    elif principal_point == "centre":
        use_full, ok = torch.zeros_like(ok_full), ok_c
    else:
        use_full = ok_full & (n_views >= min_views_principal_point)
        ok = use_full | ok_c
    params = torch.where(use_full[:, None], full, centre)
    fallback = torch.tensor([1.0, 1.0, 0.0, 0.0], dtype=dtype, device=H.device).expand(C, 4)
    params = torch.where(ok[:, None] & params.isfinite().all(-1, keepdim=True), params, fallback)
    ok = ok & params.isfinite().all(-1)
    fx, fy = params[:, 0] * s, params[:, 1] * s
    cx, cy = params[:, 2] * s + c0[:, 0], params[:, 3] * s + c0[:, 1]
    z, o = torch.zeros_like(fx), torch.ones_like(fx)
    K = torch.stack([fx, z, cx, z, fy, cy, z, z, o], -1).reshape(C, 3, 3)
    if unbatched:
        K, ok = K[0], ok[0]
    return (K, ok) if return_ok else K


def extrinsics_from_homography(K: torch.Tensor, H: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Board pose from a homography and the camera matrix.

    ``K^-1 H ~ [r1 r2 t]``; the scale is the mean of the first two column norms, its sign puts the board
    origin in front of the camera (``t_z > 0``), and ``[r1 r2 r1 x r2]`` is projected onto the nearest
    rotation with an SVD (determinant +1).

    Args:
        K: :math:`(*, 3, 3)` camera matrices, broadcast against ``H``'s leading dims (e.g. ``(C, 1, 3, 3)``
            for ``H`` of shape ``(C, V, 3, 3)``; a ``(C, 3, 3)`` K with ``(C, V, 3, 3)`` H is broadcast per
            camera automatically).
        H: :math:`(*, 3, 3)` board-to-pixel homographies.

    Returns:
        rvec :math:`(*, 3)` axis-angle and tvec :math:`(*, 3)`, OpenCV's world-to-camera convention.

    Example:
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> H = K @ torch.tensor([[1., 0, 0.1], [0, 1, 0.2], [0, 0, 2.0]], dtype=torch.float64)
        >>> rvec, tvec = extrinsics_from_homography(K, H)
        >>> tvec
        tensor([0.1000, 0.2000, 2.0000], dtype=torch.float64)
    """
    check_tensor(K, "K", ["*", "3", "3"])
    check_tensor(H, "H", ["*", "3", "3"])
    if K.dim() == 3 and H.dim() == 4 and K.shape[0] == H.shape[0]:
        K = K[:, None]
    R, t = rotation_translation_from_homography(K, H)
    rvec = log_so3(R)
    return rvec, t


def rotation_translation_from_homography(K: torch.Tensor, H: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation matrices :math:`(*, 3, 3)` and translations :math:`(*, 3)` as :func:`extrinsics_from_homography`.

    ``K`` and ``H`` broadcast against each other (no automatic per-camera unsqueeze here).
    """
    dtype = torch.promote_types(K.dtype, H.dtype)
    shape = broadcast_shapes(K.shape, H.shape)
    A = torch.linalg.solve(K.to(dtype).expand(shape), H.to(dtype).expand(shape))
    a1, a2, a3 = A[..., :, 0], A[..., :, 1], A[..., :, 2]
    lam = 2.0 / (a1.norm(dim=-1) + a2.norm(dim=-1)).clamp_min(1e-300)
    lam = lam * torch.where(a3[..., 2] < 0, -1.0, 1.0)
    r1, r2, t = a1 * lam[..., None], a2 * lam[..., None], a3 * lam[..., None]
    Q = torch.stack([r1, r2, torch.linalg.cross(r1, r2)], -1)
    Q = torch.where(Q.isfinite(), Q, torch.zeros_like(Q))
    U, _, Vh = torch.linalg.svd(Q)
    d = torch.linalg.det(U @ Vh)
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return U @ D @ Vh, t


class ZhangInit(nn.Module):
    r"""Module wrapper of :func:`zhang_intrinsics` (+ poses for every view).

    Args:
        principal_point: see :func:`zhang_intrinsics`.
        fix_aspect_ratio: assume ``fx == fy``.

    Shape:
        - H: :math:`(C, V, 3, 3)`, view_mask: :math:`(C, V)`
        - output: K :math:`(C, 3, 3)`, rvec :math:`(C, V, 3)`, tvec :math:`(C, V, 3)`, ok :math:`(C,)`

    Example:
        >>> K = torch.tensor([[800., 0, 320], [0, 780, 240], [0, 0, 1]], dtype=torch.float64)
        >>> H = K @ torch.tensor([[1., 0, 0.1], [0, 1, 0.2], [0, 0, 2.0]], dtype=torch.float64)
        >>> K0, rvec, tvec, ok = ZhangInit(principal_point="centre")(H[None, None], image_size=(640, 480))
        >>> rvec.shape
        torch.Size([1, 1, 3])
    """

    def __init__(self, principal_point: str = "auto", fix_aspect_ratio: bool = False) -> None:
        super().__init__()
        if principal_point not in _PP_MODES:
            raise ValueError(f"principal_point must be one of {_PP_MODES}, got {principal_point!r}.")
        self.principal_point = principal_point
        self.fix_aspect_ratio = fix_aspect_ratio

    def forward(
        self, H: torch.Tensor, view_mask: torch.Tensor | None = None, image_size: tuple[int, int] | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        K, ok = zhang_intrinsics(
            H, view_mask, image_size, self.principal_point, self.fix_aspect_ratio, return_ok=True
        )
        rvec, tvec = extrinsics_from_homography(K[..., None, :, :], H)
        return K, rvec, tvec, ok
