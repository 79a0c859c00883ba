"""Marks inside the light squares of a chessboard: ArUco-like codes (ChArUco) and dot / tile codes (ECoCheck).

A view's marks are a fine raster over the checker area ``[-1, cols] x [-1, rows]`` (``res`` cells per square),
each cell holding the fraction of its area covered by dark ink (discs are rasterised with 4x4 sub-samples per
cell). The renderer box-filters this raster exactly like the board: the integral of a piecewise-constant
raster over an axis-aligned box is a difference of its summed-area table, which is *exactly* bilinear
between the table's lattice points, so any footprint (a fraction of a cell or many squares wide) costs four
bilinear look-ups. Marks keep a margin inside their square, so the inner corners -- the ground truth --
are untouched.

Kinds (:data:`MARK_KINDS`), per view:

* ``none``: a plain chessboard;
* ``aruco``: a square marker of side ``fill`` (fraction of the square) made of 6x6 cells, a dark border
  around 4x4 random bits, as on ChArUco boards;
* ``dots``: a ``k x k`` grid of dots (``k`` = ``dot_grid``) whose bits are random; ``fill`` is the area
  fraction of the square that the dots cover when every bit is set (ECoCheck-like);
* ``tiles``: as ``dots`` with small squares instead of discs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["MARK_KINDS", "MarkPattern", "make_marks"]

#: kinds of marks inside the light squares
MARK_KINDS: tuple[str, ...] = ("none", "aruco", "dots", "tiles")
_RES = 36  # raster cells per square side (6x6-cell ArUco markers of side 1/6 .. 5/6 fit exactly)


@dataclass
class MarkPattern:
    """Summed-area tables of the mark rasters of ``B`` views.

    Attributes:
        sat: :math:`(B, G_h + 1, G_w + 1)` float64 cumulative ink area (in raster cells), zero first row/column.
        res: raster cells per square side.
    """

    sat: Tensor
    res: int

    def to(self, device) -> MarkPattern:
        return MarkPattern(self.sat.to(device), self.res)

    def coverage(self, u: Tensor, v: Tensor, wu: Tensor, wv: Tensor, bidx: Tensor | None = None) -> Tensor:
        """Mean ink over the boxes ``[u -+ wu/2] x [v -+ wv/2]`` (board squares).

        Args:
            u, v, wu, wv: :math:`(B, H, W)` (one view per leading index) or :math:`(P,)` with ``bidx``.
            bidx: :math:`(P,)` view index of each flattened sample.

        Returns:
            coverage in ``[0, 1]``, ``u``'s shape and dtype.
        """
        sat = self.sat
        r = float(self.res)
        gh, gw = sat.shape[1] - 1, sat.shape[2] - 1
        flat = sat.reshape(sat.shape[0], -1)
        stride = gw + 1

        def F(x: Tensor, y: Tensor) -> Tensor:
            x = x.clamp(0.0, float(gw))
            y = y.clamp(0.0, float(gh))
            i = x.floor().clamp(max=gw - 1)
            j = y.floor().clamp(max=gh - 1)
            a, c = x - i, y - j
            base = (j * stride + i).long()
            if bidx is None:
                shape = base.shape
                base = base.reshape(shape[0], -1)
                g = [flat.gather(1, base + o).view(shape) for o in (0, 1, stride, stride + 1)]
            else:
                src = flat.reshape(-1)
                base = base + bidx * flat.shape[1]
                g = [src[base + o] for o in (0, 1, stride, stride + 1)]
            return (g[0] * (1 - a) + g[1] * a) * (1 - c) + (g[2] * (1 - a) + g[3] * a) * c

        u64, v64 = u.double(), v.double()
        hu, hv = 0.5 * wu.double() * r, 0.5 * wv.double() * r
        xc, yc = (u64 + 1.0) * r, (v64 + 1.0) * r
        x0, x1, y0, y1 = xc - hu, xc + hu, yc - hv, yc + hv
        total = F(x1, y1) - F(x0, y1) - F(x1, y0) + F(x0, y0)
        return (total / (4 * hu * hv).clamp_min(1e-30)).clamp(0.0, 1.0).to(u.dtype)


def _disc_coverage(res: int, centres: Tensor, radius: Tensor, square: bool) -> Tensor:
    """Ink of discs (or squares of half side ``radius``) at ``centres`` ``(K, 2)`` (raster units inside one
    square) on a ``res x res`` raster, 4x4 sub-samples per cell; ``(K, res, res)``."""
    sub = 4
    t = (torch.arange(res * sub, dtype=torch.float64) + 0.5) / sub
    y, x = torch.meshgrid(t, t, indexing="ij")
    dx = x[None] - centres[:, 0, None, None]
    dy = y[None] - centres[:, 1, None, None]
    rr = radius.view(-1, 1, 1)
    inside = torch.maximum(dx.abs(), dy.abs()) <= rr if square else dx * dx + dy * dy <= rr * rr
    return inside.double().view(-1, res, sub, res, sub).mean((2, 4))


def make_marks(
    kind: Tensor,
    cols: Tensor,
    rows: Tensor,
    generator: torch.Generator,
    fill: Tensor | float = 0.7,
    dot_grid: int = 3,
    device="cpu",
) -> MarkPattern:
    """Random marks for ``B`` boards.

    Args:
        kind: :math:`(B,)` long index into :data:`MARK_KINDS`.
        cols, rows: :math:`(B,)` inner corners per row / rows.
        generator: random source of the bits.
        fill: ArUco marker side (fraction of the square, 1/6 .. 5/6), or the dots' / tiles' area fraction with
            every bit set (0.05 .. 0.6); a number or :math:`(B,)`.
        dot_grid: dots per side of a square's ``k x k`` grid.
        device: where the tables go.

    Returns:
        :class:`MarkPattern`.

    Example:
        >>> m = make_marks(torch.tensor([1, 2]), torch.tensor([5, 5]), torch.tensor([4, 4]),
        ...                torch.Generator().manual_seed(0))
        >>> m.sat.shape
        torch.Size([2, 181, 217])
    """
    b = int(kind.shape[0])
    res = _RES
    cols, rows = cols.cpu().long(), rows.cpu().long()
    fill_t = torch.as_tensor(fill, dtype=torch.float64).expand(b) if not isinstance(fill, Tensor) or fill.dim() == 0 \
        else fill.double().cpu()
    nx, ny = int(cols.max()) + 1, int(rows.max()) + 1
    raster = torch.zeros(b, ny * res, nx * res, dtype=torch.float64)
    for i in range(b):
        k = int(kind[i])
        if k == 0:
            continue
        c, rw = int(cols[i]) + 1, int(rows[i]) + 1
        jj, ii = torch.meshgrid(torch.arange(rw), torch.arange(c), indexing="ij")
        light = ((ii + jj) % 2 == 1).reshape(-1)  # square (ii - 1, jj - 1); the top-left square is dark
        n_sq = int(light.sum())
        sq_i, sq_j = ii.reshape(-1)[light], jj.reshape(-1)[light]
        f = float(fill_t[i])
        if MARK_KINDS[k] == "aruco":
            cell = max(1, min(5, round(f * 6)))  # raster cells per marker cell
            side = 6 * cell
            margin = (res - side) // 2
            bits = torch.rand(n_sq, 4, 4, generator=generator) < 0.5
            marker = torch.ones(n_sq, 6, 6, dtype=torch.float64)  # dark border
            marker[:, 1:5, 1:5] = bits.double()
            patch = torch.zeros(n_sq, res, res, dtype=torch.float64)
            patch[:, margin:margin + side, margin:margin + side] = marker.repeat_interleave(cell, 1).repeat_interleave(cell, 2)
        else:
            kg = int(dot_grid)
            f = min(max(f, 0.01), 0.6)
            margin = 0.15 * res
            pitch = (res - 2 * margin) / kg
            if MARK_KINDS[k] == "dots":
                radius = res * math.sqrt(f / (math.pi * kg * kg))
            else:
                radius = 0.5 * res * math.sqrt(f) / kg
            radius = min(radius, 0.48 * pitch)
            t = margin + pitch * (torch.arange(kg, dtype=torch.float64) + 0.5)
            cy, cx = torch.meshgrid(t, t, indexing="ij")
            site = _disc_coverage(res, torch.stack([cx.reshape(-1), cy.reshape(-1)], -1),
                                  torch.full((kg * kg,), radius, dtype=torch.float64), MARK_KINDS[k] == "tiles")
            bits = (torch.rand(n_sq, kg * kg, generator=generator) < 0.5).double()
            patch = torch.einsum("nk,kyx->nyx", bits, site)
        view = raster[i].view(ny, res, nx, res)
        view[sq_j, :, sq_i, :] = patch
    sat = torch.zeros(b, ny * res + 1, nx * res + 1, dtype=torch.float64)
    sat[:, 1:, 1:] = raster.cumsum(1).cumsum(2)
    return MarkPattern(sat.to(device), res)
