"""Detection on radially corrected images, and how much straighter a correction makes the detected boards.

The paper corrects the images first so that the detector sees straight lines (Sec. III-A). The pipeline
(:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline`) looks for the board on the images as they are first, and only
for the views missed there does it warp the image by the camera's pooled correction and look again
(:func:`detect_on_corrected`): a normal lens is never resampled, and a strongly distorted one still gets the
straightened copy where it needs it. :func:`straightening_evidence` measures what the correction does to the
detected boards (reported with every calibration): under a pinhole camera every row and column of a board is
straight, so a correction that really removes the lens's distortion makes them straighter, and one that misfires
(an undistorted lens) bends them. It no longer decides whether the corrected frame is tried (the observed corners
referee that calibration): on held-out strongly distorted cameras the network's correction did not always
straighten the boards where the corrected frame was the only calibration that recovered them
(``docs/measurements.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from ccs_kornia.modules.correction.radial_warp import (
    correct_points,
    correction_zoom,
    distort_points_from_correction,
    radial_undistort_image,
)
from ccs_kornia.modules.correction.straightness import straightness_rms
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.warps.warped_detection import Warp, detect_warped

__all__ = ["CorrectedCopy", "detect_on_corrected", "straightening_evidence"]


@dataclass(frozen=True)
class CorrectedCopy(Warp):
    """The images radially corrected by ``correction`` :math:`(B, 5)` (paper coefficients) of images ``size``
    ``(W, H)``, with the zoom that keeps the whole original frame in view; pixels map back through the correction.

    Example:
        >>> warp = CorrectedCopy.of(torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]]), (64, 48))
        >>> warp.apply(torch.rand(1, 1, 48, 64)).shape, warp.back(torch.tensor([[[10.0, 20.0]]]))[1].tolist()
        (torch.Size([1, 1, 48, 64]), [True])
    """

    correction: torch.Tensor
    size: tuple[int, int]
    zoom: float

    @staticmethod
    def of(correction: torch.Tensor, size: tuple[int, int]) -> "CorrectedCopy":
        """The copies corrected by ``correction`` :math:`(B, 5)` float64 of images ``size`` ``(W, H)``."""
        corr = correction.to(torch.float64)
        return CorrectedCopy(corr, size, float(correction_zoom(corr, size)))

    def apply(self, images: torch.Tensor) -> torch.Tensor:
        corr = self.correction.to(images.device).float()
        return radial_undistort_image(images.float(), corr, zoom=self.zoom).clamp(0, 1)

    def back(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        back, ok = distort_points_from_correction(points.double(), self.correction.to(points.device), self.size,
                                                  zoom=self.zoom, return_valid=True)
        return back, ok.all(-1) & back.isfinite().all(-1).all(-1)


def detect_on_corrected(
    detect: Callable[[torch.Tensor, tuple[int, int]], DetectionResult],
    refine: Callable[[torch.Tensor, torch.Tensor, tuple[int, int]], torch.Tensor],
    images: torch.Tensor,
    correction: torch.Tensor,
    board_size: tuple[int, int],
    measure: Callable[[torch.Tensor, torch.Tensor, tuple[int, int]], torch.Tensor] | None = None,
) -> DetectionResult:
    """Detect the board on radially corrected copies of ``images``; corners in the original images.

    The copies are warped with the zoom that keeps the whole original frame in view (:class:`CorrectedCopy`), the
    corners found there are mapped back through the correction, and then refined on the original images (the copies
    are interpolated): :func:`~ccs_kornia.modules.detection.warps.warped_detection.detect_warped`.

    Args:
        detect: a detector call ``(images (B,1,H,W), board_size) -> DetectionResult``.
        refine: ``(images (B,1,H,W), corners (B,N,2), board_size) -> refined corners (B,N,2)`` on the originals.
        images: :math:`(B, 1, H, W)` float in ``[0, 1]``.
        correction: :math:`(5,)` or :math:`(B, 5)` paper correction coefficients.
        board_size: ``(cols, rows)``.
        measure: ``(images, corners, board_size) -> sigma (b, N)``, the corners' precision on the originals.

    Returns:
        :class:`DetectionResult`: corners :math:`(B, N, 2)` in the original images, found :math:`(B,)`,
        reasons prefixed with ``"corrected image: "``, ``sigma`` with ``measure``.

    Example:
        >>> from ccs_kornia.modules.detection.factory import make_detector
        >>> det = make_detector("opencv")
        >>> out = detect_on_corrected(det, lambda i, c, b: c, torch.zeros(1, 1, 48, 64), torch.tensor([1.0, 0, 0, 0, 0]),
        ...                           (4, 3))
        >>> out.corners.shape, bool(out.found[0])
        (torch.Size([1, 12, 2]), False)
    """
    b, _, h, w = images.shape
    corr = correction.to(device=images.device, dtype=torch.float64)
    warp = CorrectedCopy.of(corr.expand(b, 5) if corr.dim() == 1 else corr, (int(w), int(h)))
    out = detect_warped(warp, detect, refine, images, board_size, measure)
    out.reasons = [
        "corrected image: " + ((out.reasons[k] if out.reasons else "found") if f else "board not found")
        for k, f in enumerate(out.found.tolist())
    ]
    return out


def straightening_evidence(
    corners: torch.Tensor,
    found: torch.Tensor,
    correction: torch.Tensor,
    board_size: tuple[int, int],
    image_size: tuple[int, int],
) -> tuple[torch.Tensor, torch.Tensor]:
    """How straight the detected rows and columns are before and after a correction, per camera.

    Args:
        corners: :math:`(C, V, N, 2)` corners detected on the original images; found: :math:`(C, V)`.
        correction: :math:`(C, 5)` the camera's pooled correction.
        board_size: ``(cols, rows)``; image_size: ``(W, H)``.

    Returns:
        ``(before, after)`` :math:`(C,)`: median over the camera's found views of the RMS distance (px) of the
        corners from lines fitted to each row and column, as detected and after the correction (NaN for a camera
        without a found view).

    Example:
        >>> xy = torch.stack(torch.meshgrid(torch.arange(4.) * 20 + 10, torch.arange(3.) * 20 + 8, indexing="xy"), -1)
        >>> c = xy.reshape(1, 1, 12, 2).double()
        >>> before, after = straightening_evidence(c, torch.ones(1, 1, dtype=torch.bool),
        ...                                        torch.tensor([[1.0, 0, 0.5, 0, 0]]).double(), (4, 3), (96, 64))
        >>> float(before) < 1e-6, float(after) > float(before)
        (True, True)
    """
    c, v, n = corners.shape[:3]
    flat = corners.reshape(c, v * n, 2).double()
    corrected = correct_points(flat, correction.to(flat), image_size).reshape(c * v, n, 2)
    valid = torch.ones(c * v, n, dtype=torch.bool, device=corners.device)
    before, _ = straightness_rms(flat.reshape(c * v, n, 2), valid, board_size)
    after, _ = straightness_rms(corrected, valid, board_size)
    mask = found.reshape(c * v).to(corners.device)
    nan = torch.full_like(before, float("nan"))
    before = torch.where(mask, before, nan).reshape(c, v).nanmedian(1).values
    after = torch.where(mask, after, nan).reshape(c, v).nanmedian(1).values
    return before, after
