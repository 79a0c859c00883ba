"""Detection on a warped copy of the images, corners mapped back exactly and refined on the images themselves.

Every second look of the calibration pipeline is this one routine with its own warp: the area-downscaled copy of a
large image, the copy straightened by the network's pooled correction
(:class:`~ccs_kornia.modules.detection.warps.corrected_copy.CorrectedCopy`), a virtual pinhole view of a calibrated
lens (:class:`~ccs_kornia.modules.detection.warps.virtual_view.VirtualView`). A :class:`Warp` makes the copy and
maps its pixels back; :func:`detect_warped` runs warp -> detect -> map back -> refine at full resolution -> the
corners' precision, and :func:`map_back` is its second half for callers that detect the copies elsewhere (in worker
processes). :func:`detect_images` is the first look at images as they are: the detector on them, or through a
downscaled copy where they are large.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import torch
import torch.nn.functional as F

from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    Fallbacks,
    image_rows,
)
from ccs_kornia.modules.detection.refine.patch_refine import level_size, resize_to_level

__all__ = ["Warp", "Downscale", "Level", "detect_images", "detect_warped", "map_back"]

#: ``refine(images (B, 1, H, W), corners (B, N, 2), board_size) -> corners``: a refinement on the original images
Refine = Callable[[torch.Tensor, torch.Tensor, tuple[int, int]], torch.Tensor]


class Warp:
    """An image warp with an exact map back: :meth:`apply` makes the copies, :meth:`back` maps their pixels back."""

    def apply(self, images: torch.Tensor) -> torch.Tensor:  # pragma: no cover - interface
        """The warped copies :math:`(B, 1, h, w)` of ``images`` :math:`(B, 1, H, W)`."""
        raise NotImplementedError

    def back(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover - interface
        """Points :math:`(B, N, 2)` of the copies in the original images, and :math:`(B,)` whether all of them map
        back (inside the image, finite)."""
        raise NotImplementedError


@dataclass(frozen=True)
class Downscale(Warp):
    """Area-averaged downscale to ``size`` ``(h, w)`` of images ``full`` ``(H, W)`` (the anti-aliased copy: each small
    pixel is the mean of its footprint); pixel centres map as ``x_full + 0.5 = (x_small + 0.5) * W / w``.

    Example:
        >>> warp = Downscale((24, 32), (48, 64))
        >>> warp.apply(torch.rand(2, 1, 48, 64)).shape, warp.back(torch.tensor([[[0.0, 0.0]]]))[0].tolist()
        (torch.Size([2, 1, 24, 32]), [[[0.5, 0.5]]])
    """

    size: tuple[int, int]
    full: tuple[int, int]

    @staticmethod
    def to_side(full: tuple[int, int], side: int) -> "Downscale":
        """The copy of images ``full`` ``(H, W)`` whose longer side is ``side``."""
        h, w = full
        scale = max(h, w) / side
        return Downscale((max(8, round(h / scale)), max(8, round(w / scale))), (h, w))

    def apply(self, images: torch.Tensor) -> torch.Tensor:
        return F.interpolate(images.float(), size=self.size, mode="area")

    def back(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        factor = torch.tensor([self.full[1] / self.size[1], self.full[0] / self.size[0]], dtype=points.dtype,
                              device=points.device)
        ok = torch.ones(points.shape[0], dtype=torch.bool, device=points.device)
        return (points + 0.5) * factor - 0.5, ok


@dataclass(frozen=True)
class Level(Warp):
    """The learned detector's pyramid level ``factor`` (full-resolution px per level px) of images ``full``
    ``(H, W)``: :func:`~ccs_kornia.modules.detection.refine.patch_refine.resize_to_level` (area-averaged down, bilinear up);
    pixel centres map as ``x_full + 0.5 = (x_level + 0.5) * scale``.

    Example:
        >>> warp = Level(4.0, (48, 64))
        >>> warp.apply(torch.rand(2, 1, 48, 64)).shape, warp.back(torch.tensor([[[0.0, 0.0]]]))[0].tolist()
        (torch.Size([2, 1, 12, 16]), [[[1.5, 1.5]]])
    """

    factor: float
    full: tuple[int, int]

    @property
    def size(self) -> tuple[int, int]:
        """``(h, w)`` of the level."""
        return level_size((self.full[1], self.full[0]), self.factor)

    @property
    def resamples(self) -> bool:
        """Whether the level differs from the images themselves."""
        return self.size != tuple(self.full)

    def scale(self, device: torch.device | str | None = None) -> torch.Tensor:
        """``(sx, sy)`` :math:`(2,)` float64: full-resolution px per level px along x and y."""
        h, w = self.size
        return torch.tensor([self.full[1] / w, self.full[0] / h], dtype=torch.float64, device=device)

    @property
    def coarseness(self) -> float:
        """Full-resolution px per level px, the larger of x and y (where a refinement from the level starts)."""
        return float(self.scale().max())

    def apply(self, images: torch.Tensor) -> torch.Tensor:
        return resize_to_level(images, self.factor)[0]

    def back(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        ok = torch.ones(points.shape[0], dtype=torch.bool, device=points.device)
        return ((points.double() + 0.5) * self.scale(points.device) - 0.5).to(points.dtype), ok


def map_back(warp: Warp, det: DetectionResult, refine: Refine, images: torch.Tensor, board_size: tuple[int, int],
             measure: Refine | None = None) -> DetectionResult:
    """The boards ``det`` found on ``warp``'s copies of ``images`` :math:`(B, 1, H, W)`, in the images: mapped back
    (a board with a corner that does not map back is dropped), refined there by ``refine``, their precision measured
    there by ``measure`` (``(images, corners, board_size) -> (b, N)``; ``None``: no ``sigma``).

    Returns:
        :class:`DetectionResult`: float32 corners :math:`(B, N, 2)` (zeros where not found), found :math:`(B,)`,
        ``det``'s reasons, ``sigma`` :math:`(B, N)` (NaN where not found) with ``measure``.
    """
    back, ok = warp.back(det.corners)
    found = det.found.to(ok.device) & ok
    b, n = det.corners.shape[:2]
    corners = torch.zeros(b, n, 2, dtype=torch.float32, device=images.device)
    sigma = None if measure is None else torch.full((b, n), float("nan"), dtype=torch.float32, device=images.device)
    sel = found.nonzero().flatten().to(images.device)
    if sel.numel():
        with torch.inference_mode():
            rows = image_rows(images, sel)
            corners[sel] = refine(rows.float(), back[sel].float(), board_size).float()
            if measure is not None:
                sigma[sel] = measure(rows, corners[sel], board_size).to(sigma)
    return DetectionResult(corners, found.to(images.device), det.reasons, sigma)


def detect_warped(warp: Warp, detect: Callable[[torch.Tensor, tuple[int, int]], DetectionResult], refine: Refine,
                  images: torch.Tensor, board_size: tuple[int, int], measure: Refine | None = None) -> DetectionResult:
    """Warp -> detect -> map back -> refine -> precision: ``detect`` on ``warp.apply(images)``, then :func:`map_back`.

    Args:
        warp: the copy and its map back.
        detect: a detector call ``(images (B,1,h,w), board_size) -> DetectionResult``.
        refine: ``(images (B,1,H,W), corners (B,N,2), board_size) -> corners`` on the original images.
        images: :math:`(B, 1, H, W)` float in ``[0, 1]``.
        board_size: ``(cols, rows)``.
        measure: ``(images, corners, board_size) -> sigma (B, N)`` on the original images (``None``: not measured).

    Returns:
        :class:`DetectionResult` in the original images (see :func:`map_back`).

    Example:
        >>> from ccs_kornia.modules.detection.factory import make_detector
        >>> out = detect_warped(Downscale((24, 32), (48, 64)), make_detector("opencv"), lambda i, c, b: c,
        ...                     torch.zeros(1, 1, 48, 64), (4, 3))
        >>> out.corners.shape, bool(out.found[0])
        (torch.Size([1, 12, 2]), False)
    """
    with torch.inference_mode():
        warped = warp.apply(images)
    return map_back(warp, detect(warped, board_size), refine, images, board_size, measure)


def detect_images(images: torch.Tensor, board_size: tuple[int, int], fallbacks: Fallbacks | None = None, *,
                  detector: ChessboardDetector, max_side: int | None, refine: Refine,
                  measure: Refine | None = None) -> DetectionResult:
    """The detector on images :math:`(B, 1, H, W)` of one size as they are, with ``fallbacks`` (``None``: the
    detector's own); images whose longer side exceeds ``max_side`` through a downscaled copy (:class:`Downscale`,
    :func:`detect_warped`: refined by ``refine`` at full resolution), unless the detector picks its own detection
    level (``selects_scale``: it bounds its memory itself). ``measure``: the corners' precision
    (``(images, corners, board_size, found) -> sigma (B, N)``), taken from the detector where it measured it on these
    images (``None``: not measured).

    Example:
        >>> from ccs_kornia.modules.detection.factory import make_detector
        >>> out = detect_images(torch.zeros(2, 1, 96, 128), (4, 3), detector=make_detector("opencv"), max_side=64,
        ...                     refine=lambda i, c, b: c)
        >>> out.corners.shape, out.found.tolist(), out.sigma
        (torch.Size([2, 12, 2]), [False, False], None)
    """
    h, w = images.shape[-2:]
    with torch.inference_mode():
        if max_side is None or max(h, w) <= max_side or detector.selects_scale:
            det = detector.detect(images.float(), board_size, fallbacks)
            sigma = None
            if measure is not None:
                # the learned detector has measured them on these images (its asymmetry check)
                sigma = det.sigma
                if sigma is None:
                    sigma = measure(images, det.corners, board_size, det.found)
            return DetectionResult(det.corners, det.found, det.reasons, sigma)
        detect = functools.partial(detector.detect, fallbacks=fallbacks)
        return detect_warped(Downscale.to_side((h, w), max_side), detect, refine, images, board_size, measure)
