"""Which part of the image the boards of a calibration cover, batched over cameras.

Where no board was, the distortion model is extrapolated: the degeneracy checks flag a small covered
fraction, and the diagnostics separate the projection uncertainty where the boards were from the rest.
"""

from __future__ import annotations

import functools
import math

import torch

from ccs_kornia.modules.calibration.homography import find_homographies

__all__ = ["covered_pixels", "image_coverage"]


def covered_pixels(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    used: torch.Tensor,
    pixels: torch.Tensor,
    homographies: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""Which pixels lie inside the board of some used view.

    A pixel is covered when, mapped onto the board plane by the view's homography, it falls inside the extent
    of the view's valid object points (the homography ignores lens distortion, which is fine for coverage).

    Args:
        corners: :math:`(C, V, N, 2)` px.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` planar board points.
        used: :math:`(C, V)` bool.
        pixels: :math:`(G, 2)` px.
        homographies: :math:`(C, V, 3, 3)` board-to-image homographies of these views when already computed
            (e.g. by the solver; NaN where none), else they are fitted here.

    Returns:
        :math:`(C, G)` bool.

    Example:
        >>> obj = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
        >>> uv = torch.tensor([[[[10., 10], [50, 10], [10, 50], [50, 50]]]])
        >>> covered_pixels(uv, torch.ones(1, 1, 4, dtype=torch.bool), obj, torch.ones(1, 1, dtype=torch.bool),
        ...                torch.tensor([[30., 30], [70, 30]])).tolist()
        [[True, False]]
    """
    C, V, N = valid.shape
    dtype = torch.float64
    obj = object_points.to(device=corners.device, dtype=dtype)
    obj = obj.expand(C, N, 3) if obj.dim() == 2 else obj
    ok_view = used.bool() & (valid.sum(-1) >= 4)
    if homographies is None:
        H, ok = find_homographies(obj[:, None, :, :2], corners.to(dtype), valid & ok_view[..., None], return_ok=True)
    else:
        H = homographies.to(device=corners.device, dtype=dtype)
        ok = H.flatten(-2).isfinite().all(-1)
    ok_view = ok_view & ok
    px = pixels.to(device=corners.device, dtype=dtype)
    cells = torch.cat([px, torch.ones_like(px[:, :1])], -1)  # (G, 3)
    Hinv = torch.linalg.inv(torch.where(ok_view[..., None, None], H, torch.eye(3, dtype=dtype, device=H.device)))
    b = torch.einsum("cvij,gj->cvgi", Hinv, cells)
    bxy = b[..., :2] / b[..., 2:]
    vo = (valid & ok_view[..., None])[..., None]
    big = torch.tensor(float("inf"), dtype=dtype, device=corners.device)
    lo = torch.where(vo, obj[:, None, :, :2], big).amin(2)  # (C, V, 2)
    hi = torch.where(vo, obj[:, None, :, :2], -big).amax(2)
    # b_z = 1 / (h31 X + h32 Y + 1) > 0 on the visible side of the board plane's vanishing line
    inside = ((bxy >= lo[:, :, None]) & (bxy <= hi[:, :, None])).all(-1) & (b[..., 2] > 0) & ok_view[..., None]
    return inside.any(1)


def image_coverage(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    used: torch.Tensor,
    image_size: tuple[int, int],
    grid: tuple[int, int] = (32, 24),
    homographies: torch.Tensor | None = None,
) -> torch.Tensor:
    r"""Fraction of the image covered by the union of the boards of the used views.

    The centres of a ``grid`` of cells over the image are tested with :func:`covered_pixels`.

    Args:
        corners: :math:`(C, V, N, 2)` px.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` planar board points.
        used: :math:`(C, V)` bool.
        image_size: ``(W, H)``.
        grid: cells ``(across, down)``.
        homographies: see :func:`covered_pixels`.

    Returns:
        :math:`(C, 2)`: covered fraction of all cells, and of the cells in the outer ring (beyond 60 % of the
        half-diagonal from the centre), where distortion is largest.

    Example:
        >>> obj = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
        >>> uv = torch.tensor([[[[0., 0], [99, 0], [0, 99], [99, 99]]]])  # a board filling a 100x100 image
        >>> image_coverage(uv, torch.ones(1, 1, 4, dtype=torch.bool), obj, torch.ones(1, 1, dtype=torch.bool),
        ...                (100, 100), grid=(10, 10)).tolist()
        [[1.0, 1.0]]
    """
    cells, outer = _grid(int(image_size[0]), int(image_size[1]), int(grid[0]), int(grid[1]))
    covered = covered_pixels(corners, valid, object_points, used, cells, homographies).to(torch.float64)  # (C, G)
    return torch.stack([covered.mean(-1), covered[:, outer.to(covered.device)].mean(-1)], -1)


@functools.lru_cache(maxsize=16)
def _grid(W_: int, H_: int, gx: int, gy: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Cell centres (G, 2) of a ``gx x gy`` grid over a ``W_ x H_`` image and the outer-ring flags (G,)."""
    with torch.inference_mode(False):  # (cached: ordinary tensors, whatever mode the first call ran in)
        xs = (torch.arange(gx, dtype=torch.float64) + 0.5) * W_ / gx - 0.5
        ys = (torch.arange(gy, dtype=torch.float64) + 0.5) * H_ / gy - 0.5
        yy, xx = torch.meshgrid(ys, xs, indexing="ij")
        cells = torch.stack([xx.reshape(-1), yy.reshape(-1)], -1)
        half_diag = math.hypot((W_ - 1) / 2, (H_ - 1) / 2)
        r = ((cells[:, 0] - (W_ - 1) / 2) ** 2 + (cells[:, 1] - (H_ - 1) / 2) ** 2).sqrt() / half_diag
    return cells, r > 0.6
