"""Copies of a view: pairwise corner differences between the views of a camera, batched over cameras.

Copies (the same photo twice, a board that did not move) are not independent observations: the solver drops
them before anything else (:func:`duplicate_views`), and :mod:`.degeneracy` flags near-identical views.
"""

from __future__ import annotations

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["batch_view_corners", "view_differences", "duplicate_views"]


def batch_view_corners(
    corners: torch.Tensor, valid: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor, bool]:
    r"""The corners of a camera's views (or of several cameras') as a batch over cameras, checked, with their mask.

    The view-pair measures (:func:`view_differences`, :func:`duplicate_views`,
    :mod:`~ccs_kornia.modules.calibration.quality.degeneracy`) take one camera or a batch of them alike.

    Args:
        corners: :math:`(C, V, N, 2)` or :math:`(V, N, 2)` px.
        valid: matching bool mask :math:`(C, V, N)` or :math:`(V, N)` (``None``: finite corners).

    Returns:
        corners :math:`(C, V, N, 2)`, valid :math:`(C, V, N)` bool (also False where a corner is not finite), and
        whether the input had no camera dimension (``C = 1`` added).

    Example:
        >>> corners, valid, unbatched = batch_view_corners(torch.zeros(3, 4, 2), None)
        >>> corners.shape, valid.shape, unbatched
        (torch.Size([1, 3, 4, 2]), torch.Size([1, 3, 4]), True)
    """
    check_tensor(corners, "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
    if valid is None:
        valid = corners.isfinite().all(-1)
    check_tensor(valid, "valid", corners.shape[:-1])
    unbatched = corners.dim() == 3
    if unbatched:
        corners, valid = corners[None], valid[None]
    return corners, valid.bool() & corners.isfinite().all(-1), unbatched


def view_differences(corners: torch.Tensor, valid: torch.Tensor | None = None, min_common: int = 4) -> torch.Tensor:
    r"""RMS distance (px) between the corners of every pair of views of a camera.

    Computed over the corners valid in both views, for the board order as given and reversed (a symmetric
    board may be detected rotated by 180 degrees, which reverses the grid order); the smaller is kept.

    Args:
        corners: :math:`(C, V, N, 2)` or :math:`(V, N, 2)` px.
        valid: matching bool mask (default: finite corners).
        min_common: pairs with fewer common corners get ``inf``.

    Returns:
        :math:`(C, V, V)` (or :math:`(V, V)`), ``inf`` on the diagonal.

    Example:
        >>> uv = torch.rand(3, 20, 2) * 100
        >>> d = view_differences(torch.stack([uv[0], uv[1], uv[0] + 0.1]))
        >>> round(float(d[0, 2]), 3), bool(d[0, 1] > 1)
        (0.141, True)
    """
    corners, valid, unbatched = batch_view_corners(corners, valid)
    C, V, N = valid.shape
    m = valid.to(torch.float64)
    # centred per camera (the sums below cancel less), zero where invalid
    x = corners.to(torch.float64).nan_to_num(0.0) * m[..., None]
    x = (x - x.sum((1, 2), keepdim=True) / m.sum((1, 2)).clamp_min(1)[:, None, None, None]) * m[..., None]
    s = (x * x).sum(-1)  # (C, V, N)
    # sum over common corners of |x_i - x_j|^2 = s_i . m_j + m_i . s_j - 2 x_i . x_j, for both grid orders of j
    ys = torch.stack([x, x.flip(-2)], 1)  # (C, 2, V, N, 2)
    my = torch.stack([m, m.flip(-1)], 1)
    sy = torch.stack([s, s.flip(-1)], 1)
    mT, sT = my.transpose(-1, -2), sy.transpose(-1, -2)
    n = m[:, None] @ mT  # (C, 2, V, V)
    sq = s[:, None] @ mT + m[:, None] @ sT - 2 * (x.flatten(2)[:, None] @ ys.flatten(3).transpose(-1, -2))
    rms = (sq.clamp_min(0) / n.clamp_min(1)).sqrt()
    out = torch.where(n >= min_common, rms, torch.full_like(rms, float("inf"))).amin(1)
    eye = torch.eye(V, dtype=torch.bool, device=corners.device)
    out = out.masked_fill(eye, float("inf"))
    return out[0] if unbatched else out


def duplicate_views(
    corners: torch.Tensor,
    valid: torch.Tensor | None = None,
    view_mask: torch.Tensor | None = None,
    tol: float = 0.5,
    differences: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""Index of the earlier view each view copies (corners within ``tol`` px RMS), -1 for distinct views.

    Copies are not independent observations (the same photo twice, or a board that did not move): kept, they
    shrink the reported uncertainty by the square root of the number of copies while adding no information.

    Args:
        corners: :math:`(C, V, N, 2)` or :math:`(V, N, 2)` px.
        valid: matching bool mask.
        view_mask: :math:`(C, V)` views to consider (default: views with >= 4 valid corners).
        tol: RMS corner difference in px.
        differences: :math:`(C, V, V)` from :func:`view_differences` when already computed.

    Returns:
        :math:`(C, V)` int64.

    Example:
        >>> uv = torch.rand(2, 20, 2) * 100
        >>> duplicate_views(torch.stack([uv[0], uv[1], uv[0], uv[0] + 0.01])).tolist()
        [-1, -1, 0, 0]
    """
    corners, valid, unbatched = batch_view_corners(corners, valid)
    C, V, _ = valid.shape
    if view_mask is None:
        view_mask = valid.sum(-1) >= 4
    elif unbatched:
        view_mask = view_mask[None]
    view_mask = view_mask.bool()
    d = view_differences(corners, valid) if differences is None else (differences[None] if unbatched else differences)
    close = (d <= tol) & view_mask[:, :, None] & view_mask[:, None, :]
    earlier = torch.ones(V, V, dtype=torch.bool, device=d.device).tril(-1)  # [j, i]: i < j
    close = close & earlier
    first = torch.where(close.any(-1), close.float().argmax(-1), torch.full((C, V), -1, device=d.device))
    return first[0] if unbatched else first
