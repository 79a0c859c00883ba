r"""Seeds of the sub-pixel corner positions: local maxima of a corner heatmap (paper Sec. III-B).

:func:`heatmap_peaks` / :class:`HeatmapPeaks`: strict local maxima (kornia ``nms2d``) above a threshold, the
``max_peaks`` strongest per image, each moved to the weighted mean of the heatmap in a small window around it
(kornia ``spatial_expectation2d``). :func:`~ccs_kornia.modules.detection.learned.gaussian_fit.gaussian_fit` then gives
the precise position and :func:`~ccs_kornia.modules.detection.learned.sigma_rejection.sigma_outlier_rejection` drops
unreliable blobs.

Coordinates follow the project convention: the centre of the top-left pixel is ``(0, 0)``, ``x`` is the column,
``y`` the row. Variable peak counts are padded to ``M`` with a boolean mask.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from kornia.geometry.subpix import spatial_expectation2d
from torch import nn

from ccs_kornia.runtime.checks import check_tensor

__all__ = [
    "strict_local_maxima", "heatmap_peaks", "HeatmapPeaks", "check_heatmap", "check_odd_window", "gather_windows",
]


def check_heatmap(heatmap: torch.Tensor) -> None:
    """Raise unless ``heatmap`` is a floating-point corner heatmap :math:`(B, 1, H, W)` (``TypeError`` for a non-tensor,
    ``ValueError`` otherwise): the check at the boundary of the heatmap's stages (peaks, Gaussian fit).

    Example:
        >>> check_heatmap(torch.zeros(2, 1, 8, 8))
        >>> check_heatmap(torch.zeros(2, 8, 8))
        Traceback (most recent call last):
        ...
        ValueError: heatmap must be (B, 1, H, W), got (2, 8, 8).
    """
    if not isinstance(heatmap, torch.Tensor):
        raise TypeError(f"heatmap must be a torch.Tensor, got {type(heatmap)}.")
    check_tensor(heatmap, "heatmap", ["B", "1", "H", "W"])
    if not heatmap.is_floating_point():
        raise ValueError(f"heatmap must be a floating point tensor, got {heatmap.dtype}.")


def check_odd_window(window: int, name: str = "window") -> None:
    """Raise ``ValueError`` unless ``window`` (the argument ``name``) is an odd integer >= 3: a window centred on a
    pixel (non-maximum suppression, the peaks' weighted mean, the Gaussian fit).

    Example:
        >>> check_odd_window(5)
        >>> check_odd_window(4, "nms_kernel")
        Traceback (most recent call last):
        ...
        ValueError: nms_kernel must be an odd integer >= 3, got 4.
    """
    if not isinstance(window, int) or window < 3 or window % 2 == 0:
        raise ValueError(f"{name} must be an odd integer >= 3, got {window!r}.")


def gather_windows(heatmap: torch.Tensor, centres: torch.Tensor, window: int) -> torch.Tensor:
    """``window x window`` patches of ``heatmap`` (B,1,H,W) centred on integer ``centres`` (B,M,2) xy: what the peaks'
    weighted mean and the Gaussian fit read around each seed.

    Pixels outside the image read as ``0``, so a peak near the border keeps its in-image pixels only. Centres
    must lie inside the image. Differentiable with respect to ``heatmap``.

    Returns:
        patches of shape (B, M, window, window).

    Example:
        >>> heat = torch.arange(16.0).reshape(1, 1, 4, 4)
        >>> gather_windows(heat, torch.tensor([[[0, 0]]]), 3)[0, 0]
        tensor([[0., 0., 0.],
                [0., 0., 1.],
                [0., 4., 5.]])
    """
    batch, _, height, width = heatmap.shape
    num = centres.shape[1]
    radius = window // 2
    padded = F.pad(heatmap[:, 0], (radius, radius, radius, radius))  # (B, H+2r, W+2r), zeros outside
    padded_width = width + 2 * radius
    steps = torch.arange(window, device=heatmap.device)
    rows = centres[..., 1, None, None] + steps[:, None]  # (B, M, K, 1): row in padded = y - r + k + r
    cols = centres[..., 0, None, None] + steps[None, :]  # (B, M, 1, K)
    index = (rows * padded_width + cols).reshape(batch, num * window * window)
    patches = padded.reshape(batch, -1).gather(1, index)
    return patches.reshape(batch, num, window, window)


def strict_local_maxima(x: torch.Tensor, kernel: int) -> torch.Tensor:
    r"""Pixels strictly greater than every other pixel of their ``kernel x kernel`` window, :math:`(B, C, H, W)` bool.

    The same mask as kornia's ``nms2d(..., mask_only=True)`` on the map padded with ``-inf`` (pixels near the border
    are compared with their in-image neighbours only; NaN is never a maximum and never lets a neighbour be one), from
    five max-poolings instead of ``kernel**2 - 1`` full-size comparisons: the largest neighbour is the largest of the
    rows above, the rows below, and the left and right parts of the pixel's own row.

    Example:
        >>> x = torch.tensor([[[[0., 1, 0, 0], [0, 0, 0, 2], [3, 0, 0, 2]]]])
        >>> strict_local_maxima(x, 3)[0, 0].int()
        tensor([[0, 1, 0, 0],
                [0, 0, 0, 0],
                [1, 0, 0, 0]], dtype=torch.int32)
    """
    check_odd_window(kernel, "kernel")
    r = kernel // 2
    h, w = x.shape[-2:]
    padded = F.pad(x, (r, r, r, r), value=float("-inf"))

    def run_max(t: torch.Tensor, n: int, dim: int) -> torch.Tensor:
        # max over n consecutive entries along dim (output shorter by n - 1); shifted slices, no pooling kernel
        out = t.narrow(dim, 0, t.shape[dim] - n + 1)
        for d in range(1, n):
            out = torch.maximum(out, t.narrow(dim, d, t.shape[dim] - n + 1))
        return out

    rows = run_max(padded, kernel, -1)  # (.., H + 2r, W): max over the full window width
    above = run_max(rows[..., : h + r - 1, :], r, -2)
    below = run_max(rows[..., r + 1 :, :], r, -2)
    middle = padded[..., r : r + h, :]
    left = run_max(middle[..., : w + r - 1], r, -1)
    right = run_max(middle[..., r + 1 :], r, -1)
    neighbours = torch.maximum(torch.maximum(above, below), torch.maximum(left, right))
    return x > neighbours


def heatmap_peaks(
    heatmap: torch.Tensor,
    threshold: float = 0.3,
    max_peaks: int = 256,
    nms_kernel: int = 5,
    refine_window: int = 5,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    r"""Seed points: the strongest local maxima of a corner heatmap, refined to sub-pixel by a local weighted mean.

    A pixel is a peak when it is strictly greater than every other pixel in its ``nms_kernel`` window
    (:func:`strict_local_maxima`, kornia ``nms2d``'s mask; corners near the border can be peaks too) and greater than
    ``threshold``. The ``max_peaks`` highest peaks are kept, sorted by score. Each seed is then the heatmap-weighted
    mean position (kornia ``spatial_expectation2d``) in the ``refine_window`` around the peak pixel. That mean is
    pulled towards the peak pixel (the window truncates the blob): for sigma 1.5 seeds are within 0.25 px with the
    default 5x5 window (0.5 px with 3x3); :func:`gaussian_fit` gives the precise position.

    Args:
        heatmap: corner heatmap :math:`(B, 1, H, W)`.
        threshold: minimum heatmap value of a peak.
        max_peaks: ``M``, the number of slots per image (unused slots have ``mask == False``).
        nms_kernel: odd size of the non-maximum-suppression window; keep it below the corner spacing in pixels.
        refine_window: odd size of the window of the weighted mean.

    Returns:
        - seeds :math:`(B, M, 2)` sub-pixel ``(x, y)`` (``0`` where masked out),
        - scores :math:`(B, M)` heatmap value at the peak pixel (``0`` where masked out),
        - mask :math:`(B, M)` bool, ``True`` for real peaks; real peaks come first, by decreasing score.

    Example:
        >>> heat = torch.zeros(1, 1, 32, 32)
        >>> heat[0, 0, 10, 20] = 1.0
        >>> seeds, scores, mask = heatmap_peaks(heat, max_peaks=4)
        >>> seeds[0, 0], mask[0]
        (tensor([20., 10.]), tensor([ True, False, False, False]))
    """
    check_heatmap(heatmap)
    check_odd_window(nms_kernel, "nms_kernel")
    check_odd_window(refine_window, "refine_window")
    if not isinstance(max_peaks, int) or max_peaks < 1:
        raise ValueError(f"max_peaks must be a positive integer, got {max_peaks!r}.")
    batch, _, height, width = heatmap.shape
    with torch.no_grad():
        candidates = strict_local_maxima(heatmap, nms_kernel) & (heatmap > threshold)
        flat = torch.where(candidates, heatmap, torch.full_like(heatmap, float("-inf"))).reshape(batch, -1)
        k = min(max_peaks, height * width)
        top_values, top_index = flat.topk(k, dim=1)
        mask = torch.isfinite(top_values)
        if k < max_peaks:  # fewer pixels than slots: pad to the fixed size M
            top_values = F.pad(top_values, (0, max_peaks - k))
            top_index = F.pad(top_index, (0, max_peaks - k))
            mask = F.pad(mask, (0, max_peaks - k), value=False)
        top_index = torch.where(mask, top_index, torch.zeros_like(top_index))
        centres = torch.stack([top_index % width, top_index // width], dim=-1)  # (B, M, 2) integer xy

    patches = gather_windows(heatmap, centres, refine_window).clamp_min(0)  # (B, M, K, K)
    total = patches.sum(dim=(-2, -1), keepdim=True)
    weights = patches / total.clamp_min(torch.finfo(heatmap.dtype).tiny)
    local = spatial_expectation2d(weights, normalized_coordinates=False)  # (B, M, 2) in patch coordinates
    seeds = centres.to(heatmap.dtype) + local - refine_window // 2
    seeds = torch.where(mask[..., None], seeds, torch.zeros_like(seeds))
    scores = torch.where(mask, top_values, torch.zeros_like(top_values)).to(heatmap.dtype)
    return seeds, scores, mask


class HeatmapPeaks(nn.Module):
    r"""Module form of :func:`heatmap_peaks`: seeds, scores and mask from a corner heatmap.

    Args:
        threshold: minimum heatmap value of a peak.
        max_peaks: number of slots ``M`` per image.
        nms_kernel: odd non-maximum-suppression window.
        refine_window: odd window of the local weighted mean.

    Example:
        >>> seeds, scores, mask = HeatmapPeaks(max_peaks=8)(torch.rand(2, 1, 32, 32))
        >>> seeds.shape, scores.shape, mask.shape
        (torch.Size([2, 8, 2]), torch.Size([2, 8]), torch.Size([2, 8]))
    """

    def __init__(
        self, threshold: float = 0.3, max_peaks: int = 256, nms_kernel: int = 5, refine_window: int = 5
    ) -> None:
        super().__init__()
        check_odd_window(nms_kernel, "nms_kernel")
        check_odd_window(refine_window, "refine_window")
        self.threshold = threshold
        self.max_peaks = max_peaks
        self.nms_kernel = nms_kernel
        self.refine_window = refine_window

    def forward(self, heatmap: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return heatmap_peaks(heatmap, self.threshold, self.max_peaks, self.nms_kernel, self.refine_window)

    def extra_repr(self) -> str:
        return (
            f"threshold={self.threshold}, max_peaks={self.max_peaks}, nms_kernel={self.nms_kernel}, "
            f"refine_window={self.refine_window}"
        )
