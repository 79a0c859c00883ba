"""Chessboard images in, camera calibration out: the composed inference pipeline.

:class:`CalibrationPipeline` chains a :class:`~ccs_kornia.modules.detector.ChessboardDetector` (the
learned heatmap detector or the OpenCV baseline) and the
:class:`~ccs_kornia.modules.calibrator.CalibrationSolver` (homographies, Zhang initialisation,
image-level RANSAC, joint Levenberg-Marquardt refinement). Each stage is usable alone
(:meth:`CalibrationPipeline.detect`, :meth:`CalibrationPipeline.calibrate`), which is how the
command line streams large image sets: detect batch by batch, then solve once.

Many cameras are calibrated in one call by stacking their views: images ``(C, V, 1, H, W)``.
This module imports neither the command line nor Lightning.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ccs_kornia.camera import board_object_points
from ccs_kornia.modules.calibrator import CalibrationResult, CalibrationSolver
from ccs_kornia.modules.detector import ChessboardDetector, DetectionResult, make_detector

__all__ = ["PipelineResult", "CalibrationPipeline"]


@dataclass
class PipelineResult:
    """Detections and calibration of one pipeline call.

    Attributes:
        detections: corners :math:`(V, N, 2)` / :math:`(C, V, N, 2)` and found :math:`(V,)` /
            :math:`(C, V)`.
        calibration: the solver's :class:`~ccs_kornia.modules.calibrator.CalibrationResult`
            (camera dimension squeezed away for unbatched input).
    """

    detections: DetectionResult
    calibration: CalibrationResult


class CalibrationPipeline(nn.Module):
    """Detect chessboard corners and calibrate the camera(s).

    Args:
        detector: a detector name for :func:`~ccs_kornia.modules.detector.make_detector`
            (``"opencv"`` or ``"learned"``) or a :class:`ChessboardDetector` instance.
        model: output distortion model: ``opencv5`` (k1, k2, p1, p2, k3), ``k1k2``, ``rational`` or
            ``none``.
        use_ransac: reject inconsistent views with image-level RANSAC before the refinement.
        seed: seed of the RANSAC sampling (results are deterministic for a given seed).
        detection_batch_size: most images handed to the detector at once (bounds memory of the
            learned detector; the OpenCV detector works image by image anyway).
        solver_kwargs: further options of :class:`~ccs_kornia.modules.calibrator.CalibrationSolver`
            (e.g. ``fix_aspect_ratio=True``).

    Example:
        >>> pipe = CalibrationPipeline("opencv", model="opencv5")
        >>> out = pipe(images, (9, 6), 0.025)  # doctest: +SKIP
        >>> out.calibration.K.shape, out.detections.found.shape  # doctest: +SKIP
        (torch.Size([3, 3]), torch.Size([15]))
    """

    def __init__(
        self,
        detector: str | ChessboardDetector = "opencv",
        model: str = "opencv5",
        use_ransac: bool = True,
        seed: int = 0,
        detection_batch_size: int = 16,
        **solver_kwargs,
    ) -> None:
        super().__init__()
        self.detector = make_detector(detector) if isinstance(detector, str) else detector
        if not isinstance(self.detector, ChessboardDetector):
            raise ValueError(f"detector must be a name or a ChessboardDetector, got {type(detector).__name__}.")
        if detection_batch_size < 1:
            raise ValueError(f"detection_batch_size must be >= 1, got {detection_batch_size}.")
        self.solver = CalibrationSolver(model=model, use_ransac=use_ransac, seed=seed, **solver_kwargs)
        self.model = model
        self.detection_batch_size = detection_batch_size

    def detect(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Detect the board on every image.

        Args:
            images: :math:`(V, 1, H, W)` or :math:`(C, V, 1, H, W)` float in ``[0, 1]``.
            board_size: ``(cols, rows)`` inner corners.

        Returns:
            :class:`DetectionResult` with the leading dimensions of ``images``.
        """
        if not isinstance(images, torch.Tensor) or images.dim() not in (4, 5) or images.shape[-3] != 1:
            shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
            raise ValueError(f"Expected grey images (V, 1, H, W) or (C, V, 1, H, W), got {shape}.")
        lead = images.shape[:-3]
        flat = images.reshape(-1, *images.shape[-3:])
        with torch.inference_mode():
            parts = [
                self.detector(flat[i : i + self.detection_batch_size], board_size)
                for i in range(0, flat.shape[0], self.detection_batch_size)
            ]
        corners = torch.cat([p.corners for p in parts])
        found = torch.cat([p.found for p in parts])
        reasons = None
        if all(p.reasons is not None for p in parts):
            reasons = [r for p in parts for r in p.reasons]  # type: ignore[union-attr]
        return DetectionResult(corners.reshape(*lead, *corners.shape[1:]), found.reshape(lead), reasons)

    def calibrate(
        self,
        corners: torch.Tensor,
        valid: torch.Tensor,
        board_size: tuple[int, int],
        square: float,
        image_size: tuple[int, int],
    ) -> CalibrationResult:
        """Calibrate from detected corners (the solver stage alone).

        Args:
            corners: :math:`(V, N, 2)` or :math:`(C, V, N, 2)` pixels in grid order.
            valid: :math:`(V, N)` / :math:`(C, V, N)` bool, or per view :math:`(V,)` / :math:`(C, V)`.
            board_size: ``(cols, rows)``; ``N = cols * rows``.
            square: square side in world units (scales the translations only).
            image_size: ``(W, H)``.

        Returns:
            The solver's :class:`~ccs_kornia.modules.calibrator.CalibrationResult`.
        """
        cols, rows = int(board_size[0]), int(board_size[1])
        if corners.dim() not in (3, 4) or corners.shape[-1] != 2 or corners.shape[-2] != cols * rows:
            raise ValueError(
                f"Expected corners (V, {cols * rows}, 2) or (C, V, {cols * rows}, 2) for a {cols}x{rows} board, "
                f"got {tuple(corners.shape)}."
            )
        if valid.shape == corners.shape[:-2]:
            valid = valid[..., None].expand(corners.shape[:-1])
        if valid.shape != corners.shape[:-1]:
            raise ValueError(f"valid must have shape {tuple(corners.shape[:-1])}, got {tuple(valid.shape)}.")
        if not square > 0:
            raise ValueError(f"square must be positive, got {square}.")
        object_points = board_object_points(cols, rows, float(square), device=corners.device, dtype=torch.float64)
        with torch.inference_mode():
            return self.solver(corners.to(torch.float64), valid.bool(), object_points, (int(image_size[0]), int(image_size[1])))

    def forward(self, images: torch.Tensor, board_size: tuple[int, int], square: float = 1.0) -> PipelineResult:
        """Detect and calibrate.

        Args:
            images: :math:`(V, 1, H, W)` (one camera) or :math:`(C, V, 1, H, W)` (``C`` cameras of
                one image size) float in ``[0, 1]``.
            board_size: ``(cols, rows)`` inner corners.
            square: square side in world units.

        Returns:
            :class:`PipelineResult`.
        """
        detections = self.detect(images, board_size)
        image_size = (int(images.shape[-1]), int(images.shape[-2]))
        calibration = self.calibrate(detections.corners, detections.valid, board_size, square, image_size)
        return PipelineResult(detections, calibration)
