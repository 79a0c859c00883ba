"""Prediction of the grid cells the detector missed, from their row and column neighbours."""

from __future__ import annotations

import torch

from ccs_kornia.runtime.checks import check_board_size, check_points, check_tensor

__all__ = ["lattice_deviation", "predict_missing_corners", "unconfirmed_corners"]


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
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> pts = board_object_points(4, 3)[None, :, :2] * 10
        >>> valid = torch.ones(1, 12, dtype=torch.bool); valid[0, 0] = False
        >>> out, filled = predict_missing_corners(pts * valid[..., None], valid, (4, 3))
        >>> bool(filled.all()), torch.allclose(out, pts)
        (True, True)
    """
    cols, rows = check_board_size(board_size)
    check_points(corners, "corners", N=cols * rows)
    check_tensor(valid, "valid", corners.shape[:2])
    b = corners.shape[0]
    g = corners.reshape(b, rows, cols, 2).clone()
    v = valid.reshape(b, rows, cols).clone()
    for _ in range(passes):
        if bool(v.all()):
            break
        estimate, count = _neighbour_estimate(g, v)
        fill = ~v & (count > 0)
        g = torch.where(fill[..., None], estimate, g)
        v = v | fill
    return g.reshape(b, -1, 2), v.reshape(b, -1)


def lattice_deviation(corners: torch.Tensor, board_size: tuple[int, int], return_estimate: bool = False
                      ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""How far each corner of complete boards lies from where its row and column neighbours put it, in squares.

    The prediction is :func:`predict_missing_corners`' estimate of the cell from its neighbours (the corner itself
    left out), the distance is divided by the board's median distance between neighbouring corners. A board's corners
    follow a smooth lattice (perspective, lens distortion), so a corner that converged onto a different junction
    (e.g. a corner of a ChArUco mark) stands out.

    Args:
        corners: :math:`(B, N, 2)` grid-ordered corners of found boards, ``N = cols * rows``; NaN for the hidden
            corners of partial boards (they predict nothing and get deviation 0).
        board_size: ``(cols, rows)``.
        return_estimate: also return the positions :math:`(B, N, 2)` the neighbours predict.

    Returns:
        :math:`(B, N)` deviations in squares (and the predicted positions).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> pts = board_object_points(5, 4)[None, :, :2] * 10
        >>> pts[0, 7] += torch.tensor([3.0, 0.0])  # one corner 0.3 squares off
        >>> dev = lattice_deviation(pts, (5, 4))
        >>> int(dev.argmax()), round(float(dev.max()), 2)
        (7, 0.3)
    """
    cols, rows = check_board_size(board_size)
    check_points(corners, "corners", N=cols * rows)
    b = corners.shape[0]
    g = corners.reshape(b, rows, cols, 2)
    v = g.isfinite().all(-1)  # hidden corners of partial boards (NaN) are no neighbours
    g = torch.where(v[..., None], g, torch.zeros_like(g))
    estimate, count = _neighbour_estimate(g, v)
    from ccs_kornia.modules.detection.grid.grid_geometry import grid_spacing

    # the board's median square: a displaced corner must not shrink its own yardstick
    spacing = grid_spacing(corners, v.reshape(b, -1), board_size).median(-1).values[:, None, None]
    dev = (g - estimate).norm(dim=-1) / spacing.clamp_min(1e-6)
    dev = torch.where((count > 0) & v, dev, torch.zeros_like(dev)).reshape(b, -1)
    if return_estimate:
        return dev, torch.where((count > 0)[..., None], estimate, corners.reshape(b, rows, cols, 2)).reshape(b, -1, 2)
    return dev


def unconfirmed_corners(valid: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    r"""The measured corners that their row and column neighbours cannot predict, :math:`(B, N)`.

    A corner is confirmed by the lattice of its measured neighbours: two in a row or column on one side of it, or one
    on each side (:func:`lattice_deviation`'s prediction). Where there is neither, nothing on the board confirms that
    the corner is the one its id names (:func:`lattice_deviation` gives it 0): on a board foreshortened to squares a
    few px tall, a corner whose row and column neighbours were lost had its saddle fit converge onto the next row's
    corner. A disputed corner is dropped, never guessed.

    Args:
        valid: :math:`(B, N)` bool, the measured corners, ``N = cols * rows`` in grid order.
        board_size: ``(cols, rows)``.

    Returns:
        :math:`(B, N)` bool.

    Example:
        >>> valid = torch.tensor([[True, False, True, True,
        ...                        False, True, True, True,
        ...                        True, True, True, True]])
        >>> unconfirmed_corners(valid, (4, 3)).nonzero()[:, 1].tolist()  # corner 0: its right and lower neighbours lost
        [0]
    """
    cols, rows = check_board_size(board_size, min_side=1)
    check_tensor(valid, "valid", ["B", str(cols * rows)])
    v = valid.reshape(-1, rows, cols)
    _, count = _neighbour_estimate(torch.zeros(*v.shape, 2, device=valid.device), v)
    return valid & (count.reshape(valid.shape) == 0)


def _shifted(x: torch.Tensor, k: int, dim: int) -> torch.Tensor:
    """Value of the cell ``k`` steps further along ``dim`` (zero / False beyond the board)."""
    out = torch.zeros_like(x)
    n = x.shape[dim]
    if abs(k) >= n:
        return out
    src = x.narrow(dim, max(k, 0), n - abs(k))
    out.narrow(dim, max(-k, 0), n - abs(k)).copy_(src)
    return out


def _neighbour_estimate(g: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Every cell's position from its valid row and column neighbours (the cell itself not used), ``(B, rows, cols,
    2)``, and the weight of the estimates behind it ``(B, rows, cols)`` (0: none)."""
    total = torch.zeros_like(g)
    count = torch.zeros(g.shape[:-1], dtype=g.dtype, device=g.device)
    for dim in (1, 2):  # rows (along j) and columns (along i)
        for sgn in (1, -1):
            p1, v1 = _shifted(g, sgn, dim), _shifted(v, sgn, dim)
            p2, v2 = _shifted(g, 2 * sgn, dim), _shifted(v, 2 * sgn, dim)
            p3, v3 = _shifted(g, 3 * sgn, dim), _shifted(v, 3 * sgn, dim)
            quad = v1 & v2 & v3
            lin = v1 & v2 & ~v3
            est = torch.where(quad[..., None], 3 * p1 - 3 * p2 + p3, 2 * p1 - p2)
            use = quad | lin
            total = total + est * use[..., None]
            count = count + use
        pa, va = _shifted(g, 1, dim), _shifted(v, 1, dim)
        pb, vb = _shifted(g, -1, dim), _shifted(v, -1, dim)
        mid = va & vb
        # the midpoint is the most reliable estimate: count it twice
        total = total + (pa + pb) * mid[..., None]
        count = count + 2 * mid
    return total / count.clamp_min(1)[..., None], count
