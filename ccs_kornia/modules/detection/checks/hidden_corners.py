"""Corners of a found board that the image does not show (glare, an occluder): partial boards.

A saturating reflection on a glossy print flattens a few squares to white; the board is still identified by the rest
of its corners (the grid organiser's lattice, its borders and its size), but the corners under the glare cannot be
measured. Rather than drop the whole view, those corners are left out (NaN in the detector's output, so that no
consumer can take a guess for a measurement) and the others are kept.

* :func:`checker_contrast`: the intensity range within a quarter square of each corner of a board in grid order;
* :func:`hidden_corners`: corners where that contrast is a small fraction of the board's own, i.e. the image shows
  no checker there;
* :func:`settle_partial_boards`: on the boards with hidden corners, the full-resolution corners next to the glare
  whose point symmetry is far worse than the board's are left out too (the saddle fit confirms them, yet the glare's
  edge pulls them by pixels), on any board a corner whose symmetry is worse still (it converged onto an edge or into a
  square: a confident wrong corner), and a board left with fewer than :data:`PARTIAL_BOARD_FRACTION` of its corners is
  refused.

A predicted corner whose saddle the refiner cannot confirm *and* whose contrast is still there (at least
:data:`UNCONFIRMED_CONTRAST_FRACTION` of the board's) is not hidden: something else is in the image at that place (a
wrong lattice, a board of another size), and the detector refuses the board as before, unless it lies next to a
hidden corner (:func:`glare_rim`): at the rim of a glare one side of the junction is saturated, the saddle fit fails
and the quarter square still spans most of the board's contrast. A corner outside the image (a board cut by its
border) reads as flat and is hidden too.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ccs_kornia.modules.detection.base import DetectionResult, image_rows
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_uncertainty
from ccs_kornia.runtime.checks import (
    check_board_size,
    check_grey_images,
    check_points,
    check_same_shape,
    check_tensor,
)

__all__ = ["HIDDEN_CONTRAST_FRACTION", "UNCONFIRMED_CONTRAST_FRACTION", "MAX_ASYMMETRY_RATIO", "MAX_ASYMMETRY_RATIO_WHOLE",
           "PARTIAL_BOARD_FRACTION", "checker_contrast", "glare_rim", "hidden_corners", "intensity_range", "relative_contrast",
           "settle_partial_boards", "spans_board"]

#: a corner is hidden where its checker contrast is below this fraction of the median of the board's visible corners
HIDDEN_CONTRAST_FRACTION = 0.25
#: a predicted corner that the saddle refinement cannot confirm is hidden below this fraction (at the rim of a glare
#: the saddles are lost before the contrast has faded below it: ``docs/measurements.md``)
UNCONFIRMED_CONTRAST_FRACTION = 0.6
#: on a partial board, a corner whose point-symmetry residual (:func:`corner_uncertainty`) exceeds this multiple of the
#: board's median is left out (at the rim of a glare, on renders and real photographs with a spot added, corners
#: pixels off exceed it and good ones stay below: ``docs/measurements.md``)
MAX_ASYMMETRY_RATIO = 20.0
#: on any board, a corner whose point-symmetry residual exceeds this multiple of the board's median is left out: it lies
#: on an edge or inside a square, not on a junction; good corners stay below it even at a fisheye's rim, where the
#: lines curve within the window (``docs/measurements.md``)
MAX_ASYMMETRY_RATIO_WHOLE = 30.0
#: a partial board has at least this fraction of its corners: the organiser asks for peaks at this fraction of the
#: cells, and a board left with fewer visible corners after the checks is refused (one fraction for both, so a board the
#: organiser accepts is not refused for its size alone)
PARTIAL_BOARD_FRACTION = 0.4
# the contrast is measured within this many squares of the corner along either grid axis: marks inside the white
# squares (ChArUco, ECoCheck) keep a margin of about a quarter square clear
CONTRAST_RADIUS = 0.25


def _check(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int]) -> tuple[int, int]:
    check_grey_images(images, min_side=0)
    cols, rows = check_board_size(board_size)
    check_points(corners, "corners", B=images.shape[0], N=cols * rows)
    return cols, rows


def checker_contrast(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    r"""Contrast around each corner, :math:`(B, N)` (image units): the intensity range within a quarter square.

    The image is sampled on a 5 x 5 grid spanning a quarter square on either side of the corner along the local grid
    axes (the half differences of the corner's neighbours, one-sided on the board's rim). A visible corner shows the
    full black-white step there, marks inside the white squares (ChArUco, ECoCheck) or not; a corner under saturating
    glare shows about none.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        corners: :math:`(B, N, 2)` complete boards in grid order (``n = j * cols + i``).
        board_size: ``(cols, rows)``.

    Returns:
        :math:`(B, N)` contrast (NaN where a corner or a neighbour is not finite).

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)  # 4 x 3 squares of 32 px: 3 x 2 inner corners
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> img[..., 16:48, 80:112] = 1.0  # glare over the top right-hand corner
        >>> pts = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> checker_contrast(img, pts, (3, 2))[0].tolist()
        [1.0, 1.0, 0.0, 1.0, 1.0, 1.0]
    """
    cols, rows = _check(images, corners, board_size)
    b = corners.shape[0]
    g = corners.double().reshape(b, rows, cols, 2)
    u = torch.gradient(g, dim=2)[0]  # one square along a row
    v = torch.gradient(g, dim=1)[0]  # one square along a column
    steps = torch.linspace(-CONTRAST_RADIUS, CONTRAST_RADIUS, 5, dtype=g.dtype, device=g.device)
    su, sv = torch.meshgrid(steps, steps, indexing="ij")
    offsets = su.reshape(-1, 1, 1, 1, 1) * u + sv.reshape(-1, 1, 1, 1, 1) * v  # (K, B, rows, cols, 2)
    pts = (g + offsets).permute(1, 2, 3, 0, 4).reshape(b, rows * cols, -1, 2)
    contrast = intensity_range(images, pts).to(corners.device, corners.dtype)
    finite = g.isfinite().all(-1) & u.isfinite().all(-1) & v.isfinite().all(-1)
    return torch.where(finite.reshape(b, -1), contrast, torch.full_like(contrast, float("nan")))


def intensity_range(images: torch.Tensor, points: torch.Tensor, outside: str = "border") -> torch.Tensor:
    r"""Intensity range (largest minus smallest bilinear sample) over the ``K`` points of each of ``N`` sets.

    The one contrast measure of the detector: :func:`checker_contrast` at a board's corners, and the organiser's
    contrast at the empty cells of a partial lattice.

    Args:
        images: :math:`(B, 1, H, W)`.
        points: :math:`(B, N, K, 2)` pixel coordinates (pixel centres at integers).
        outside: ``"border"``: a sample off the image reads the nearest border pixel (and a NaN point reads the
            image's corner); ``"nan"``: samples whose bilinear footprint leaves the image are not counted, and a set
            without a sample reads NaN.

    Returns:
        :math:`(B, N)` (float32).

    Example:
        >>> img = torch.zeros(1, 1, 4, 4); img[..., 2:, :] = 1.0  # rows 2 and 3 light
        >>> pts = torch.tensor([[[[1.0, 1.0], [1.0, 2.0]], [[1.0, 1.0], [1.0, 5.0]]]])  # the second set leaves the image
        >>> intensity_range(img, pts).tolist(), intensity_range(img, pts, outside="nan").tolist()
        ([[1.0, 1.0]], [[1.0, 0.0]])
    """
    if outside not in ("border", "nan"):
        raise ValueError(f"outside must be 'border' or 'nan', got {outside!r}.")
    b, n, k = points.shape[:3]
    h, w = images.shape[-2:]
    pts = points.reshape(b, n * k, 2)
    grid = torch.stack([(pts[..., 0] + 0.5) * (2.0 / w) - 1.0, (pts[..., 1] + 0.5) * (2.0 / h) - 1.0], -1)
    vals = F.grid_sample(images.float(), grid[:, None].to(images.device, torch.float32).nan_to_num(-2.0),
                         mode="bilinear", padding_mode="border", align_corners=False)[:, 0, 0]
    vals = vals.reshape(b, n, k)
    if outside == "border":
        return vals.amax(-1) - vals.amin(-1)
    x, y = pts[..., 0].to(vals.device), pts[..., 1].to(vals.device)
    inside = ((x >= 0) & (x < w - 1) & (y >= 0) & (y < h - 1)).reshape(b, n, k)
    top = vals.masked_fill(~inside, float("-inf")).amax(-1)
    low = vals.masked_fill(~inside, float("inf")).amin(-1)
    return torch.where(inside.any(-1), top - low, torch.full_like(top, float("nan")))


def hidden_corners(
    images: torch.Tensor, corners: torch.Tensor, visible: torch.Tensor, board_size: tuple[int, int],
    fraction: float | torch.Tensor = HIDDEN_CONTRAST_FRACTION,
) -> torch.Tensor:
    r"""Corners the image does not show: checker contrast below ``fraction`` of the median over ``visible``.

    Args:
        images: :math:`(B, 1, H, W)` grey images in ``[0, 1]``.
        corners: :math:`(B, N, 2)` complete boards in grid order (missing corners predicted).
        visible: :math:`(B, N)` bool, corners known to be visible (e.g. confirmed by the saddle refinement): the
            board's own contrast.
        board_size: ``(cols, rows)``.
        fraction: see above; a float or a :math:`(B, N)` tensor (one per corner).

    Returns:
        :math:`(B, N)` bool (False on boards without a visible corner).

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)  # 4 x 3 squares of 32 px: 3 x 2 inner corners
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> img[..., :, 80:] = 1.0  # glare saturates the right-hand squares
        >>> pts = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> hidden_corners(img, pts, torch.ones(1, 6, dtype=torch.bool), (3, 2)).tolist()
        [[False, False, True, False, False, True]]
    """
    fraction = torch.as_tensor(fraction, dtype=torch.float64)
    if not bool(((fraction > 0) & (fraction < 1)).all()):
        raise ValueError(f"fraction must be in (0, 1), got {fraction}.")
    relative = relative_contrast(images, corners, visible, board_size)
    return (relative < fraction.to(relative)).nan_to_num(False)


def relative_contrast(
    images: torch.Tensor, corners: torch.Tensor, visible: torch.Tensor, board_size: tuple[int, int]
) -> torch.Tensor:
    r""":func:`checker_contrast` of every corner over its median on the ``visible`` corners of the board (what
    :func:`hidden_corners` compares with its fractions; one measurement serves several thresholds).

    Args:
        images, corners, visible, board_size: see :func:`hidden_corners`.

    Returns:
        :math:`(B, N)`, NaN on boards without a visible corner and at corners whose contrast cannot be measured.

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> img[..., :, 80:] = 1.0
        >>> pts = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> relative_contrast(img, pts, torch.ones(1, 6, dtype=torch.bool), (3, 2)).tolist()
        [[1.0, 1.0, 0.0, 1.0, 1.0, 0.0]]
    """
    contrast = checker_contrast(images, corners, board_size)
    check_tensor(visible, "visible", contrast.shape)
    reference = torch.where(visible.to(contrast.device), contrast, torch.full_like(contrast, float("nan")))
    reference = reference.nanmedian(-1, keepdim=True).values
    return torch.where(reference > 0, contrast / reference, torch.full_like(contrast, float("nan")))


def glare_rim(candidates: torch.Tensor, hidden: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    r"""The ``candidates`` next to a ``hidden`` corner (one grid step along a row or a column).

    Args:
        candidates: :math:`(B, N)` bool, e.g. the predicted corners the saddle refinement could not confirm.
        hidden: :math:`(B, N)` bool, the corners the image does not show (:func:`hidden_corners`).
        board_size: ``(cols, rows)``, ``N = cols * rows`` in grid order.

    Returns:
        :math:`(B, N)` bool.

    Example:
        >>> hidden = torch.tensor([[False, True, False, False, False, False]])  # 3 x 2 board, corner (1, 0) hidden
        >>> glare_rim(torch.ones(1, 6, dtype=torch.bool), hidden, (3, 2)).tolist()
        [[True, False, True, False, True, False]]
    """
    cols, rows = check_board_size(board_size)
    check_tensor(hidden, "hidden", ["B", "N"], N=cols * rows)
    check_same_shape(candidates, "candidates", hidden, "hidden")
    h = F.pad(hidden.reshape(-1, rows, cols).float(), (1, 1, 1, 1))
    near = h[:, :-2, 1:-1] + h[:, 2:, 1:-1] + h[:, 1:-1, :-2] + h[:, 1:-1, 2:]
    return candidates & ~hidden & (near > 0).reshape(hidden.shape)


def spans_board(valid: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    r"""Whether the ``valid`` corners reach all four border lines of the board (its first and last row and column).

    Such a lattice has one place on the board; a shorter one was placed by what the image shows at its empty cells,
    and only the corners confirmed there vouch for that placement.

    Args:
        valid: :math:`(B, N)` bool, ``N = cols * rows`` in grid order.
        board_size: ``(cols, rows)``.

    Returns:
        :math:`(B,)` bool.

    Example:
        >>> valid = torch.ones(2, 6, dtype=torch.bool)
        >>> valid[1, [2, 5]] = False  # 3 x 2 board without its last column
        >>> spans_board(valid, (3, 2)).tolist()
        [True, False]
    """
    cols, rows = check_board_size(board_size)
    check_tensor(valid, "valid", ["B", "N"], N=cols * rows)
    g = valid.reshape(-1, rows, cols)
    return g[:, 0].any(-1) & g[:, -1].any(-1) & g[:, :, 0].any(-1) & g[:, :, -1].any(-1)


def settle_partial_boards(
    images: torch.Tensor, result: DetectionResult, board_size: tuple[int, int],
    max_asymmetry: float = MAX_ASYMMETRY_RATIO, min_visible: float = PARTIAL_BOARD_FRACTION,
    max_asymmetry_whole: float = MAX_ASYMMETRY_RATIO_WHOLE,
) -> DetectionResult:
    r"""Leave out the corners of the found boards whose point symmetry is far worse than the board's median (more than
    ``max_asymmetry`` times on boards with hidden (NaN) corners, ``max_asymmetry_whole`` times on the others), then
    refuse the boards left with fewer than ``min_visible`` of their corners. The point-symmetry residuals it measured
    are kept as the result's per-corner precision (``sigma``, NaN at the corners left out and off the boards found),
    so that a solver weighing corners by it need not measure them again.

    Args:
        images: :math:`(B, 1, H, W)` the full-resolution images of ``result``.
        result: a :class:`~ccs_kornia.modules.detection.base.DetectionResult` (modified in place, ``sigma``
            replaced, and returned).
        board_size: ``(cols, rows)``.
        max_asymmetry, min_visible, max_asymmetry_whole: see above.

    Returns:
        ``result``.

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> pts = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> pts[0, 2:] = float("nan")  # four of six corners hidden: too few left
        >>> out = settle_partial_boards(img, DetectionResult(pts, torch.tensor([True]), ["learned"]), (3, 2))
        >>> out.found.tolist(), out.reasons
        ([False], ['board incomplete: 4 of 6 corners hidden'])
    """
    n = result.corners.shape[1]
    idx = result.found.nonzero().flatten()
    result.sigma = torch.full(result.corners.shape[:2], float("nan"), dtype=torch.float32,
                              device=result.corners.device)
    if idx.numel() == 0:
        return result
    corners = result.corners[idx]
    measured = corners.isfinite().all(-1)
    sigma = corner_uncertainty(image_rows(images, idx), corners, measured, board_size)
    ratio = sigma / sigma.nanmedian(-1, keepdim=True).values.clamp_min(1e-12)
    limit = torch.where(measured.all(-1), max_asymmetry_whole, max_asymmetry)[:, None]
    corners = corners.masked_fill((ratio > limit.to(ratio))[..., None].to(corners.device), float("nan"))
    result.corners[idx] = corners
    result.sigma[idx] = sigma.to(result.sigma).masked_fill(~corners.isfinite().all(-1).to(result.sigma.device),
                                                           float("nan"))
    visible = corners.isfinite().all(-1).sum(-1)
    for k, b in enumerate(idx.tolist()):
        if int(visible[k]) < min_visible * n:
            result.found[b] = False
            result.corners[b] = 0.0
            result.sigma[b] = float("nan")
            if result.reasons is not None:
                result.reasons[b] = f"board incomplete: {n - int(visible[k])} of {n} corners hidden"
    return result
