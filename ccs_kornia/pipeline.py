"""Chessboard images in, camera calibration out: the composed inference pipeline.

:class:`CalibrationPipeline` chains a :class:`~ccs_kornia.modules.detection.base.ChessboardDetector` (the
learned heatmap detector or the OpenCV baseline) and the
:class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` (homographies, Zhang initialisation,
image-level RANSAC, joint Levenberg-Marquardt refinement). Each stage is usable alone
(:meth:`CalibrationPipeline.detect`, :meth:`CalibrationPipeline.calibrate`), which is how the
command line streams large image sets: detect batch by batch, then solve once.

Many cameras are calibrated in one call by stacking their views: images ``(C, V, 1, H, W)``.
This module imports neither the command line nor Lightning.

Large images (longer side above ``max_detection_side``, 2048 px by default) are detected on an
area-downscaled copy; the corners are mapped back to full resolution and refined there on a small
patch around each corner (:func:`~ccs_kornia.modules.detection.saddle_refine.refine_corners`). The OpenCV detector
takes about a minute on a blank 6000x4000 image and far longer on textured ones, so full-resolution
detection of 24 Mpx photographs is not a usable default; the refinement keeps their sub-pixel
precision.

Distortion correction (paper Sec. III-A, on by default): the
:class:`~ccs_kornia.modules.correction.distortion_net.DistortionNet` predicts a radial correction per view, pooled
into one per camera (:mod:`~ccs_kornia.modules.correction.pooling`). Where it moves pixels by more than
``min_correction`` of the half diagonal, the images are corrected
(:func:`~ccs_kornia.modules.correction.radial_warp.radial_undistort_image`), the board is detected in the corrected
images, the corners are mapped back to the original images (boards missed there are looked for in the originals)
and polished there; the camera is then calibrated in the corrected frame
(:mod:`~ccs_kornia.modules.correction.corrected_frame`), kept unless it fits the observed corners clearly worse
than the usual joint calibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ccs_kornia.camera import board_object_points
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.correction import corrected_frame
from ccs_kornia.modules.correction.distortion_net import load_distortion_net
from ccs_kornia.modules.correction.pooling import aggregate_corrections, correction_displacement
from ccs_kornia.modules.correction.radial_warp import distort_points_from_correction, radial_undistort_image
from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.saddle_refine import CornerRefiner, grid_spacing, refine_corners

__all__ = ["PipelineResult", "CalibrationPipeline"]


@dataclass
class PipelineResult:
    """Detections and calibration of one pipeline call.

    Attributes:
        detections: corners :math:`(V, N, 2)` / :math:`(C, V, N, 2)` and found :math:`(V,)` /
            :math:`(C, V)`.
        calibration: the solver's :class:`~ccs_kornia.modules.calibration.result.CalibrationResult`
            (camera dimension squeezed away for unbatched input).
        correction: the radial correction per camera :math:`(5,)` / :math:`(C, 5)`: the network's pooled
            prediction, or the refined one where the camera was calibrated in the corrected frame (``None`` when
            distortion correction is off).
        corrected: per camera, whether the correction was applied (images corrected for detection and the
            camera calibrated in the corrected frame; bool, ``None`` when off).
    """

    detections: DetectionResult
    calibration: CalibrationResult
    correction: torch.Tensor | None = None
    corrected: torch.Tensor | None = None

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
        detector: a detector name for :func:`~ccs_kornia.modules.detection.factory.make_detector`
            (``"opencv"`` or ``"learned"``) or a :class:`ChessboardDetector` instance.
        model: output distortion model: ``opencv5`` (k1, k2, p1, p2, k3), ``k1k2``, ``rational`` or
            ``none``.
        use_ransac: reject inconsistent views with image-level RANSAC before the refinement.
        seed: seed of the RANSAC sampling (results are deterministic for a given seed).
        detection_batch_size: most images handed to the detector at once (bounds memory of the
            learned detector; the OpenCV detector works image by image anyway).
        max_detection_side: images whose longer side exceeds this are detected on a downscaled copy
            and refined at full resolution (``None`` or 0: always detect at full resolution). A detector that picks
            its own detection level (``selects_scale``: the learned one with ``scale="auto"``) gets the full images
            directly; the distortion-corrected detection of large images still uses the downscaled copy.
        distortion_correction: ``True`` (the shipped :class:`DistortionNet`), ``False`` (off, e.g. for ablation),
            a weight-file path or a ``DistortionNet``.
        min_correction: the correction is applied only to cameras whose pooled correction moves some pixel by
            more than this fraction of the half image diagonal (0.02: 8 px at 640x480); below that the usual
            detection and calibration handle the lens.
        free_distortion_centre: the corrected-frame refinement also estimates the distortion centre (the paper's
            model centres it on the image centre; real lenses centre it near the principal point).
        joint_iters: Levenberg-Marquardt iterations at most of the joint refinement of intrinsics, image-centred
            radial distortion and poses (0: the pinhole calibration of the corrected corners as it is).
        max_rms_ratio: the corrected-frame calibration is kept only if its radial model's RMS on the observed
            corners is at most this times that of the usual calibration in the output model (equal parameter
            counts for ``opencv5``: the better fit wins); otherwise the usual one is returned.
        solver_kwargs: further options of :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`
            (e.g. ``fix_aspect_ratio=True``).

    Example:
        >>> from ccs_kornia.data.scenes import make_calibration_set
        >>> K = torch.tensor([[300., 0, 160], [0, 300, 120], [0, 0, 1]], dtype=torch.float64)
        >>> views = make_calibration_set(K, (6, 4), 0.025, (320, 240), num_views=5, seed=1, supersample=1)
        >>> out = CalibrationPipeline("opencv")(views.images, (6, 4), 0.025)
        >>> out.K.shape, out.found.shape, out.view_rms.shape, bool(out.calibration.success)
        (torch.Size([3, 3]), torch.Size([5]), torch.Size([5]), True)
        >>> bool((out.K - K).abs().max() < 3.0)
        True
    """

    def __init__(
        self,
        detector: str | ChessboardDetector = "learned",
        model: str = "opencv5",
        use_ransac: bool = True,
        seed: int = 0,
        detection_batch_size: int = 16,
        max_detection_side: int | None = 2048,
        distortion_correction=True,
        min_correction: float = 0.02,
        joint_iters: int = 50,
        max_rms_ratio: float = 1.0,
        free_distortion_centre: bool = True,
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
        self.distortion_net = load_distortion_net(distortion_correction)
        if joint_iters < 0:
            raise ValueError(f"joint_iters must be >= 0, got {joint_iters}.")
        if not min_correction >= 0:
            raise ValueError(f"min_correction must be >= 0, got {min_correction}.")
        self.min_correction = float(min_correction)
        self.joint_iters = int(joint_iters)
        self.max_rms_ratio = float(max_rms_ratio)
        self.free_distortion_centre = bool(free_distortion_centre)

    def _detect_chunk(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Detect on ``(B, 1, H, W)``, through a downscaled copy when the images are large."""
        h, w = images.shape[-2:]
        limit = self.max_detection_side
        # a detector that picks its own detection scale and refines at full resolution (the learned one with
        # ``scale="auto"``, modules/detection/scale.py) bounds its memory itself
        if limit is None or max(h, w) <= limit or getattr(self.detector, "selects_scale", False):
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
        init_corners: torch.Tensor | None = None,
        initial: CalibrationResult | None = None,
    ) -> CalibrationResult:
        """Calibrate from detected corners (the solver stage alone).

        Args:
            corners: :math:`(V, N, 2)` or :math:`(C, V, N, 2)` pixels in grid order.
            valid: :math:`(V, N)` / :math:`(C, V, N)` bool, or per view :math:`(V,)` / :math:`(C, V)`.
            board_size: ``(cols, rows)``; ``N = cols * rows``.
            square: square side in world units (scales the translations only).
            image_size: ``(W, H)``.
            init_corners, initial: optional start of the solver (undistorted corners / a previous result), see
                :class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`.

        Returns:
            The solver's :class:`~ccs_kornia.modules.calibration.result.CalibrationResult`.
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
            return self.solver(
                corners.to(torch.float64), valid.bool(), object_points, (int(image_size[0]), int(image_size[1])),
                init_corners=None if init_corners is None else init_corners.to(corners.device, torch.float64),
                initial=initial,
            )

    # ------------------------------------------------------------------------------------------
    # distortion correction stages (each usable alone, e.g. streamed over a folder of images)
    # ------------------------------------------------------------------------------------------

    def view_corrections(self, images: torch.Tensor) -> torch.Tensor:
        """The network's radial correction of each view, :math:`(B, 5)` float64, for images :math:`(B, 1, H, W)`."""
        if self.distortion_net is None:
            raise RuntimeError("distortion correction is off for this pipeline.")
        net = self.distortion_net.to(images.device)
        with torch.inference_mode():
            return torch.cat([net(images[i : i + 16].float()) for i in range(0, images.shape[0], 16)]).double()

    def pool_corrections(self, per_view: torch.Tensor, image_size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
        """One correction per camera from :math:`(C, V, 5)` per-view ones, and whether it is applied :math:`(C,)`
        (it moves some pixel by more than ``min_correction`` of the half image diagonal)."""
        correction = aggregate_corrections(per_view.double(), image_size)
        half_diagonal = 0.5 * math.hypot(image_size[0], image_size[1])
        return correction, correction_displacement(correction, image_size) > self.min_correction * half_diagonal

    def detect_corrected(self, images: torch.Tensor, correction: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Detect on radially corrected copies of the images; corners in the original images.

        Boards missed in the corrected images are looked for in the originals. The corners are saddle-refined
        on the originals at the end (the corrected copies are interpolated).

        Args:
            images: :math:`(B, 1, H, W)`.
            correction: :math:`(5,)` or :math:`(B, 5)` correction coefficients.
            board_size: ``(cols, rows)``.
        """
        b, _, h, w = images.shape
        size = (int(w), int(h))
        corr = correction.double().to(images.device)
        corr = corr.expand(b, 5) if corr.dim() == 1 else corr
        limit = self.max_detection_side
        if limit is not None and max(h, w) > limit:
            # large photos: warp and detect an area-downscaled copy (the correction is defined in units of the
            # image size, so the same coefficients apply), then refine the corners at full resolution
            scale = max(h, w) / limit
            small_size = (max(8, round(h / scale)), max(8, round(w / scale)))
            small = F.interpolate(images.float(), size=small_size, mode="area")
            det = self.detect_corrected(small, corr, board_size)
            factor = torch.tensor([w / small_size[1], h / small_size[0]], dtype=det.corners.dtype,
                                  device=det.corners.device)
            corners = (det.corners + 0.5) * factor - 0.5
            found_idx = det.found.nonzero().flatten()
            if found_idx.numel():
                corners[found_idx] = self._refine_full_resolution(images, corners[found_idx], found_idx, board_size)
            return DetectionResult(corners, det.found, det.reasons)
        zoom = float(corrected_frame.correction_zoom(corr, size))
        parts_c, parts_f, reasons = [], [], []
        for i in range(0, b, self.detection_batch_size):
            chunk = slice(i, i + self.detection_batch_size)
            with torch.inference_mode():
                warped = radial_undistort_image(images[chunk].float(), corr[chunk].float(), zoom=zoom).clamp(0, 1)
            det = self.detect(warped, board_size)
            back, ok = distort_points_from_correction(det.corners.double(), corr[chunk], size, zoom=zoom, return_valid=True)
            found_c = det.found & ok.all(-1) & back.isfinite().all(-1).all(-1)
            parts_c.append(torch.where(found_c[:, None, None], back, torch.zeros_like(back)))
            parts_f.append(found_c)
            reasons += [("corrected image: " + (det.reasons[k] if det.reasons else "found")) if f else ""
                        for k, f in enumerate(found_c.tolist())]
        corners, found = torch.cat(parts_c), torch.cat(parts_f)
        missed = (~found).nonzero().flatten()
        if missed.numel():
            plain = self.detect(images[missed], board_size)
            corners[missed] = torch.where(plain.found[:, None, None], plain.corners.double(), corners[missed])
            found[missed] = plain.found
            for k, i in enumerate(missed.tolist()):
                reasons[i] = plain.reasons[k] if plain.reasons else ("" if plain.found[k] else "board not found")
        sel = (found & (torch.arange(b, device=found.device)[:, None] != missed[None, :]).all(-1)).nonzero().flatten()
        if sel.numel():
            with torch.inference_mode():
                cells = torch.ones(sel.numel(), corners.shape[1], dtype=torch.bool, device=corners.device)
                corners[sel] = self.refiner(images[sel].float(), corners[sel].float(), cells, board_size).double()
        return DetectionResult(corners.float(), found, reasons)

    def solve_with_correction(
        self,
        corners: torch.Tensor,
        found: torch.Tensor,
        correction: torch.Tensor,
        apply: torch.Tensor,
        board_size: tuple[int, int],
        square: float,
        image_size: tuple[int, int],
    ) -> tuple[CalibrationResult, torch.Tensor, torch.Tensor]:
        """The solver stage of the corrected pipeline: the usual calibration, and for cameras in ``apply`` the
        corrected-frame one, kept unless it fits the observed corners clearly worse
        (:func:`~ccs_kornia.modules.correction.corrected_frame.solve_with_correction`).

        Args:
            corners: :math:`(C, V, N, 2)`; found: :math:`(C, V)`; correction: :math:`(C, 5)` pooled corrections;
            apply: :math:`(C,)` bool, cameras to calibrate in the corrected frame.

        Returns:
            (calibration, correction per camera (re-fitted where applied), applied :math:`(C,)`).
        """
        usual = self.calibrate(corners, found, board_size, square, image_size)
        return corrected_frame.solve_with_correction(
            self.solver, usual, corners, found, correction, apply, board_size, square, image_size,
            joint_iters=self.joint_iters, free_distortion_centre=self.free_distortion_centre,
            max_rms_ratio=self.max_rms_ratio,
        )

    def calibrate_corrected(
        self,
        corners: torch.Tensor,
        found: torch.Tensor,
        correction: torch.Tensor,
        board_size: tuple[int, int],
        square: float,
        image_size: tuple[int, int],
    ) -> tuple[CalibrationResult, torch.Tensor, torch.Tensor]:
        """Calibrate in the radially corrected frame, then express the camera in the output model
        (:func:`~ccs_kornia.modules.correction.corrected_frame.calibrate_corrected` with this pipeline's solver).

        Returns:
            (result in the output model, refined correction :math:`(C, 5)`, RMS reprojection error of the radial
            model :math:`(C,)`).
        """
        return corrected_frame.calibrate_corrected(
            self.solver, corners, found, correction, board_size, square, image_size,
            joint_iters=self.joint_iters, free_distortion_centre=self.free_distortion_centre,
        )

    # ------------------------------------------------------------------------------------------

    def forward(self, images: torch.Tensor, board_size: tuple[int, int], square: float = 1.0) -> PipelineResult:
        """Detect and calibrate (with the distortion correction when it is on).

        Args:
            images: :math:`(V, 1, H, W)` (one camera) or :math:`(C, V, 1, H, W)` (``C`` cameras of
                one image size) float in ``[0, 1]``.
            board_size: ``(cols, rows)`` inner corners.
            square: square side in world units.

        Returns:
            :class:`PipelineResult`.
        """
        if self.distortion_net is None:
            detections = self.detect(images, board_size)
            image_size = (int(images.shape[-1]), int(images.shape[-2]))
            calibration = self.calibrate(detections.corners, detections.valid, board_size, square, image_size)
            return PipelineResult(detections, calibration)
        if not isinstance(images, torch.Tensor) or images.dim() not in (4, 5) or images.shape[-3] != 1:
            shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
            raise ValueError(f"Expected grey images (V, 1, H, W) or (C, V, 1, H, W), got {shape}.")
        unbatched = images.dim() == 4
        imgs = images[None] if unbatched else images
        c, v = imgs.shape[:2]
        h, w = imgs.shape[-2:]
        size = (int(w), int(h))
        n = int(board_size[0]) * int(board_size[1])
        flat = imgs.reshape(c * v, 1, h, w)
        correction, strong = self.pool_corrections(self.view_corrections(flat).reshape(c, v, 5), size)
        corners = torch.zeros(c * v, n, 2, dtype=torch.float64, device=imgs.device)
        found = torch.zeros(c * v, dtype=torch.bool, device=imgs.device)
        reasons: list[str] = [""] * (c * v)
        is_strong = strong.to(imgs.device).repeat_interleave(v)
        # strongly distorted cameras camera by camera (each correction sets its own zoom), the others in one go
        groups = [(torch.arange(ci * v, (ci + 1) * v, device=imgs.device), ci) for ci in strong.nonzero().flatten().tolist()]
        rest = (~is_strong).nonzero().flatten()
        if rest.numel():
            groups.append((rest, None))
        for sel, ci in groups:
            det = self.detect(flat[sel], board_size) if ci is None else \
                self.detect_corrected(flat[sel], correction[ci], board_size)
            corners[sel] = det.corners.double()
            found[sel] = det.found
            for k, i in enumerate(sel.tolist()):
                reasons[i] = det.reasons[k] if det.reasons else ""
        corners, found = corners.reshape(c, v, n, 2), found.reshape(c, v)
        calib, correction, strong = self.solve_with_correction(corners, found, correction, strong, board_size, square, size)
        detections = DetectionResult(corners.to(torch.float32), found, reasons)
        out = PipelineResult(detections, calib, correction, strong)
        if unbatched:
            det = DetectionResult(detections.corners[0], detections.found[0], reasons)
            cal = CalibrationResult(**{k: (a[0] if isinstance(a, torch.Tensor) else a) for k, a in calib.__dict__.items()})
            out = PipelineResult(det, cal, correction[0], strong[0])
        return out

