r"""Whether a model fits: the structure left in a calibration's residuals, and the model-fit flag it gives.

A model that fits leaves residuals that are the detector's noise: zero on average everywhere in the image. A model that
cannot follow the lens leaves the same error wherever the lens departs from it, view after view. The figure
(:func:`residual_structure`): the image in a grid of cells (6 x 4 by default), the mean residual vector of the corners in
each cell with its standard error (the residuals' spread in the cell over the square root of their number); a cell is
*significant* where its mean is beyond what the noise explains (the squared means over their squared standard errors,
summed over x and y, above the 99 % point of a chi-square with 2 degrees of freedom, 9.21). Reported: the cells with
enough corners, the RMS of the cell means, the cells significant and the worst cell mean.

The corners' own noise is measured on the board itself: along its rows and columns, the third difference of four
neighbouring corners' residuals (``r_a - 3 r_b + 3 r_c - r_d``) cancels whatever the model leaves that varies smoothly
over the board (up to a quadratic along the row) and keeps the noise (20 times its variance). Its median length over the
square root of 20 is the noise's typical length (that of a residual of pure noise, by the same median); the *noise
ratio* is the median residual length over it: about 1 where the residuals are noise. (Second differences are polluted
by the curvature of a wide lens's error field: a pinhole fit of a lens with k1 = -0.3 reads 4.6 with them, 12 with
third differences, where a fit to the noise reads 1.0; ``docs/benchmarks.md``.)

:func:`model_fit` turns it into one flag per camera (:class:`ModelFit`):

* ``DOES_NOT_FIT``: the residuals are far above the corners' noise: the noise ratio above ``max_ratio`` (8), or the RMS
  above ``noise_factor`` times the detector's noise where that is given;
* ``STRUCTURED``: the model fits, but more than a quarter of the cells are significant (1 % by chance) and their mean
  residuals are not negligible (RMS of the cell means above ``floor_px``): a richer model, or a bent board
  (:mod:`~ccs_kornia.modules.calibration.board_flatness`), would explain more;
* ``FITS``: otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import torch

from ccs_kornia.runtime.checks import check_same_shape, check_tensor

__all__ = ["CHI2_2DOF_99", "ModelFit", "ResidualStructure", "board_runs", "model_fit", "residual_structure"]

#: the 99 % point of a chi-square with 2 degrees of freedom: a cell mean beyond it is significant
CHI2_2DOF_99 = 9.2103


class ModelFit(IntEnum):
    """How well the model follows the lens (``CalibrationResult.model_fit``).

    Example:
        >>> ModelFit(2).label, ModelFit.STRUCTURED.message.split(":")[0]
        ('does not fit', 'the residuals have structure over the image')
    """

    FITS = 0
    STRUCTURED = 1
    DOES_NOT_FIT = 2

    @property
    def message(self) -> str:
        return MODEL_FIT_MESSAGES[self]

    @property
    def label(self) -> str:
        """One word for the JSON (``fits``, ``structured``, ``does not fit``)."""
        return ("fits", "structured", "does not fit")[int(self)]


MODEL_FIT_MESSAGES = {
    ModelFit.FITS: "the model fits: the residuals are noise",
    ModelFit.STRUCTURED: "the residuals have structure over the image: a richer lens model or a bent board would "
                         "explain more",
    ModelFit.DOES_NOT_FIT: "the model does not fit: the residuals are mostly its error, not the corners' noise",
}


@dataclass
class ResidualStructure:
    """:func:`residual_structure` of C cameras.

    Attributes:
        cells: :math:`(C,)` int64 cells with enough corners to judge.
        rms_cell_means: :math:`(C,)` px, the RMS over those cells of the mean residual's length.
        significant: :math:`(C,)` int64 cells whose mean is beyond their standard error (module docstring).
        worst: :math:`(C,)` px, the longest cell mean.
        rms: :math:`(C,)` px, the RMS of the residuals (over the corners judged).
        grid: ``(columns, rows)`` of cells.
    """

    cells: torch.Tensor
    rms_cell_means: torch.Tensor
    significant: torch.Tensor
    worst: torch.Tensor
    rms: torch.Tensor
    grid: tuple[int, int]
    #: (C,) px, the corners' noise measured on the board (module docstring; NaN without four corners in a row)
    noise: torch.Tensor | None = None
    median: torch.Tensor | None = None  #: (C,) px, the median residual length
    #: (C, rows, columns, 2) px, each cell's mean residual (NaN where too few corners to judge)
    cell_means: torch.Tensor | None = None
    #: (C, rows, columns) bool, the cells whose mean is beyond their standard error
    cell_significant: torch.Tensor | None = None

    @property
    def noise_ratio(self) -> torch.Tensor | None:
        """:math:`(C,)` the median residual over the corners' noise (about 1: the residuals are noise)."""
        return None if self.noise is None else self.median / self.noise


def board_runs(object_points: torch.Tensor) -> torch.Tensor:
    """:math:`(T, 4)` indices of four neighbouring points in a row or column of the board (one spacing apart, in
    order), each run once.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> board_runs(board_object_points(5, 2, 0.1)).tolist()
        [[0, 1, 2, 3], [1, 2, 3, 4], [5, 6, 7, 8], [6, 7, 8, 9]]
    """
    xy = object_points[..., :2].to(torch.float64)
    if xy.shape[0] < 4:
        return torch.zeros(0, 4, dtype=torch.long, device=xy.device)
    d = (xy[:, None] - xy[None]).norm(dim=-1)
    d.fill_diagonal_(float("inf"))
    s = d.min()
    a, b = ((d - s).abs() <= 1e-6 * s).nonzero().unbind(-1)
    step = xy[b] - xy[a]
    run = [a, b]
    keep = torch.ones_like(a, dtype=torch.bool)
    for k in (2, 3):
        gap, nxt = ((xy[a] + k * step)[:, None] - xy[None]).norm(dim=-1).min(-1)
        keep = keep & (gap <= 1e-6 * s)
        run.append(nxt)
    keep = keep & (a < run[3])
    return torch.stack([r[keep] for r in run], -1)


def residual_structure(residuals: torch.Tensor, corners: torch.Tensor, mask: torch.Tensor,
                       image_size: tuple[int, int], grid: tuple[int, int] = (6, 4),
                       min_count: int = 10, runs: torch.Tensor | None = None) -> ResidualStructure:
    r"""The residuals' structure over the image (module docstring).

    Args:
        residuals: :math:`(C, V, N, 2)` projected minus observed pixels.
        corners: :math:`(C, V, N, 2)` the observed pixels (which cell a residual falls in).
        mask: :math:`(C, V, N)` bool, the residuals to judge.
        image_size: ``(W, H)``.
        grid: ``(columns, rows)`` of cells.
        min_count: cells with fewer corners are left out.
        runs: :math:`(T, 4)` neighbouring corners in a row (:func:`board_runs`) for the corners' noise
            (``None``: not measured).

    Returns:
        :class:`ResidualStructure`.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> corners = torch.rand(1, 40, 50, 2, generator=g, dtype=torch.float64) * 600
        >>> noise = 0.1 * torch.randn(1, 40, 50, 2, generator=g, dtype=torch.float64)
        >>> mask = torch.ones(1, 40, 50, dtype=torch.bool)
        >>> s = residual_structure(noise, corners, mask, (600, 600))
        >>> int(s.cells), int(s.significant) <= 1, float(s.rms_cell_means) < 0.02
        (24, True, True)
        >>> s = residual_structure(noise + 0.003 * (corners - 300), corners, mask, (600, 600))
        >>> int(s.significant), round(float(s.worst), 1)
        (24, 1.0)
    """
    check_tensor(residuals, "residuals", ["C", "V", "N", "2"])
    check_same_shape(residuals, "residuals", corners, "corners")
    C = residuals.shape[0]
    gx, gy = int(grid[0]), int(grid[1])
    W, H = float(image_size[0]), float(image_size[1])
    ok = mask.bool() & residuals.isfinite().all(-1) & corners.isfinite().all(-1)
    col = (corners[..., 0].nan_to_num(0.0) / W * gx).floor().clamp(0, gx - 1).long()
    row = (corners[..., 1].nan_to_num(0.0) / H * gy).floor().clamp(0, gy - 1).long()
    cell = (row * gx + col).masked_fill(~ok, gx * gy)  # the last bin: not judged
    r = torch.where(ok[..., None], residuals, 0.0).to(torch.float64)
    flat_cell = cell.reshape(C, -1)
    K = gx * gy + 1
    n = torch.zeros(C, K, dtype=torch.float64, device=r.device).scatter_add_(1, flat_cell,
                                                                            ok.reshape(C, -1).to(torch.float64))
    s1 = torch.zeros(C, K, 2, dtype=torch.float64, device=r.device).scatter_add_(
        1, flat_cell[..., None].expand(-1, -1, 2), r.reshape(C, -1, 2))
    s2 = torch.zeros(C, K, 2, dtype=torch.float64, device=r.device).scatter_add_(
        1, flat_cell[..., None].expand(-1, -1, 2), r.reshape(C, -1, 2) ** 2)
    n, s1, s2 = n[:, :-1], s1[:, :-1], s2[:, :-1]
    enough = n >= max(int(min_count), 2)
    mean = s1 / n.clamp_min(1)[..., None]
    var = ((s2 - n[..., None] * mean**2) / (n - 1).clamp_min(1)[..., None]).clamp_min(0)
    se2 = var / n.clamp_min(1)[..., None]
    chi2 = (mean**2 / se2.clamp_min(torch.finfo(torch.float64).tiny)).sum(-1)
    length = mean.norm(dim=-1)
    cells = enough.sum(-1)
    rms_means = (torch.where(enough, length**2, 0.0).sum(-1) / cells.clamp_min(1)).sqrt()
    rms_means = rms_means.masked_fill(cells == 0, float("nan"))
    significant = (enough & (chi2 > CHI2_2DOF_99)).sum(-1)
    worst = torch.where(enough, length, float("-inf")).amax(-1).masked_fill(cells == 0, float("nan"))
    count = ok.reshape(C, -1).sum(-1)
    rms = ((r**2).sum((-1, -2, -3)) / count.clamp_min(1)).sqrt().masked_fill(count == 0, float("nan"))
    noise = median = None
    if runs is not None:
        length = residuals.to(torch.float64).norm(dim=-1).masked_fill(~ok, float("nan")).reshape(C, -1)
        median = length.nanmedian(-1).values
        a, b, c, d = runs.to(residuals.device).unbind(-1)
        every = ok[..., a] & ok[..., b] & ok[..., c] & ok[..., d]
        r64 = residuals.to(torch.float64)
        d3 = (r64[..., a, :] - 3 * r64[..., b, :] + 3 * r64[..., c, :] - r64[..., d, :]).norm(dim=-1)
        d3 = d3.masked_fill(~every, float("nan")).reshape(C, -1)
        noise = d3.nanmedian(-1).values / 20**0.5 if d3.shape[-1] else torch.full_like(rms, float("nan"))
    cell_means = mean.masked_fill(~enough[..., None], float("nan")).reshape(C, gy, gx, 2)
    cell_significant = (enough & (chi2 > CHI2_2DOF_99)).reshape(C, gy, gx)
    return ResidualStructure(cells, rms_means, significant, worst, rms, (gx, gy), noise, median, cell_means,
                             cell_significant)


def model_fit(structure: ResidualStructure, noise_px: torch.Tensor | float | None = None, noise_factor: float = 10.0,
              floor_px: float = 0.02, max_ratio: float = 8.0) -> torch.Tensor:
    """:math:`(C,)` int64 :class:`ModelFit` of each camera from its :class:`ResidualStructure` (module docstring).

    Args:
        structure: the residuals' structure.
        noise_px: the detector's noise (px, per coordinate RMS) where known.
        noise_factor: an RMS above this many times the noise does not fit.
        floor_px: residuals (their median, or the cell means' RMS) below this are never called a misfit or structure
            (the numerical noise of an exact fit).
        max_ratio: a noise ratio above this does not fit.

    Example:
        >>> s = ResidualStructure(torch.tensor([24, 24, 24]), torch.tensor([0.05, 0.5, 11.0]),
        ...                       torch.tensor([1, 21, 24]), torch.tensor([0.1, 1.2, 22.0]),
        ...                       torch.tensor([0.6, 1.4, 28.0]), (6, 4), noise=torch.tensor([0.3, 0.23, 1.5]),
        ...                       median=torch.tensor([0.4, 0.9, 17.0]))
        >>> [ModelFit(int(v)).label for v in model_fit(s)]
        ['fits', 'structured', 'does not fit']
    """
    rms, means = structure.rms.to(torch.float64), structure.rms_cell_means.to(torch.float64)
    judged = structure.cells > 0
    big = means > floor_px
    misfit = torch.zeros_like(judged)
    if structure.noise is not None:
        ratio = structure.noise_ratio.to(torch.float64)
        misfit = (ratio > max_ratio) & (structure.median > floor_px)
    if noise_px is not None:
        misfit = misfit | (rms > noise_factor * torch.as_tensor(noise_px, dtype=torch.float64, device=rms.device)
                           * 2**0.5)
    structured = judged & big & (4 * structure.significant > structure.cells)
    out = torch.full_like(structure.cells, ModelFit.FITS)
    out = out.masked_fill(structured, ModelFit.STRUCTURED)
    return out.masked_fill(misfit, ModelFit.DOES_NOT_FIT)
