"""Chessboard images in, camera calibration out: the composed inference pipeline.

:class:`CalibrationPipeline` chains a :class:`~ccs_kornia.modules.detector.ChessboardDetector` (the
learned heatmap detector or the OpenCV baseline) and the
:class:`~ccs_kornia.modules.calibrator.CalibrationSolver` (homographies, Zhang initialisation,
image-level RANSAC, joint Levenberg-Marquardt refinement). Each stage is usable alone
(:meth:`CalibrationPipeline.detect`, :meth:`CalibrationPipeline.calibrate`), which is how the
command line streams large image sets: detect batch by batch, then solve once.

Many cameras are calibrated in one call by stacking their views: images ``(C, V, 1, H, W)``.
This module imports neither the command line nor Lightning.

Large images (longer side above ``max_detection_side``, 2048 px by default) are detected on an
area-downscaled copy; the corners are mapped back to full resolution and refined there on a small
patch around each corner (:func:`~ccs_kornia.modules.corner_refine.refine_corners`). The OpenCV detector
takes about a minute on a blank 6000x4000 image and far longer on textured ones, so full-resolution
detection of 24 Mpx photographs is not a usable default; the refinement keeps their sub-pixel
precision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ccs_kornia.camera import board_object_points
from ccs_kornia.modules.calibrator import CalibrationResult, CalibrationSolver
from ccs_kornia.modules.corner_refine import CornerRefiner, grid_spacing, refine_corners
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

    # shortcuts to the tensors most callers want
    @property
    def K(self) -> torch.Tensor:
        """Camera matrices :math:`(3, 3)` / :math:`(C, 3, 3)` (NaN where the calibration failed)."""
        return self.calibration.K

    @property
    def dist(self) -> torch.Tensor:
        """Distortion coefficients in OpenCV order :math:`(D,)` / :math:`(C, D)`."""
        return self.calibration.dist

    @property
    def rvec(self) -> torch.Tensor:
        """World-to-camera rotations (axis-angle) :math:`(V, 3)` / :math:`(C, V, 3)`."""
        return self.calibration.rvec

    @property
    def tvec(self) -> torch.Tensor:
        """World-to-camera translations :math:`(V, 3)` / :math:`(C, V, 3)` in units of ``square``."""
        return self.calibration.tvec

    @property
    def view_rms(self) -> torch.Tensor:
        """Per-view RMS reprojection error in px :math:`(V,)` / :math:`(C, V)`, NaN for unused views."""
        return self.calibration.view_rms

    @property
    def used(self) -> torch.Tensor:
        """Views used by the final refinement :math:`(V,)` / :math:`(C, V)` bool."""
        return self.calibration.used

    @property
    def found(self) -> torch.Tensor:
        """Views where the board was detected :math:`(V,)` / :math:`(C, V)` bool."""
        return self.detections.found

    @property
    def rms(self) -> torch.Tensor:
        """Overall RMS reprojection error in px, scalar / :math:`(C,)`."""
        return self.calibration.rms

    @property
    def std(self) -> torch.Tensor:
        """Standard deviations of ``(fx, fy, cx, cy, *dist)`` :math:`(4 + D,)` / :math:`(C, 4 + D)`."""
        return torch.cat([self.calibration.std_intrinsics, self.calibration.std_dist], -1)


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
        max_detection_side: images whose longer side exceeds this are detected on a downscaled copy
            and refined at full resolution (``None`` or 0: always detect at full resolution).
        solver_kwargs: further options of :class:`~ccs_kornia.modules.calibrator.CalibrationSolver`
            (e.g. ``fix_aspect_ratio=True``).

    Example:
        >>> from ccs_kornia.data.synthetic import make_calibration_set
        >>> K = torch.tensor([[600., 0, 320], [0, 600, 240], [0, 0, 1]], dtype=torch.float64)
        >>> views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=6, seed=1)
        >>> out = CalibrationPipeline("opencv")(views.images, (9, 6), 0.025)  # doctest: +SKIP
        >>> out.K.shape, out.found.shape, out.view_rms.shape  # doctest: +SKIP
        (torch.Size([3, 3]), torch.Size([6]), torch.Size([6]))
    """

    def __init__(
        self,
        detector: str | ChessboardDetector = "learned",
        model: str = "opencv5",
        use_ransac: bool = True,
        seed: int = 0,
        detection_batch_size: int = 16,
        max_detection_side: int | None = 2048,
        **solver_kwargs,
    ) -> None:
        super().__init__()
        self.detector = make_detector(detector) if isinstance(detector, str) else detector
        if not isinstance(self.detector, ChessboardDetector):
            raise ValueError(f"detector must be a name or a ChessboardDetector, got {type(detector).__name__}.")
        if detection_batch_size < 1:
            raise ValueError(f"detection_batch_size must be >= 1, got {detection_batch_size}.")
        self.solver = CalibrationSolver(model=model, use_ransac=use_ransac, seed=seed, **solver_kwargs)
        if max_detection_side is not None and max_detection_side != 0 and max_detection_side < 64:
            raise ValueError(f"max_detection_side must be >= 64 (or None/0 to disable), got {max_detection_side}.")
        self.model = model
        self.detection_batch_size = detection_batch_size
        self.max_detection_side = int(max_detection_side) if max_detection_side else None
        self.refiner = CornerRefiner()

    def _detect_chunk(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Detect on ``(B, 1, H, W)``, through a downscaled copy when the images are large."""
        h, w = images.shape[-2:]
        limit = self.max_detection_side
        if limit is None or max(h, w) <= limit:
            return self.detector(images, board_size)
        scale = max(h, w) / limit
        small_size = (max(8, round(h / scale)), max(8, round(w / scale)))
        # area averaging is the anti-aliased downscale (each small pixel is the mean of its footprint)
        small = F.interpolate(images.float(), size=small_size, mode="area")
        det = self.detector(small, board_size)
        # pixel centres: x_full + 0.5 = (x_small + 0.5) * w / w_small
        factor = torch.tensor([w / small_size[1], h / small_size[0]], dtype=det.corners.dtype, device=det.corners.device)
        corners = (det.corners + 0.5) * factor - 0.5
        refined = corners.clone()
        found = det.found.nonzero().flatten()
        if found.numel():
            refined[found] = self._refine_full_resolution(images, corners[found], found, board_size)
        return DetectionResult(refined, det.found, det.reasons)

    def _refine_full_resolution(
        self, images: torch.Tensor, corners: torch.Tensor, index: torch.Tensor, board_size: tuple[int, int]
    ) -> torch.Tensor:
        """Refine corners :math:`(S, N, 2)` of ``images[index]`` on small patches around each corner.

        The refiner smooths and normalises the whole image it is given; on a 24 Mpx photo that alone
        costs seconds, so every corner gets its own patch (window + smoothing margin) and all patches
        are refined in one batch.
        """
        r = self.refiner
        h, w = images.shape[-2:]
        half = int(math.ceil(r.max_radius + 3 * max(r.normalize_sigma, r.smooth_sigma) + 4))
        s, n = corners.shape[:2]
        offsets = torch.arange(-half, half + 1, device=images.device)
        origin = corners.detach().round().long().to(images.device)  # (S, N, 2) patch centres
        ys = (origin[..., 1, None] + offsets).clamp(0, h - 1)  # (S, N, P), replicate at image borders
        xs = (origin[..., 0, None] + offsets).clamp(0, w - 1)
        patches = images[index.to(images.device)[:, None, None, None], 0, ys[..., :, None], xs[..., None, :]]
        size = 2 * half + 1
        local = (corners - (origin.to(corners) - half)).reshape(s * n, 1, 2)
        valid = torch.ones(s, n, dtype=torch.bool, device=corners.device)
        radius = (r.radius_factor * grid_spacing(corners, valid, board_size)).reshape(s * n, 1)
        out = refine_corners(
            patches.reshape(s * n, 1, size, size).float(), local, None, radius, r.method, r.iterations, r.max_radius,
            r.smooth_sigma, r.normalize_sigma,
        )
        return out.reshape(s, n, 2) + (origin.to(corners) - half)

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
                self._detect_chunk(flat[i : i + self.detection_batch_size], board_size)
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
