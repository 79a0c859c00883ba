"""Prediction of the grid cells the detector missed, from their row and column neighbours."""

from __future__ import annotations

import torch

from ccs_kornia.modules._checks import check_board_size

__all__ = ["predict_missing_corners"]


def predict_missing_corners(
    corners: torch.Tensor, valid: torch.Tensor, board_size: tuple[int, int], passes: int = 3
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Predict invalid grid cells from their row and column neighbours (local, so it follows distortion).

    Each missing cell takes the mean of every available estimate: the midpoint of its two neighbours
    along a row or column, and the quadratic extrapolation ``3 p_1 - 3 p_2 + p_3`` from the three next
    cells on either side along a row or column (linear ``2 p_1 - p_2`` when only two exist). A global
    board homography cannot follow strong barrel distortion near the image border; these local
    estimates can. Chains of missing cells fill over successive passes.

    Args:
        corners: :math:`(B, N, 2)` grid-ordered corners, ``N = cols * rows``.
        valid: :math:`(B, N)` bool.
        board_size: ``(cols, rows)``.
        passes: filling passes.

    Returns:
        corners with predictions written into the missing cells, and the mask of cells that now hold a
        measured or predicted position.

    Example:
        >>> from ccs_kornia.camera import board_object_points
        >>> pts = board_object_points(4, 3)[None, :, :2] * 10
        >>> valid = torch.ones(1, 12, dtype=torch.bool); valid[0, 0] = False
        >>> out, filled = predict_missing_corners(pts * valid[..., None], valid, (4, 3))
        >>> bool(filled.all()), torch.allclose(out, pts)
        (True, True)
    """
    cols, rows = check_board_size(board_size)
    if corners.dim() != 3 or corners.shape[1] != cols * rows or valid.shape != corners.shape[:2]:
        raise ValueError(f"corners must be (B, {cols * rows}, 2) with a matching valid mask, got {tuple(corners.shape)}.")
    b = corners.shape[0]
    g = corners.reshape(b, rows, cols, 2).clone()
    v = valid.reshape(b, rows, cols).clone()

    def shifted(x: torch.Tensor, k: int, dim: int) -> torch.Tensor:
        # value of the cell k steps further along ``dim`` (zero / False beyond the board)
        out = torch.zeros_like(x)
        n = x.shape[dim]
        if abs(k) >= n:
            return out
        src = x.narrow(dim, max(k, 0), n - abs(k))
        out.narrow(dim, max(-k, 0), n - abs(k)).copy_(src)
        return out

    for _ in range(passes):
        if bool(v.all()):
            break
        total = torch.zeros_like(g)
        count = torch.zeros(g.shape[:-1], dtype=g.dtype, device=g.device)
        for dim in (1, 2):  # rows (along j) and columns (along i)
            for sgn in (1, -1):
                p1, v1 = shifted(g, sgn, dim), shifted(v, sgn, dim)
                p2, v2 = shifted(g, 2 * sgn, dim), shifted(v, 2 * sgn, dim)
                p3, v3 = shifted(g, 3 * sgn, dim), shifted(v, 3 * sgn, dim)
                quad = v1 & v2 & v3
                lin = v1 & v2 & ~v3
                est = torch.where(quad[..., None], 3 * p1 - 3 * p2 + p3, 2 * p1 - p2)
                use = quad | lin
                total = total + est * use[..., None]
                count = count + use
            pa, va = shifted(g, 1, dim), shifted(v, 1, dim)
            pb, vb = shifted(g, -1, dim), shifted(v, -1, dim)
            mid = va & vb
            # the midpoint is the most reliable estimate: count it twice
            total = total + (pa + pb) * mid[..., None]
            count = count + 2 * mid
        fill = ~v & (count > 0)
        g = torch.where(fill[..., None], total / count.clamp_min(1)[..., None], g)
        v = v | fill
    return g.reshape(b, -1, 2), v.reshape(b, -1)
