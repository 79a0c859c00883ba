"""The detector interface: a batch of grey images in, all ``cols*rows`` inner corners in grid order out.

:class:`ChessboardDetector` is the interface every detector implements (the OpenCV baseline in
:mod:`~ccs_kornia.modules.detection.opencv_detector`, the learned heatmap detector in
:mod:`~ccs_kornia.modules.detection.learned.learned_detector`); :class:`DetectionResult` is what they return.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from ccs_kornia.runtime.checks import check_board_size, check_grey_images

__all__ = ["DetectionResult", "ChessboardDetector", "Fallbacks", "image_rows", "measured_corners"]


def image_rows(images: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``images[idx]``, without a copy where ``idx`` (increasing) is a run of consecutive images (a view): a batch's
    images are found, or share a level, more often than not, and a copy costs its time on every call
    (``docs/measurements.md``).

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
            :func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_uncertainty`.
        correction: optional :math:`(C, 5)` lens correction per camera of a :math:`(C, V)` result (the calibration
            pipeline's ``detect``: the network's pooled correction, for its ``calibrate``).
        correction_tried: optional :math:`(C,)` bool with ``correction``: the correction is large enough to be tried.
        gap: optional, the shape of ``corners``: how far a differentiable corner estimator's value is from each corner
            (px; NaN where not found; the pipeline's differentiable ``detect``).
    """

    corners: torch.Tensor
    found: torch.Tensor
    reasons: list[str] | None = None
    sigma: torch.Tensor | None = None
    correction: torch.Tensor | None = None
    correction_tried: torch.Tensor | None = None
    gap: torch.Tensor | None = None

    @property
    def valid(self) -> torch.Tensor:
        """:math:`(B, N)` bool mask of measured corners (those of a found board, less any hidden ones)."""
        return measured_corners(self.corners, self.found)

    def fill(self, index: Any, other: "DetectionResult") -> torch.Tensor:
        """Write the boards ``other`` found into this result at ``index`` (in place), where this one has none.

        ``index`` selects ``other.found.shape[0]`` entries of this result's leading dimensions (an index tensor, or a
        tuple of them for :math:`(C, V)` results). Where ``other`` found the board, its corners, ``found``, reason and
        precision (NaN where ``other`` has none) replace this result's; elsewhere this result is left as it is.

        Returns:
            :math:`(B,)` bool: where ``other`` found the board.

        Example:
            >>> det = DetectionResult(torch.zeros(2, 3, 1, 2), torch.zeros(2, 3, dtype=torch.bool), ["no"] * 6)
            >>> got = DetectionResult(torch.ones(2, 1, 2), torch.tensor([True, False]), ["yes", "no again"])
            >>> det.fill((torch.tensor([0, 1]), torch.tensor([2, 0])), got).tolist(), det.found.tolist(), det.reasons[2]
            ([True, False], [[False, False, True], [False, False, False]], 'yes')
        """
        hit = other.found.to(self.found.device).bool()
        flat = torch.arange(self.found.numel(), device=self.found.device).reshape(self.found.shape)
        flat = flat[tuple(i.to(flat.device) for i in index) if isinstance(index, tuple) else index.to(flat.device)]
        if bool(hit.any()):
            at = flat[hit]
            self.corners.view(-1, *self.corners.shape[self.found.dim():])[at] = other.corners.to(self.corners.device)[
                hit.to(other.corners.device)].to(self.corners.dtype)
            self.found.view(-1)[at] = True
            if self.sigma is not None:
                sigma = self.sigma.view(-1, self.sigma.shape[-1])
                if other.sigma is None:
                    sigma[at] = float("nan")
                else:
                    sigma[at] = other.sigma.to(self.sigma.device)[hit.to(other.sigma.device)].to(self.sigma.dtype)
        if self.reasons is not None and other.reasons is not None:
            for k, i in enumerate(flat.tolist()):
                if bool(hit[k]):
                    self.reasons[i] = other.reasons[k]
        return hit


@dataclass(frozen=True)
class Fallbacks:
    """What a detector tries where the board is not found at first: a value passed per call, so that each look of
    the calibration pipeline says which of the detector's fallbacks it pays for.

    Attributes:
        primary: the level the square-size estimate picks (``False``: only the other levels, for a second pass).
        levels: relative factors of the levels tried in turn where the board was not found at that level.
        finest: with ``levels``, then also the octaves below the finest of them and the finest level allowed.
        opencv: then OpenCV's corner candidates on a bounded level (boards with marks in the white squares).
        foreshortened: then the level compressed along a few directions (boards at a grazing angle).
        copies: last, where no board was found, the same looks (the grazing angle's included) on the image's enhanced
            copies that suit it (:func:`~ccs_kornia.modules.detection.learned.learned_detector.chessboard_copies`:
            dim or small views).

    Example:
        >>> own = Fallbacks(levels=(0.5, 2.0, 0.25))
        >>> own.but(levels=(0.5,), opencv=False)
        Fallbacks(primary=True, levels=(0.5,), finest=True, opencv=False, foreshortened=True, copies=True)
    """

    primary: bool = True
    levels: tuple[float, ...] = (0.5, 2.0, 0.25)
    finest: bool = True
    opencv: bool = True
    foreshortened: bool = True
    copies: bool = True

    def but(self, **changes: Any) -> "Fallbacks":
        """A copy with ``changes``."""
        return dataclasses.replace(self, **changes)

    @property
    def empty(self) -> bool:
        """Nothing to try: neither the first level nor any fallback (``finest`` counts only with ``levels``)."""
        return not (self.primary or self.levels or self.opencv or self.foreshortened or self.copies)


class ChessboardDetector(nn.Module):
    """Interface: ``forward(images (B,1,H,W) in [0,1], board_size (cols, rows)) -> DetectionResult``.

    What a detector can do is declared here, with the answer of a plain detector, and overridden by a detector that
    does more; callers read these and never probe for attributes:

    * :attr:`fallbacks`: a detector with fallbacks to choose from sets its own and takes ``fallbacks=`` in
      ``forward`` (:meth:`detect`); one whose own include ``foreshortened`` implements :meth:`foreshortened`;
    * :attr:`selects_scale`: it picks its own detection level (callers need not downscale large images);
    * :attr:`board`: the board whose object points the solver takes;
    * :attr:`lens_correction`: the distortion network's correction may be judged on its images;
    * for the differentiable corners (:mod:`~ccs_kornia.modules.detection.refine.differentiable_refine`):
      :attr:`heatmap_net`, :attr:`fit_window`, :attr:`refines_on_image` and :meth:`detection_factor`.
    """

    #: the detector's own :class:`Fallbacks` (``None``: it has none to choose)
    fallbacks: Fallbacks | None = None
    #: it picks its own detection level and refines at full resolution: callers need not downscale large images
    selects_scale: bool = False
    #: the board description whose object points the solver takes (:mod:`~ccs_kornia.modules.detection.boards`, e.g.
    #: an AprilGrid, whose corners are not evenly spaced); ``None``: a chessboard of unit squares
    board: Any = None
    #: the distortion network (trained on boards of squares) may judge the lens from its images and boards; ``False``
    #: for boards it never saw (a circle grid), whose corrections it does not predict
    lens_correction: bool = True
    #: odd window of the Gaussian fit that seeds a corner from the heatmap (with a :attr:`heatmap_net`)
    fit_window: int = 7

    @property
    def heatmap_net(self) -> nn.Module | None:
        """The network whose corner heatmap seeds the differentiable corners (``None``: none)."""
        return None

    @property
    def refines_on_image(self) -> bool:
        """Its corners are refined on the image (the differentiable corners then run the refinement steps too)."""
        return True

    def detection_factor(self, images: torch.Tensor) -> torch.Tensor | float:
        """Full-resolution px per detection-level px of each image :math:`(B, 1, H, W)`: :math:`(B,)` or a number (1:
        the detector sees the images as they are)."""
        return 1.0

    def detect(self, images: torch.Tensor, board_size: tuple[int, int],
               fallbacks: Fallbacks | None = None) -> DetectionResult:
        """``forward`` with ``fallbacks`` (``None``, or a detector without its own: what ``forward`` does alone)."""
        if self.fallbacks is None or fallbacks is None:
            return self(images, board_size)
        return self(images, board_size, fallbacks=fallbacks)

    def forward(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:  # pragma: no cover
        raise NotImplementedError

    def foreshortened(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Only the last resort for boards at a grazing angle (``Fallbacks.foreshortened``), for a detector whose own
        :attr:`fallbacks` include it."""
        raise NotImplementedError(f"{type(self).__name__} has no last resort for boards at a grazing angle.")

    @staticmethod
    def _check_inputs(images: torch.Tensor, board_size: tuple[int, int]) -> tuple[int, int]:
        check_grey_images(images, min_side=0)
        return check_board_size(board_size)
