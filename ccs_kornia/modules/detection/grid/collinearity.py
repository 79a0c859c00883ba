"""The paper's collinearity refinement (*collineation post-processing*, Sec. III-B), batched torch.

:func:`collinearity_refine` / :class:`CollinearityRefiner` fit a straight line to every row and every column of
an organised board and replace each corner by the intersection of its row and column lines. This also recovers
missing corners. It assumes an undistorted image (the paper removes distortion first); it is off in the
learned detector by default (``LearnedChessboardDetector(collinearity=True)`` switches it on; the benchmark's
corner section reports both).
"""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.runtime.checks import check_board_size, check_tensor

__all__ = ["collinearity_refine", "CollinearityRefiner"]


def _fit_lines(pts: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted total-least-squares lines along dim -2.

    Args:
        pts: (..., L, 2) points; w: (..., L) weights.

    Returns:
        unit normals (..., 2) and offsets (...,) with ``normal . x = offset`` on the line.
    """
    wsum = w.sum(-1, keepdim=True).clamp_min(1e-12)
    mean = (w.unsqueeze(-1) * pts).sum(-2) / wsum
    d = pts - mean.unsqueeze(-2)
    sxx = (w * d[..., 0] ** 2).sum(-1)
    syy = (w * d[..., 1] ** 2).sum(-1)
    sxy = (w * d[..., 0] * d[..., 1]).sum(-1)
    # principal direction of the 2x2 scatter matrix in closed form
    theta = 0.5 * torch.atan2(2.0 * sxy, sxx - syy)
    normal = torch.stack([-torch.sin(theta), torch.cos(theta)], -1)
    return normal, (normal * mean).sum(-1)


def _concurrent_lines(
    pts: torch.Tensor, w: torch.Tensor, normal: torch.Tensor, offset: torch.Tensor, line_w: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Refit a family of lines (all rows, or all columns, of each board) through one common point.

    Under a homography (no distortion) the rows of a board meet in one vanishing point, and so do the
    columns. The point is the least-squares meeting point of the free lines (homogeneous, so it may
    lie at infinity); each line is then refitted through it, leaving one free parameter per line
    instead of two, which steadies lines with few or clustered corners.

    Args:
        pts: (B, L, K, 2) points of each line; w: (B, L, K) weights.
        normal, offset: (B, L, 2), (B, L) free lines ``normal . x = offset``.
        line_w: (B, L) weight of each line in the meeting-point estimate (0 for undefined lines).

    Returns:
        unit normals (B, L, 2) and offsets (B, L) of the concurrent lines.
    """
    lines = torch.cat([normal, -offset.unsqueeze(-1)], -1)  # (B, L, 3), homogeneous
    scatter = torch.einsum("bl,bli,blj->bij", line_w, lines, lines)
    _, vecs = torch.linalg.eigh(scatter)
    basis = vecs[..., 1:]  # (B, 3, 2): lines through the meeting point are l = basis @ a
    hom = torch.cat([pts, torch.ones_like(pts[..., :1])], -1)  # (B, L, K, 3)
    m3 = torch.einsum("blk,blki,blkj->blij", w, hom, hom)
    m = basis.transpose(-1, -2).unsqueeze(1) @ m3 @ basis.unsqueeze(1)  # (B, L, 2, 2)
    e2 = basis[:, :2, :]
    n = (e2.transpose(-1, -2) @ e2).unsqueeze(1).expand_as(m)  # |normal|^2 = a^T n a
    # smallest root of det(m - lambda n) = 0 (generalised 2x2 eigenproblem), stable form
    qa = n[..., 0, 0] * n[..., 1, 1] - n[..., 0, 1] ** 2
    qb = m[..., 0, 0] * n[..., 1, 1] + m[..., 1, 1] * n[..., 0, 0] - 2.0 * m[..., 0, 1] * n[..., 0, 1]
    qc = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] ** 2
    disc = (qb**2 - 4.0 * qa * qc).clamp_min(1e-30)
    lam = 2.0 * qc / (qb + torch.sqrt(disc)).clamp_min(1e-30)
    r = m - lam[..., None, None] * n
    # null vector of the (singular) 2x2 matrix r, from whichever row is better conditioned
    a0 = torch.stack([-r[..., 0, 1], r[..., 0, 0]], -1)
    a1 = torch.stack([-r[..., 1, 1], r[..., 1, 0]], -1)
    a = torch.where((a0.norm(dim=-1) >= a1.norm(dim=-1)).unsqueeze(-1), a0, a1)
    line = (basis.unsqueeze(1) @ a.unsqueeze(-1))[..., 0]  # (B, L, 3)
    scale = line[..., :2].norm(dim=-1, keepdim=True).clamp_min(1e-12)
    line = line / scale
    return line[..., :2], -line[..., 2]


def collinearity_refine(
    corners: torch.Tensor,
    valid: torch.Tensor,
    board_size: tuple[int, int],
    iterations: int = 2,
    min_points: int = 3,
    blend: float = 1.0,
    concurrent: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Refine organised corners by fitting straight rows and columns and intersecting them.

    The paper's collineation post-processing. Every row ``j`` (``cols`` corners) and every column
    ``i`` (``rows`` corners) gets a total-least-squares line fitted to its valid corners (all lines of
    all boards at once, closed-form 2x2 eigenvector); each corner becomes the intersection of its
    row and column lines, which also recovers corners that are missing. With ``iterations > 1`` the
    fits are repeated with Cauchy weights on each corner's distance to its lines, so a single bad
    corner cannot bend its row and column.

    .. note:: Straight lines assume an image **without distortion** (the paper removes distortion
       first); on a distorted image this pulls corners off their true (curved) rows.

    Args:
        corners: :math:`(B, N, 2)` corners in grid order ``n = j*cols + i``.
        valid: :math:`(B, N)` bool, which corners were measured.
        board_size: ``(cols, rows)``.
        iterations: line fits (1: plain least squares; more: robust reweighting).
        min_points: a line is defined by at least this many valid corners (2 works, 3 is safer).
        blend: weight of the line intersection against the measured position for measured corners
            (1.0: the intersection, as in the paper; missing corners always take the intersection).
        concurrent: also make all rows meet in one (vanishing) point and all columns in another, as
            they do in a perspective image; much steadier lines for rows/columns with few corners,
            at the price of assuming the perspective model more strictly (``False``: the paper's
            independent lines).

    Returns:
        refined corners :math:`(B, N, 2)` and valid :math:`(B, N)` (measured, or both lines defined).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> pts = board_object_points(5, 4)[:, :2][None] * 30 + 20
        >>> valid = torch.ones(1, 20, dtype=torch.bool); valid[0, 7] = False
        >>> refined, ok = collinearity_refine(pts + 0.1 * torch.randn_like(pts), valid, (5, 4))
        >>> bool(ok.all()), bool((refined - pts).norm(dim=-1).max() < 0.5)
        (True, True)
    """
    cols, rows = check_board_size(board_size)
    check_tensor(corners, "corners", ["B", "N", "2"], what=f"for a {cols}x{rows} board", N=cols * rows)
    check_tensor(valid, "valid", corners.shape[:2])
    if iterations < 1 or min_points < 2:
        raise ValueError(f"iterations must be >= 1 and min_points >= 2, got {iterations}, {min_points}.")
    if not 0.0 <= blend <= 1.0:
        raise ValueError(f"blend must be in [0, 1], got {blend}.")
    bsz = corners.shape[0]
    measured = corners.reshape(bsz, rows, cols, 2)
    vmask = valid.reshape(bsz, rows, cols)
    # zero the unmeasured entries so padding values (nan, garbage) cannot leak into sums or gradients
    grid = torch.where(vmask.unsqueeze(-1), measured, torch.zeros_like(measured))
    base_w = vmask.to(corners.dtype)
    # work in board-normalised coordinates (centred, unit RMS radius): well-conditioned homogeneous lines
    count = base_w.sum((1, 2)).clamp_min(1.0)[:, None, None, None]
    centre = (grid * base_w.unsqueeze(-1)).sum((1, 2), keepdim=True) / count
    spread = ((((grid - centre) ** 2).sum(-1) * base_w).sum((1, 2)) / count[..., 0, 0, 0]).sqrt()
    spread = spread.clamp_min(1e-9)[:, None, None, None]
    grid = torch.where(vmask.unsqueeze(-1), (grid - centre) / spread, torch.zeros_like(grid))
    row_ok = vmask.sum(2) >= min_points  # (B, rows)
    col_ok = vmask.sum(1) >= min_points  # (B, cols)
    weight = base_w
    for it in range(iterations):
        n_row, c_row = _fit_lines(grid, weight)  # (B, rows, 2), (B, rows)
        n_col, c_col = _fit_lines(grid.transpose(1, 2), weight.transpose(1, 2))  # (B, cols, 2), (B, cols)
        if concurrent:
            row_w = row_ok.to(grid.dtype) * weight.sum(2)
            col_w = col_ok.to(grid.dtype) * weight.sum(1)
            n_row, c_row = _concurrent_lines(grid, weight, n_row, c_row, row_w)
            n_col, c_col = _concurrent_lines(grid.transpose(1, 2), weight.transpose(1, 2), n_col, c_col, col_w)
        nr = n_row[:, :, None, :]
        cr = c_row[:, :, None]
        nc = n_col[:, None, :, :]
        cc = c_col[:, None, :]
        det = nr[..., 0] * nc[..., 1] - nr[..., 1] * nc[..., 0]  # sine of the row/column angle
        det_safe = torch.where(det.abs() > 1e-6, det, torch.ones_like(det))
        x = (cr * nc[..., 1] - cc * nr[..., 1]) / det_safe
        y = (nr[..., 0] * cc - nc[..., 0] * cr) / det_safe
        inter = torch.stack([x, y], -1)  # (B, rows, cols, 2)
        if it + 1 < iterations:
            # Cauchy weights on the distance of each measured corner to its row and column lines
            r_row = (grid * nr).sum(-1) - cr
            r_col = (grid * nc).sum(-1) - cc
            res = torch.sqrt(r_row**2 + r_col**2 + 1e-18)
            masked = torch.where(vmask, res, torch.full_like(res, float("nan"))).reshape(bsz, -1)
            med = torch.nanmedian(masked, dim=1).values.nan_to_num(0.0)
            scale = (2.5 * 1.4826 * med).clamp_min(1e-6)[:, None, None]
            weight = base_w / (1.0 + (res / scale) ** 2)
    inter = inter * spread + centre
    inter_ok = row_ok[:, :, None] & col_ok[:, None, :] & (det.abs() > 1e-6)
    blended = torch.where(vmask.unsqueeze(-1), blend * inter + (1.0 - blend) * measured, inter)
    out = torch.where(inter_ok.unsqueeze(-1), blended, measured)
    return out.reshape(bsz, -1, 2), (vmask | inter_ok).reshape(bsz, -1)


class CollinearityRefiner(nn.Module):
    r"""Module wrapper of :func:`collinearity_refine` (assumes undistorted corners).

    Example:
        >>> ref = CollinearityRefiner((4, 3))
        >>> c, v = ref(torch.rand(2, 12, 2), torch.ones(2, 12, dtype=torch.bool))
        >>> c.shape, v.shape
        (torch.Size([2, 12, 2]), torch.Size([2, 12]))
    """

    def __init__(
        self,
        board_size: tuple[int, int],
        iterations: int = 2,
        min_points: int = 3,
        blend: float = 1.0,
        concurrent: bool = True,
    ) -> None:
        super().__init__()
        self.board_size = check_board_size(board_size)
        self.iterations = iterations
        self.min_points = min_points
        self.blend = blend
        self.concurrent = concurrent

    def forward(self, corners: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return collinearity_refine(
            corners, valid, self.board_size, self.iterations, self.min_points, self.blend, self.concurrent
        )

    def extra_repr(self) -> str:
        return f"board_size={self.board_size}, iterations={self.iterations}, blend={self.blend}"
