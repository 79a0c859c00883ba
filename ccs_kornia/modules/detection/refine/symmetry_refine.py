"""Point-symmetry polish of chessboard corners: the last, most precise step of the saddle refinement.

Around a chessboard corner the image is point-symmetric: opposite quadrants have the same colour, and an affine
view (perspective, locally) keeps that symmetry, whatever the angle between the edges. So the corner is the point
``c`` that minimises ``sum_d w(d) (I(c + d) - I(c - d))^2`` over a window of offsets ``d``, a 2-parameter
Gauss-Newton problem per corner whose Jacobian is ``grad I(c + d) - grad I(c - d)``.

Unlike a quadratic surface fit, this model is exact for any edge profile: it needs no heavy smoothing to make the
junction look quadratic, and no division by a local mean (which bends the geometry wherever the mean's window sees
the next square or the background), so it uses every pixel of a wider window at full precision: on held-out wild
renders it lowers the mean corner error of the saddle fit alone in every condition (``docs/measurements.md``).

It works on the regions that :mod:`~ccs_kornia.modules.detection.refine.saddle_refine` already gathers and smooths per
corner, so it adds three window samples per iteration and nothing per image.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from ccs_kornia.modules.detection.grid.grid_geometry import line_sagitta

__all__ = ["WIDE_MARGIN", "WIDE_MAX_MOVE", "WIDE_MAX_SAGITTA", "WIDE_WINDOW", "symmetry_polish", "symmetry_terms", "wide_allowed",
           "wide_polish", "wide_vote"]

#: the wide polish's window radius, in saddle-fit windows (0.4 x the grid spacing with the default 0.2)
WIDE_WINDOW = 2.0
#: farthest the wide polish may move a corner (px): further, it has found another optimum, not a better estimate
WIDE_MAX_MOVE = 0.5

#: a board keeps the wide polish where at least half of its corners are left at most this many times as asymmetric
#: as by the usual polish
WIDE_MARGIN = 1.15
#: the wide polish only where the board's rows and columns bend by at most this much (px; the sagitta of
#: :func:`~ccs_kornia.modules.detection.grid.grid_geometry.line_sagitta`): on severely distorted renders it gains below
#: 0.05 px, is neutral up to 0.1 and loses beyond (``docs/measurements.md``)
WIDE_MAX_SAGITTA = 0.05
#: Gauss-Newton steps of the wide polish (it starts from the usual polish's point)
WIDE_ITERATIONS = 2


def symmetry_polish(
    src: torch.Tensor,
    corners: torch.Tensor,
    radius: torch.Tensor,
    rmax: int,
    sample_window: Callable[[torch.Tensor, torch.Tensor, int], torch.Tensor],
    weights: torch.Tensor,
    iterations: int = 8,
    max_step: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Move each corner to the centre of point symmetry of its region, by Gauss-Newton.

    Args:
        src: :math:`(M, 1, q, q)` smoothed image regions, one per corner.
        corners: :math:`(M, 2)` starting points in region coordinates (px, x then y).
        radius: :math:`(M,)` window radius per corner (px); only used to bound the total move.
        rmax: half-size of the square window of offsets (``(2 rmax + 1)^2`` samples, point-symmetric order).
        sample_window: ``(src, centres (M, 2), rmax) -> (M, P)`` bilinear samples at ``centre + offset``, offsets
            in row-major order, so reversing the last axis samples ``centre - offset``.
        weights: :math:`(M, P)` window weights (zero outside each corner's radius).
        iterations: Gauss-Newton steps.
        max_step: largest move per step (px): the symmetry residual is only linear within about a blur width.

    Returns:
        ``(corners (M, 2), ok (M,), asymmetry (M,))``: the polished points; whether the normal matrix was well
        posed and the point stayed within ``radius`` of its start (elsewhere the input point is returned); and the
        asymmetry left, ``sum w (I(c+d) - I(c-d))^2 / sum 4 w (I(c+d) - mean)^2`` (0 for a perfect corner, about
        1 where the window shows no point symmetry), which lets a caller compare sources.

    Example:
        >>> from ccs_kornia.modules.detection.refine.saddle_refine import sample_window, weighted_window
        >>> img = torch.zeros(1, 1, 41, 41); img[..., :20, :20] = 1; img[..., 20:, 20:] = 1
        >>> r = torch.tensor([6.0]); w = weighted_window(r, 6)[1]
        >>> symmetry_polish(img, torch.tensor([[20.2, 19.1]]), r, 6, sample_window, w)[0].round(decimals=2)
        tensor([[19.5000, 19.5000]])
    """
    m, side = corners.shape[0], 2 * rmax + 1
    # the normal equations over the first half of the window (symmetry_terms) are exactly half those over all of it
    w_half = weights[:, None, : side * side // 2]

    c0 = corners
    c = corners.clone()
    ok = torch.ones(m, dtype=torch.bool, device=c.device)
    for _ in range(iterations):
        odd = symmetry_terms(src, c, rmax, sample_window)
        # [[axx, axy, gx], [axy, ayy, gy]] of the doubled Jacobian in one batched product
        normal = torch.bmm(odd[:, :2] * w_half, odd.transpose(1, 2))
        axx, axy, ayy, gx_, gy_ = normal[:, 0, 0], normal[:, 0, 1], normal[:, 1, 1], normal[:, 0, 2], normal[:, 1, 2]
        det = axx * ayy - axy * axy
        good = det > 1e-12 * (axx + ayy).square().clamp_min(1e-30)
        det = torch.where(good, det, torch.ones_like(det))
        # the doubled Jacobian scales the normal matrix by 4 and the gradient by 2: the step is twice this solve
        step = -2.0 * torch.stack([(ayy * gx_ - axy * gy_) / det, (axx * gy_ - axy * gx_) / det], -1)
        norm = step.norm(dim=-1, keepdim=True)
        step = step * (max_step / norm.clamp_min(max_step))
        step = torch.where((good & torch.isfinite(step).all(-1))[:, None], step, torch.zeros_like(step))
        ok = ok & good
        c = c + step
    ok = ok & torch.isfinite(c).all(-1) & ((c - c0).norm(dim=-1) <= radius)
    # asymmetry left at the end: the residual's share of the window's contrast energy
    f = sample_window(src, c, rmax)
    mean = (weights * f).sum(-1, keepdim=True) / weights.sum(-1, keepdim=True).clamp_min(1e-12)
    asym = (weights * (f - f.flip(-1)).square()).sum(-1) / (4 * weights * (f - mean).square()).sum(-1).clamp_min(1e-12)
    return torch.where(ok[:, None], c, c0), ok, asym


def symmetry_terms(
    src: torch.Tensor,
    centre: torch.Tensor,
    rmax: int,
    sample_window: Callable[[torch.Tensor, torch.Tensor, int], torch.Tensor],
) -> torch.Tensor:
    r"""The point-symmetry residual ``r(d) = I(c + d) - I(c - d)`` and twice its Jacobian ``grad I(c + d) - grad I(c - d)``
    over the first half of the window, :math:`(M, 3, P_{half})` (rows: twice ``J_x``, twice ``J_y``, ``r``).

    Offsets ``d`` and ``-d`` sit at ``k`` and ``P - 1 - k`` of the row-major window: the residual and the Jacobian
    are odd in ``d``, so the first half holds every term once (the centre contributes zero) and, with even weights,
    sums over it are exactly half those over the whole window. Values and gradient come from a single gather: one
    window a pixel wider, whose central differences are the gradient's bilinear samples (shift and difference commute).

    Args:
        src: :math:`(M, 1, q, q)` regions; centre: :math:`(M, 2)` points in region coordinates; rmax: window half-size;
        sample_window: as for :func:`symmetry_polish`.

    Example:
        >>> from ccs_kornia.modules.detection.refine.saddle_refine import sample_window
        >>> img = torch.zeros(1, 1, 41, 41); img[..., :20, :20] = 1; img[..., 20:, 20:] = 1
        >>> symmetry_terms(img, torch.tensor([[19.5, 19.5]]), 6, sample_window)[:, 2].abs().max().item()
        0.0
    """
    m, side = centre.shape[0], 2 * rmax + 1
    half = side * side // 2
    big = sample_window(src, centre, rmax + 1).reshape(m, side + 2, side + 2)
    # the three rows written in place (a stack of them would copy them once more)
    parts = big.new_empty(m, 3, side, side)
    torch.sub(big[:, 1:-1, 2:], big[:, 1:-1, :-2], out=parts[:, 0])
    torch.sub(big[:, 2:, 1:-1], big[:, :-2, 1:-1], out=parts[:, 1])
    parts[:, 2] = big[:, 1:-1, 1:-1]
    parts = parts.reshape(m, 3, -1)
    return parts[..., :half] - parts[..., half + 1:].flip(-1)


def wide_polish(
    src: torch.Tensor,
    polished: torch.Tensor,
    ok: torch.Tensor,
    asymmetry: torch.Tensor,
    reach: torch.Tensor,
    rmax: int,
    sample_window: Callable[[torch.Tensor, torch.Tensor, int], torch.Tensor],
    weights: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The polished points again, in a wider window: :math:`(M, 2)` points, and :math:`(M,)` where the wider window
    sees the corner as point-symmetric as the usual one did (the per-board vote of :func:`wide_vote`).

    A wider window averages more pixels: on held-out wild renders (window 0.4 instead of 0.3 x the grid spacing) the
    mean corner error drops under noise, blur, JPEG and tilt. It also reaches what breaks the symmetry: marks inside
    the white squares and the curvature of distorted lines. Marks raise the asymmetry it leaves, relative to the usual
    window's, hence the vote: a board keeps the wide result only where at least half of its corners have a ratio of at
    most :data:`WIDE_MARGIN`. Curvature does not, and the wide window loses on strongly bent lines, hence the
    straightness gate of :func:`wide_allowed` (:data:`WIDE_MAX_SAGITTA`). Figures: ``docs/measurements.md``.

    Args:
        src: :math:`(M, 1, q, q)` regions (each corner's chosen source); polished: :math:`(M, 2)` points of the usual
            polish in region coordinates; ok: :math:`(M,)` where that polish succeeded; asymmetry: :math:`(M,)` the
            asymmetry it left; reach: :math:`(M,)` largest move; rmax: half-size of the wide window; sample_window,
            weights: as for :func:`symmetry_polish`.

    Example:
        >>> from ccs_kornia.modules.detection.refine.saddle_refine import sample_window, weighted_window
        >>> img = torch.zeros(1, 1, 41, 41); img[..., :20, :20] = 1; img[..., 20:, 20:] = 1
        >>> r = torch.tensor([9.0])
        >>> p, agree = wide_polish(img, torch.tensor([[19.6, 19.4]]), torch.tensor([True]), torch.tensor([0.01]),
        ...                        r.clamp_max(0.5), 9, sample_window, weighted_window(r, 9)[1])
        >>> p.round(decimals=1), agree  # the corner is at (19.5, 19.5)
        (tensor([[19.5000, 19.5000]]), tensor([True]))
    """
    wide, moved, asym_wide = symmetry_polish(src, polished, reach, rmax, sample_window, weights, WIDE_ITERATIONS)
    return torch.where((ok & moved)[:, None], wide, polished), ok & moved & (asym_wide <= WIDE_MARGIN * asymmetry)


def wide_vote(agree: torch.Tensor, tried: torch.Tensor) -> torch.Tensor:
    r"""The corners that keep the wide polish, :math:`(B, N)` bool: those ``tried`` on boards where at least half of
    the tried corners ``agree`` (:func:`wide_polish`).

    Example:
        >>> tried = torch.tensor([[True, True, True, False], [True, True, False, False]])
        >>> wide_vote(torch.tensor([[True, True, False, False], [False, True, False, False]]), tried)
        tensor([[ True,  True,  True, False],
                [ True,  True, False, False]])
    """
    votes, total = (agree & tried).sum(-1, keepdim=True), tried.sum(-1, keepdim=True)
    return tried & (2 * votes >= total)


def wide_allowed(corners: torch.Tensor, valid: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    """The corners of organised boards that may take the wide polish, :math:`(B, N)` bool: where the board's row and
    column bend by at most :data:`WIDE_MAX_SAGITTA`
    (:func:`~ccs_kornia.modules.detection.grid.grid_geometry.line_sagitta`, on the ``valid`` corners). Measured from the
    usual polish's corners: from the detector's coarser ones the noise alone makes many corners of a strongly noisy
    straight board look bent (``docs/measurements.md``)."""
    if min(board_size) < 2 or corners.shape[1] != board_size[0] * board_size[1]:  # one row or column: bend unknown
        return torch.zeros_like(valid)
    return line_sagitta(corners, valid, board_size) <= WIDE_MAX_SAGITTA
