"""The detector interface: a batch of grey images in, all ``cols*rows`` inner corners in grid order out.

:class:`ChessboardDetector` is the interface every detector implements (the OpenCV baseline in
:mod:`~ccs_kornia.modules.detection.opencv_detector`, the learned heatmap detector in
:mod:`~ccs_kornia.modules.detection.learned_detector`); :class:`DetectionResult` is what they return.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator

import torch
from torch import nn

from ccs_kornia.modules._checks import check_shape

__all__ = ["DetectionResult", "ChessboardDetector", "detector_options", "image_rows", "measured_corners"]


def image_rows(images: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``images[idx]``, without a copy where ``idx`` (increasing) is a run of consecutive images (a view): a batch's
    images are found, or share a level, more often than not, and a copy costs 0.6 ms per 640x480 image and 0.15 s
    per 27 Mpx photograph each time.

    Example:
        >>> x = torch.rand(4, 1, 8, 8)
        >>> image_rows(x, torch.tensor([1, 2])).data_ptr() == x[1:3].data_ptr()
        True
    """
    n = idx.numel()
    if n and int(idx[-1]) - int(idx[0]) == n - 1:
        return images.narrow(0, int(idx[0]), n)
    return images[idx.to(images.device)]


def measured_corners(corners: torch.Tensor, found: torch.Tensor) -> torch.Tensor:
    """Mask :math:`(..., N)` of the measured corners: those of found views (``found`` :math:`(...)`) that are finite (a
    partial board's hidden corners are NaN).

    Example:
        >>> c = torch.tensor([[[1.0, 2.0], [float("nan"), 0.0]], [[0.0, 0.0], [0.0, 0.0]]])
        >>> measured_corners(c, torch.tensor([True, False])).tolist()
        [[True, False], [False, False]]
    """
    return found.bool()[..., None] & corners.isfinite().all(-1)


@dataclass
class DetectionResult:
    """Corners detected on a batch of images.

    Attributes:
        corners: :math:`(B, N, 2)` pixel coordinates in grid order (``n = j*cols + i``), zeros where
            the board was not found, NaN at the corners of a found board that the image does not show (a partial
            board: glare, an occluder).
        found: :math:`(B,)` bool, the board was found (its identity and order are known; :attr:`valid` says which
            corners were measured).
        reasons: optional per-image text: how the board was found (``"classic"``, ``"sb"``) or why it
            was not.
        sigma: optional :math:`(B, N)` per-corner precision (px, relative; NaN where unknown), e.g. from
            :func:`~ccs_kornia.modules.detection.corner_uncertainty.corner_uncertainty`.
    """

    corners: torch.Tensor
    found: torch.Tensor
    reasons: list[str] | None = None
    sigma: torch.Tensor | None = None

    @property
    def valid(self) -> torch.Tensor:
        """:math:`(B, N)` bool mask of measured corners (those of a found board, less any hidden ones)."""
        return measured_corners(self.corners, self.found)


class ChessboardDetector(nn.Module):
    """Interface: ``forward(images (B,1,H,W) in [0,1], board_size (cols, rows)) -> DetectionResult``."""

    def forward(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def _check_inputs(images: torch.Tensor, board_size: tuple[int, int]) -> tuple[int, int]:
        check_shape(images, ["B", "1", "H", "W"], "Expected grey images of shape (B, 1, H, W)")
        if len(board_size) != 2 or min(int(board_size[0]), int(board_size[1])) < 2:
            raise ValueError(f"board_size must be (cols, rows) with at least 2 inner corners each, got {board_size}.")
        return int(board_size[0]), int(board_size[1])


@contextmanager
def detector_options(detector: Any, **options: Any) -> Iterator[Any]:
    """Set the detector's attributes ``options`` for a ``with`` block, then restore them; options the detector does
    not have are ignored (e.g. the learned detector's last resorts, switched off for second looks at many views).

    Example:
        >>> class Det:
        ...     opencv_retry = True
        >>> d = Det()
        >>> with detector_options(d, opencv_retry=False, foreshortened_retry=False):
        ...     d.opencv_retry, hasattr(d, "foreshortened_retry")
        (False, False)
        >>> d.opencv_retry
        True
    """
    saved = {k: getattr(detector, k) for k in options if hasattr(detector, k)}
    for k in saved:
        setattr(detector, k, options[k])
    try:
        yield detector
    finally:
        for k, value in saved.items():
            setattr(detector, k, value)
