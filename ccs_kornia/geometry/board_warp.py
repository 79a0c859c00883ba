r"""A board that is not flat: mrcal's two-parameter sag of the calibration board.

A large board bends (temperature, humidity, its own weight). mrcal models the bend as two axis-aligned parabolas: with
the board's points normalised to :math:`u, v \in [-1, 1]` along its x and y axes (its extent in the board's
frame), a point moves along the board's z axis by

.. math::
    \Delta z = c_x (1 - u^2) + c_y (1 - v^2),

zero at the edges and :math:`c_x + c_y` at the centre (metres, the board's units). ``c = (c_x, c_y)`` is exactly
mrcal's ``calobject_warp``, so the two compare number for number. The camera and rig fits estimate ``c``
jointly with everything else on the one LM core (:func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt` and the rig's, with
``board_warp``), with its 1-sigma from the same covariance.
"""

from __future__ import annotations

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["board_warp_basis", "warped_board"]


def board_warp_basis(object_points: torch.Tensor) -> torch.Tensor:
    r"""The sag's two shapes at the board's points: ``(1 - u^2, 1 - v^2)``, :math:`u, v` the points' x and y mapped
    from the board's extent onto :math:`[-1, 1]` (for a chessboard, ``u = 2 i / (cols - 1) - 1``: mrcal's grid).

    Args:
        object_points: :math:`(..., N, 3)` the flat board's points.

    Returns:
        :math:`(..., N, 2)` of the points' dtype.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> b = board_warp_basis(board_object_points(3, 3, 0.1, dtype=torch.float64))
        >>> b[:, 0].tolist(), b[:, 1].tolist()
        ([0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    """
    check_tensor(object_points, "object_points", ["*", "N", "3"])
    xy = object_points[..., :2]
    lo, hi = xy.amin(-2, keepdim=True), xy.amax(-2, keepdim=True)
    uv = 2 * (xy - lo) / (hi - lo).clamp_min(torch.finfo(xy.dtype).tiny) - 1
    return 1 - uv * uv


def warped_board(object_points: torch.Tensor, warp: torch.Tensor | None) -> torch.Tensor:
    r"""The board's points bent by ``warp`` (``None``: the flat board itself).

    Args:
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)` the flat board.
        warp: :math:`(C, 2)` or :math:`(2,)` mrcal's ``calobject_warp`` (:math:`c_x, c_y`, the board's units).

    Returns:
        :math:`(C, N, 3)` (or :math:`(N, 3)` for a flat ``warp`` of shape (2,) with an (N, 3) board).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> obj = board_object_points(3, 3, 0.1, dtype=torch.float64)
        >>> warped_board(obj, torch.tensor([-0.001, 0.0005], dtype=torch.float64))[4].tolist()
        [0.1, 0.1, -0.0005]
    """
    if warp is None:
        return object_points
    warp = warp.to(object_points)
    if warp.dim() > 1 and object_points.dim() == 2:
        object_points = object_points.expand(warp.shape[0], *object_points.shape)
    dz = (board_warp_basis(object_points) * warp[..., None, :]).sum(-1)
    return torch.cat([object_points[..., :2], object_points[..., 2:] + dz[..., None]], -1)
