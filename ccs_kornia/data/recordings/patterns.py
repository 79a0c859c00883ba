"""What is printed on a calibration board, as the renderer of recordings sees it: the corners' object points and the
grey level of any pixel whose footprint falls on the board's plane.

A pixel arrives as its board-plane coordinates ``(X, Y)`` (world units, the object points' frame) and the footprint
Jacobian ``dX/dx, dX/dy, dY/dx, dY/dy`` (world units per pixel):

* :class:`ChessPattern`: a chessboard, shaded analytically as :func:`~ccs_kornia.data.render.renderer.render_chessboard`
  shades it (each pixel's footprint box-filtered in closed form, sub-cells only on pixels that straddle an edge), so
  its corners are exact;
* :class:`TexturePattern`: any board that prints itself (``texture()`` gives the print and the map from object points
  to its pixels, ``object_points()`` its corners: the ChArUco boards and AprilGrids of
  :mod:`ccs_kornia.modules.detection.boards`); the print is sampled ``supersample x supersample`` times per pixel from
  the level of a mip-map pyramid whose texels are about that sub-cell's size (bilinear).

Grey levels are linear light in ``[0, 1]``; the board's back (a camera that sees it from behind) is plain.

Example:
    >>> import torch
    >>> p = ChessPattern(4, 3, 0.03)
    >>> p.object_points().shape, p.board_size, p.outline().shape
    (torch.Size([12, 3]), (4, 3), torch.Size([64, 2]))
    >>> X, Y = torch.tensor([[[0.015, 0.015]]]), torch.tensor([[[-0.015, 0.015]]])  # a light and a dark square
    >>> J = (torch.full_like(X, 1e-3), torch.zeros_like(X), torch.zeros_like(X), torch.full_like(X, 1e-3))
    >>> p.shade(X, Y, J, torch.ones_like(X, dtype=torch.bool), torch.tensor(0.5), supersample=1).round(decimals=3)
    tensor([[[0.9000, 0.1000]]])
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ccs_kornia.data.render.renderer import shade_footprints
from ccs_kornia.geometry.board_points import board_object_points

__all__ = ["BoardPattern", "ChessPattern", "TexturePattern"]

#: grey level of a board's back, relative to its light level
_BACK = 0.8


def _rectangle(x0: float, y0: float, x1: float, y1: float, per_side: int = 16) -> Tensor:
    """Points along the sides of a rectangle, ``(4 * per_side, 2)`` float64."""
    t = torch.arange(per_side, dtype=torch.float64) / per_side
    sides = [
        torch.stack([x0 + (x1 - x0) * t, torch.full_like(t, y0)], -1),
        torch.stack([torch.full_like(t, x1), y0 + (y1 - y0) * t], -1),
        torch.stack([x1 - (x1 - x0) * t, torch.full_like(t, y1)], -1),
        torch.stack([torch.full_like(t, x0), y1 - (y1 - y0) * t], -1),
    ]
    return torch.cat(sides, 0)


def _levels(dark: float, light: float, front: Tensor | None, b: int) -> tuple[Tensor, Tensor]:
    """``(b, 1, 1)`` grey levels of the ink and the paper of each item: the print where the camera sees its front,
    one plain grey where it sees the back."""
    lo, hi = torch.full((b, 1, 1), float(dark)), torch.full((b, 1, 1), float(light))
    if front is not None:
        back = ~front.reshape(b, 1, 1).cpu()
        lo, hi = torch.where(back, hi * _BACK, lo), torch.where(back, hi * _BACK, hi)
    return lo, hi


class BoardPattern:
    """A printed board: its corners and its grey levels (see the module docstring)."""

    dark: float
    light: float

    @property
    def board_size(self) -> tuple[int, int]:
        """``(cols, rows)`` of the corner grid (corner ``n = row * cols + col``)."""
        raise NotImplementedError

    def object_points(self) -> Tensor:
        """:math:`(N, 3)` float64 corners on the board's plane ``z = 0``."""
        raise NotImplementedError

    def outline(self) -> Tensor:
        """:math:`(P, 2)` float64 points along the edge of the printed area (where the image can change)."""
        raise NotImplementedError

    def shade(self, X: Tensor, Y: Tensor, jacobian: tuple[Tensor, Tensor, Tensor, Tensor], valid: Tensor,
              background: Tensor, supersample: int = 2, front: Tensor | None = None) -> Tensor:
        """Grey levels of pixels that see the board's plane.

        Args:
            X, Y: :math:`(B, H, W)` board-plane coordinates of the pixel centres.
            jacobian: ``(dX/dx, dX/dy, dY/dx, dY/dy)``, each :math:`(B, H, W)`.
            valid: :math:`(B, H, W)` pixels that see the plane (others show the background).
            background: grey levels behind the board, a number, :math:`(1, H, W)` or :math:`(B, H, W)`.
            supersample: sub-cells (or samples) per pixel side.
            front: optional :math:`(B,)` bool, the camera sees the printed side (else the board's plain back).

        Returns:
            :math:`(B, H, W)` float32.
        """
        raise NotImplementedError

    def to_json(self) -> dict:
        """The pattern as JSON."""
        raise NotImplementedError

    @property
    def side(self) -> float:
        """Which side of the board the print is on: ``1`` where a camera at the board's pose ``R = I`` (the board's
        ``z`` axis along the camera's) sees it, ``-1`` for the other side (an AprilGrid: its ``y`` axis points up on
        the print)."""
        return 1.0

    @property
    def upright(self) -> Tensor:
        """:math:`(3, 3)` the board's orientation in which a camera looking along its ``z`` axis sees the print
        upright: the identity, or half a turn about ``x`` when the print is on the other side."""
        return torch.diag(torch.tensor([1.0, self.side, self.side], dtype=torch.float64))

    def facing(self, R: Tensor, t: Tensor) -> Tensor:
        """Whether cameras see the printed side of boards at poses ``R`` :math:`(..., 3, 3)`, ``t`` :math:`(..., 3)`
        (board to camera)."""
        return self.side * (R[..., :, 2] * t).sum(-1) > 0

    @property
    def size(self) -> float:
        """The printed area's largest side (world units)."""
        o = self.outline()
        return float((o.amax(0) - o.amin(0)).max())

    @property
    def centre(self) -> Tensor:
        """:math:`(3,)` the middle of the corners."""
        return self.object_points().mean(0)


class ChessPattern(BoardPattern):
    """A chessboard of ``cols x rows`` inner corners, squares of side ``square``, with a light border of ``border``
    squares; the top-left square is dark (the layout of :func:`~ccs_kornia.data.render.renderer.render_chessboard`).

    Args:
        cols, rows: inner corners.
        square: side of a square (world units).
        border: light margin around the squares, in squares.
        dark, light: grey levels of the ink and the paper.
    """

    def __init__(self, cols: int, rows: int, square: float, border: float = 1.0, dark: float = 0.1,
                 light: float = 0.9) -> None:
        if int(cols) < 2 or int(rows) < 2 or not square > 0 or border < 0 or not 0 <= dark < light <= 1:
            raise ValueError(f"a chessboard needs cols, rows >= 2, a positive square, border >= 0 and "
                             f"0 <= dark < light <= 1; got {cols}, {rows}, {square}, {border}, {dark}, {light}.")
        self.cols, self.rows, self.square, self.border = int(cols), int(rows), float(square), float(border)
        self.dark, self.light = float(dark), float(light)

    @property
    def board_size(self) -> tuple[int, int]:
        return self.cols, self.rows

    def object_points(self) -> Tensor:
        return board_object_points(self.cols, self.rows, self.square, dtype=torch.float64)

    def outline(self) -> Tensor:
        lo = (-1.0 - self.border) * self.square
        return _rectangle(lo, lo, (self.cols + self.border) * self.square, (self.rows + self.border) * self.square)

    def shade(self, X, Y, jacobian, valid, background, supersample=2, front=None) -> Tensor:
        b = X.shape[0]
        inv = 1.0 / self.square
        u, v = X * inv, Y * inv
        ux, uy, vx, vy = (j * inv for j in jacobian)
        lo, hi = _levels(self.dark, self.light, front, b)
        light, contrast = hi.to(u), (0.5 * (hi - lo)).to(u)
        bg = torch.as_tensor(background, dtype=u.dtype, device=u.device)
        if bg.dim() < 3:
            bg = bg.reshape(1, 1, 1).expand(b, 1, 1)
        cols = torch.full((b, 1, 1), float(self.cols))
        rows = torch.full((b, 1, 1), float(self.rows))
        return shade_footprints(u, v, ux, uy, vx, vy, valid, cols.to(u), rows.to(u), self.border, bg, light,
                                 contrast, supersample)

    def to_json(self) -> dict:
        return {"kind": "chessboard", "cols": self.cols, "rows": self.rows, "square": self.square,
                "border": self.border, "dark": self.dark, "light": self.light}


class TexturePattern(BoardPattern):
    """A board that prints itself (a ChArUco board, an AprilGrid: anything with ``texture()``, ``object_points()``
    and ``board_size``), sampled from a mip-map of its print.

    Args:
        board: the board.
        dark, light: grey levels of its ink and paper.
        inverted: printed white on black.
    """

    def __init__(self, board, dark: float = 0.1, light: float = 0.9, inverted: bool = False) -> None:
        if not 0 <= dark < light <= 1:
            raise ValueError(f"need 0 <= dark < light <= 1, got {dark}, {light}.")
        self.board, self.dark, self.light, self.inverted = board, float(dark), float(light), bool(inverted)
        art, a = board.texture()
        tex = torch.as_tensor(art, dtype=torch.float32) / 255.0
        if self.inverted:
            tex = 1.0 - tex
        self.A = torch.as_tensor(a, dtype=torch.float64)
        # premultiplied (ink level, coverage) pyramid: level k + 1 averages 2 x 2 texels of level k (zero-padded)
        level = torch.stack([tex, torch.ones_like(tex)])[None]
        self.levels = [level]
        while min(level.shape[-2:]) > 4:
            ph, pw = level.shape[-2] % 2, level.shape[-1] % 2
            level = F.avg_pool2d(F.pad(level, (0, pw, 0, ph)), 2)
            self.levels.append(level)

    @property
    def board_size(self) -> tuple[int, int]:
        return tuple(int(v) for v in self.board.board_size)

    def object_points(self) -> Tensor:
        return self.board.object_points().to(torch.float64)

    @property
    def side(self) -> float:
        return 1.0 if float(torch.linalg.det(self.A[:, :2])) > 0 else -1.0

    def outline(self) -> Tensor:
        h, w = self.levels[0].shape[-2:]
        lin = self.A[:, :2]
        corners = torch.tensor([[-0.5, -0.5], [w - 0.5, h - 0.5]], dtype=torch.float64)
        xy = torch.linalg.solve(lin, (corners - self.A[:, 2]).T).T
        lo, hi = xy.amin(0), xy.amax(0)
        return _rectangle(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    def shade(self, X, Y, jacobian, valid, background, supersample=2, front=None) -> Tensor:
        b, h, w = X.shape
        a = self.A.to(torch.float32)
        tx = a[0, 0] * X + a[0, 1] * Y + a[0, 2]
        ty = a[1, 0] * X + a[1, 1] * Y + a[1, 2]
        xx, xy, yx, yy = jacobian
        tx_x, tx_y = a[0, 0] * xx + a[0, 1] * yx, a[0, 0] * xy + a[0, 1] * yy
        ty_x, ty_y = a[1, 0] * xx + a[1, 1] * yx, a[1, 0] * xy + a[1, 1] * yy
        s = max(1, int(supersample))
        # one pyramid level for the batch: texels about a sub-cell wide where the board looks smallest (the finest
        # footprints in the 10th percentile), so nothing aliases and little blurs
        foot = torch.maximum(tx_x.square() + ty_x.square(), tx_y.square() + ty_y.square()).sqrt()[valid]
        lvl = 0
        if foot.numel():
            q = float(torch.quantile(foot[:: max(1, foot.numel() // 100000)], 0.1)) / s
            lvl = min(len(self.levels) - 1, max(0, int(math.floor(math.log2(max(q, 1e-6))))))
        tex = self.levels[lvl]
        th, tw = tex.shape[-2:]
        scale = 2.0 ** lvl
        far = torch.full_like(tx, -1e6)
        tx, ty = torch.where(valid, tx, far), torch.where(valid, ty, far)
        offsets = [(k + 0.5) / s - 0.5 for k in range(s)]
        grids = []
        for oy in offsets:
            for ox in offsets:
                gx = ((tx + tx_x * ox + tx_y * oy + 0.5) / scale - 0.5) * (2.0 / max(tw - 1, 1)) - 1.0
                gy = ((ty + ty_x * ox + ty_y * oy + 0.5) / scale - 0.5) * (2.0 / max(th - 1, 1)) - 1.0
                grids.append(torch.stack([gx, gy], -1).reshape(1, -1, 1, 2))
        grid = torch.cat(grids, 1).clamp(-4.0, 4.0)
        sampled = F.grid_sample(tex, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
        ink, cover = sampled[0, :, :, 0].view(2, s * s, b, h, w).mean(1)
        lo, hi = (t.to(X) for t in _levels(self.dark, self.light, front, b))
        board = lo * cover + (hi - lo) * ink
        bg = torch.as_tensor(background, dtype=X.dtype)
        return board + (1.0 - cover) * bg

    def to_json(self) -> dict:
        board = dataclasses.asdict(self.board) if dataclasses.is_dataclass(self.board) else {}
        return {"kind": type(self.board).__name__, "board": board, "dark": self.dark, "light": self.light,
                "inverted": self.inverted}
