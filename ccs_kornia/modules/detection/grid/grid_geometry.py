"""Geometry of an organised board's grid: the spacing at each corner (:func:`grid_spacing`) and the bend of its
rows and columns (:func:`line_sagitta`).

A lens's distortion bends the board's rows and columns; perspective does not. Window-based refinements that assume
a point-symmetric neighbourhood (:mod:`~ccs_kornia.modules.detection.refine.symmetry_refine`) are biased by that bend, more
the wider their window. :func:`line_sagitta` estimates the bend at each corner from the corners themselves: a cubic
(a parabola on lines of three or four corners) is fitted (least squares) to every row and every column in the
line's own frame, which averages the corners' noise over the line, and its second derivative at the corner gives the
*sagitta*: the distance of the corner from the chord between its two neighbours one grid step away on either side,
``|y''| s^2 / 2`` for a step of ``s`` px.
"""

from __future__ import annotations

import torch
from kornia.geometry.line import fit_line

from ccs_kornia.runtime.checks import check_board_size, check_points

__all__ = ["grid_spacing", "line_sagitta"]

#: fewest valid corners on a line for a cubic fit (4 coefficients and one degree of freedom); shorter lines get a
#: parabola, and lines of fewer than :data:`MIN_LINE_CORNERS` an unknown bend (``inf``)
CUBIC_LINE_CORNERS = 5
MIN_LINE_CORNERS = 3
#: sine of the cell angle below which the spacing shrinks (30 degrees; with 45, a sheared board at the rim of a
#: rendered wide lens was confirmed and doubled its camera's E_IP, ``docs/measurements.md``)
SHEAR_SIN = 0.5
#: smallest factor by which a sheared cell shrinks the spacing (a degenerate, collinear neighbourhood keeps a window)
MIN_SHEAR_SHRINK = 0.25


def grid_spacing(corners: torch.Tensor, valid: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    """Distance from each grid corner to its nearest valid 4-neighbour in the grid, ``(B, N)``, shrunk where the
    cells are sheared below 30 degrees (by ``sin(angle) / sin(30 degrees)``, at most by :data:`MIN_SHEAR_SHRINK`).

    Windows of a fraction of this spacing stay clear of the neighbouring edges: on a board seen at a grazing angle the
    cells are thin parallelograms, and the next edge passes a corner at the cell's height, closer than any neighbour
    (``docs/measurements.md``).

    Args:
        corners: :math:`(B, N, 2)` corners in grid order, ``N = cols * rows``.
        valid: :math:`(B, N)` bool.
        board_size: ``(cols, rows)``.

    Returns:
        :math:`(B, N)` spacing in px (``inf`` where no neighbour is valid).

    Example:
        >>> square = torch.tensor([[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]]])
        >>> grid_spacing(square, torch.ones(1, 4, dtype=torch.bool), (2, 2))
        tensor([[10., 10., 10., 10.]])
        >>> sheared = torch.tensor([[[0.0, 0.0], [10.0, 0.0], [20.0, 5.0], [30.0, 5.0]]])  # 14-degree cells
        >>> grid_spacing(sheared, torch.ones(1, 4, dtype=torch.bool), (2, 2)).round(decimals=2)
        tensor([[4.8500, 4.8500, 4.8500, 4.8500]])
    """
    cols, rows = board_size
    b = corners.shape[0]
    g = corners.reshape(b, rows, cols, 2)
    v = valid.reshape(b, rows, cols)
    inf = torch.full((b, rows, cols), float("inf"), device=corners.device, dtype=corners.dtype)
    best = inf.clone()
    dx = (g[:, :, 1:] - g[:, :, :-1]).norm(dim=-1).masked_fill(~(v[:, :, 1:] & v[:, :, :-1]), float("inf"))
    dy = (g[:, 1:] - g[:, :-1]).norm(dim=-1).masked_fill(~(v[:, 1:] & v[:, :-1]), float("inf"))
    best[:, :, 1:] = torch.minimum(best[:, :, 1:], dx)
    best[:, :, :-1] = torch.minimum(best[:, :, :-1], dx)
    best[:, 1:] = torch.minimum(best[:, 1:], dy)
    best[:, :-1] = torch.minimum(best[:, :-1], dy)
    # a grazing view shears the cells into thin parallelograms: the next edge then passes a corner at the cell's
    # height (side x sin angle), closer than its neighbours; below 30 degrees the spacing shrinks accordingly
    ex = torch.zeros_like(g)
    ey = torch.zeros_like(g)
    ex_edge = (g[:, :, 1:] - g[:, :, :-1]) * (v[:, :, 1:] & v[:, :, :-1])[..., None]
    ey_edge = (g[:, 1:] - g[:, :-1]) * (v[:, 1:] & v[:, :-1])[..., None]
    ex[:, :, 1:] += ex_edge
    ex[:, :, :-1] += ex_edge
    ey[:, 1:] += ey_edge
    ey[:, :-1] += ey_edge
    norms = ex.norm(dim=-1) * ey.norm(dim=-1)
    sin = (ex[..., 0] * ey[..., 1] - ex[..., 1] * ey[..., 0]).abs() / norms.clamp_min(1e-12)
    shrink = torch.where(norms > 0, (sin / SHEAR_SIN).clamp(MIN_SHEAR_SHRINK, 1.0), torch.ones_like(sin))
    best = best * shrink
    return best.reshape(b, -1)


def _lines_sagitta(pts: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Sagitta at each point of lines ``pts`` :math:`(L, P, 2)` with weights ``w`` :math:`(L, P)` in {0, 1}:
    :math:`(L, P)`, ``inf`` on lines with fewer than :data:`MIN_LINE_CORNERS` valid points."""
    sag = torch.full_like(w, float("inf"))
    wsum = w.sum(-1)
    fitted = wsum >= MIN_LINE_CORNERS
    if not bool(fitted.any()):
        return sag
    pts, w, wsum = pts[fitted], w[fitted], wsum[fitted, None]
    # the line's frame: kornia's total-least-squares line through the weighted centroid
    line = fit_line(pts, w)
    u, origin = line.direction, line.origin
    if not (pts.requires_grad or w.requires_grad):  # kornia wraps a constant line's tensors as parameters
        u, origin = u.detach(), origin.detach()
    d = pts - origin[:, None]
    t = (d * u[:, None]).sum(-1) * w
    y = (d[..., 1] * u[:, None, 0] - d[..., 0] * u[:, None, 1]) * w
    scale = t.abs().amax(-1, keepdim=True).clamp_min(1e-6)
    ts = t / scale  # in [-1, 1]: a well-conditioned cubic
    powers = torch.stack([torch.ones_like(ts), ts, ts**2, ts**3], -1) * w[..., None]
    second = []
    for degree in (2, 3):
        basis = powers[..., : degree + 1]
        normal = basis.transpose(-1, -2) @ basis + 1e-9 * torch.eye(degree + 1, dtype=pts.dtype, device=pts.device)
        coef = torch.linalg.solve(normal, (basis * y[..., None]).sum(-2))
        cubic = 6 * coef[:, 3:4] * ts if degree == 3 else 0.0
        second.append((2 * coef[:, 2:3] + cubic) / scale**2)  # y'' in px^-1
    second = torch.where(wsum >= CUBIC_LINE_CORNERS, second[1], second[0])
    inf = torch.full_like(t, float("inf"))
    span = torch.where(w > 0, t, -inf).amax(-1, keepdim=True) - torch.where(w > 0, t, inf).amin(-1, keepdim=True)
    step = span / (wsum - 1)  # mean grid step along the line
    sag[fitted] = second.abs() * step**2 / 2
    return sag


def line_sagitta(corners: torch.Tensor, valid: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    r"""Bend of the board's lines at each corner: the larger of its row's and its column's sagitta (px).

    Args:
        corners: :math:`(B, N, 2)` corners in grid order, ``N = cols * rows``.
        valid: :math:`(B, N)` bool, the corners to fit.
        board_size: ``(cols, rows)`` inner corners.

    Returns:
        :math:`(B, N)` distance (px) of each corner from the chord between its neighbours one grid step away on its
        row or column, from a cubic fitted to each line (a parabola on lines of 3-4 valid corners, ``inf`` on shorter
        ones).

    Example:
        >>> xs, ys = torch.meshgrid(torch.arange(7.0), torch.arange(5.0), indexing="xy")
        >>> grid = 20 * torch.stack([xs, ys], -1).reshape(1, 35, 2)
        >>> straight = line_sagitta(grid, torch.ones(1, 35, dtype=torch.bool), (7, 5))
        >>> bool(straight.max() < 1e-3)
        True
        >>> bent = grid.clone(); bent[..., 1] += 0.01 * (bent[..., 0] - 60) ** 2  # rows: y'' = 0.02 / px
        >>> line_sagitta(bent, torch.ones(1, 35, dtype=torch.bool), (7, 5)).median().item()  # 0.02 * 20^2 / 2
        4.0
    """
    check_points(corners, "corners")
    cols, rows = check_board_size(board_size)
    b, n = corners.shape[:2]
    if n != cols * rows:
        raise ValueError(f"corners has {n} points but board_size {board_size} needs {cols * rows}.")
    pts = corners.double().reshape(b, rows, cols, 2)
    w = valid.reshape(b, rows, cols).double()
    w = w * torch.isfinite(pts).all(-1)
    pts = torch.nan_to_num(pts)
    along_rows = _lines_sagitta(pts.reshape(b * rows, cols, 2), w.reshape(b * rows, cols)).reshape(b, rows, cols)
    along_cols = _lines_sagitta(pts.transpose(1, 2).reshape(b * cols, rows, 2),
                                w.transpose(1, 2).reshape(b * cols, rows)).reshape(b, cols, rows).transpose(1, 2)
    return torch.maximum(along_rows, along_cols).reshape(b, n).to(corners.dtype)
