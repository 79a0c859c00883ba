"""The learned chessboard detector: heatmap UNet → peaks → Gaussian fit → sigma rejection → grid → refinement."""

from __future__ import annotations

import copy
import math
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch

from ccs_kornia.modules._fuse import fold_batchnorm, has_batchnorm
from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    Fallbacks,
    image_rows,
)
from ccs_kornia.modules.detection.checks.board_checks import whole_board_check
from ccs_kornia.modules.detection.checks.corner_evidence import (
    decide_corners,
    measure_corner_evidence,
)
from ccs_kornia.modules.detection.checks.hidden_corners import (
    PARTIAL_BOARD_FRACTION,
    settle_partial_boards,
)
from ccs_kornia.modules.detection.enhanced_copies import enhanced_copies
from ccs_kornia.modules.detection.grid.collinearity import collinearity_refine
from ccs_kornia.modules.detection.grid.grid_geometry import grid_spacing
from ccs_kornia.modules.detection.grid.grid_organizer import organize_grid
from ccs_kornia.modules.detection.grid.missing_corners import (
    predict_missing_corners,
    unconfirmed_corners,
)
from ccs_kornia.modules.detection.learned.foreshortening import detect_foreshortened
from ccs_kornia.modules.detection.learned.gaussian_fit import gaussian_fit
from ccs_kornia.modules.detection.learned.heatmap_unet import (
    PRECISIONS,
    CornerUNet,
    run_heatmap,
)
from ccs_kornia.modules.detection.learned.opencv_candidates import (
    opencv_candidates,
    opencv_level_factor,
)
from ccs_kornia.modules.detection.learned.peaks import heatmap_peaks
from ccs_kornia.modules.detection.learned.scale import (
    TARGET_SQUARE,
    ScaleSelector,
    detect_at_scale,
)
from ccs_kornia.modules.detection.learned.sigma_rejection import sigma_outlier_rejection
from ccs_kornia.modules.detection.learned.x_junction import x_junction_mask
from ccs_kornia.modules.detection.motion_deblur import (
    REFINE_NOISE,
    deblur_motion,
    motion_blur,
)
from ccs_kornia.modules.detection.refine.image_noise import NOISY, noise_to_contrast
from ccs_kornia.modules.detection.refine.patch_refine import (
    refine_from_level,
    refine_from_neighbours,
)
from ccs_kornia.modules.detection.refine.saddle_refine import (
    CornerRefiner,
    refine_corners,
)
from ccs_kornia.runtime.threads import full_threads, light_stages_single_thread
from ccs_kornia.runtime.timing import stage

__all__ = ["DEFAULT_DETECTOR_WEIGHTS", "DIM_SPAN", "DISPUTED_PX", "SMALL_PIXELS", "chessboard_copies", "load_corner_unet",
           "LearnedChessboardDetector"]

#: a corner of a board found on an enhanced copy that the image's own saddle fit moves farther than this (px) is left
#: out (the copy and the image disagree on where it is)
DISPUTED_PX = 1.0
#: the stretched copy is looked at where the image is dim: its 1st to 99th percentiles span fewer grey levels than
#: this (a quarter of the range; elsewhere the stretch barely changes the image)
DIM_SPAN = 64
#: the enlarged copy is looked at where the image is small: at most this many pixels (an enlarged large image costs
#: four times its detection and its squares are large enough already)
SMALL_PIXELS = 250_000

#: weights shipped inside the package (see docs/training.md for how they were made)
DEFAULT_DETECTOR_WEIGHTS = Path(__file__).resolve().parents[3] / "weights" / "corner_unet.pt"


def load_corner_unet(path: str | Path | None = None, map_location: str | torch.device = "cpu") -> tuple[CornerUNet, float]:
    """Load an exported detector checkpoint; returns ``(network in eval mode, training sigma)``.

    Raises:
        FileNotFoundError: no weights at ``path`` (default: the shipped ones).
    """
    path = Path(path) if path is not None else DEFAULT_DETECTOR_WEIGHTS
    if not path.is_file():
        raise FileNotFoundError(f"Detector weights not found at {path}.")
    ckpt = torch.load(path, map_location=map_location, weights_only=True)
    net = CornerUNet(**ckpt["config"])
    net.load_state_dict(ckpt["state_dict"])
    return net.eval(), float(ckpt.get("sigma", 1.5))


#: a board found from OpenCV's candidates is refused where a refined corner lies farther than this (in squares) from
#: where its row and column neighbours put it (exact lattices, 75-degree tilt included, stay well below:
#: ``docs/measurements.md``)
MAX_LATTICE_DEVIATION = 0.08
#: refinement window of boards from OpenCV's candidates, in grid spacings: such boards are mostly ones with marks in
#: their white squares, and the usual 0.2 reaches the marks' frames (``docs/measurements.md``)
MARKED_RADIUS_FACTOR = 0.1


class LearnedChessboardDetector(ChessboardDetector):
    """Heatmap-learning chessboard detector (paper §III-B) with an image-based final refinement.

    Steps, each switchable so its effect can be measured:

    1. :class:`CornerUNet` heatmap;
    2. peaks (kornia ``nms2d`` + threshold + top-k, soft-argmax seeds) and Gaussian surface fitting
       (batched least squares in log space) giving ``mu`` and ``sigma`` per peak;
    3. peaks whose ``sigma`` differs from the training sigma are rejected, and so are peaks where the
       image shows no X-junction;
    4. grid organisation into a ``cols x rows`` board (missing corners predicted, wrong boards rejected);
    5. optional collinearity refinement (only meaningful on undistorted images);
    6. optional saddle-point refinement on the image (window adapted to the grid spacing).

    Its :class:`DetectionResult` carries each corner's point-symmetry residual (``sigma``,
    :func:`~ccs_kornia.modules.detection.refine.corner_uncertainty.corner_uncertainty`), measured for the asymmetry check
    (:func:`~ccs_kornia.modules.detection.checks.hidden_corners.settle_partial_boards`) and reused by solvers that weigh
    corners by it.

    Args:
        net: a trained :class:`CornerUNet` (a copy with its batch normalisation folded is used); ``None`` loads
            ``weights``.
        weights: path of an exported checkpoint (default: the shipped weights).
        sigma: training sigma of the heatmaps (read from the checkpoint when loading).
        peak_threshold: heatmap threshold of a peak.
        nms_kernel: non-maximum suppression window.
        max_peaks: peak slots per image.
        fit_window: Gaussian-fit window (odd).
        sigma_tolerance: relative sigma tolerance of the outlier rejection.
        collinearity: run the collinearity refinement.
        refine: ``"symmetric"`` (saddle fit + point-symmetry polish), ``"saddle"``, ``"gradient"`` or ``"none"``
            image refinement.
        x_junction_check: drop peaks where the image shows no X-junction (clutter, board edges).
        scale: ``"auto"``: detect on the pyramid level where the squares have about ``target_square`` px (chosen per
            image from the image, :mod:`ccs_kornia.modules.detection.learned.scale`) and refine at full resolution;
            ``"off"``: detect at the input resolution.
        target_square: square size in px the network sees with ``scale="auto"``.
        max_pixels: most pixels of a detection level with ``scale="auto"`` (bounds memory and time).
        scale_fallback: with ``scale="auto"``, relative factors of the levels tried in turn where the board was not
            found at the chosen one, clamped to the image itself (never upsampled). A finer level resolves thin board
            margins that a coarse one blurs into an extra row of corners; a coarser one drops clutter.
        scale_finest: with a fallback, then also the octaves below the finest fallback and the finest level allowed
            (a wrong square-size estimate; :func:`~ccs_kornia.modules.detection.learned.scale.detect_at_scale`).
        max_upsampling: with ``scale="auto"``, images whose squares are smaller than ``target_square`` are upsampled
            by at most this factor (1: never).
        precision: of the heatmap network (:func:`~ccs_kornia.modules.detection.learned.heatmap_unet.run_heatmap`):
            ``"float32"`` (default), ``"bfloat16"`` or ``"auto"`` (bfloat16 where the CPU computes it natively). Opt-in:
            bfloat16 ran faster with AVX512-BF16 but lost boards (``docs/measurements.md``), and
            docs/benchmarks.md is float32: one answer on every machine.
        opencv_retry: where no level gave a board from the network's peaks, look again on the corners of OpenCV's
            classic detector on a bounded level (:mod:`~ccs_kornia.modules.detection.learned.opencv_candidates`: above all
            boards with marks inside the white squares, whose corners the network misses), organised, refined and
            checked as the network's, plus a lattice check.
        foreshortened_retry: where still no board was found, look on copies of the finest level allowed compressed
            2:1 along four directions in turn (:mod:`~ccs_kornia.modules.detection.learned.foreshortening`: boards at a
            grazing angle, whose squares are foreshortened 2-4:1).
        copies_retry: last, where still no board was found (a partial board is kept as it is), look for it on the
            image's enhanced copies that suit it (:func:`chessboard_copies`: contrast stretched where the image is dim,
            enlarged where it is small, deblurred where it shows a straight motion blur) with every fallback, in turn
            until one gives the whole board; a copy's board is refined again on the image, a corner moving more than :data:`DISPUTED_PX` there left out (a dim view misleads the square-size estimate,
            a small one's squares are a few px: docs/detection.md). Wherever a board's corners fail their saddle fit
            on an image that shows a straight motion blur, the board is refined again on the image with that blur
            undone (:mod:`~ccs_kornia.modules.detection.motion_deblur`); wherever they fail, or the level calls
            corners inside the image hidden, on a noisy board
            (:func:`~ccs_kornia.modules.detection.refine.image_noise.noise_to_contrast` above
            :data:`~ccs_kornia.modules.detection.refine.image_noise.NOISY`: a photograph taken in the dark), those
            corners are fitted again with the smoothing doubled.
        (``scale_fallback``, ``scale_finest``, ``opencv_retry``, ``foreshortened_retry`` and ``copies_retry`` make the
        detector's own
        :class:`~ccs_kornia.modules.detection.base.Fallbacks`, :attr:`fallbacks`; a caller passes others per call.)
        partial_boards: keep a found board whose unconfirmed corners the image does not show (saturating glare, an
            occluder: :mod:`~ccs_kornia.modules.detection.checks.hidden_corners`), with those corners NaN (left out of
            ``DetectionResult.valid``); otherwise such a board is refused as incomplete.
    """

    def __init__(
        self,
        net: CornerUNet | None = None,
        weights: str | Path | None = None,
        sigma: float = 1.5,
        peak_threshold: float = 0.25,
        nms_kernel: int = 5,
        max_peaks: int = 512,
        fit_window: int = 7,
        sigma_tolerance: float = 0.6,
        collinearity: bool = False,
        refine: str = "symmetric",
        x_junction_check: bool = True,
        scale: str = "auto",
        target_square: float = TARGET_SQUARE,
        max_pixels: float = 3.2e6,
        scale_fallback: tuple[float, ...] = (0.5, 2.0, 0.25),
        scale_finest: bool = True,
        max_upsampling: float = 2.0,
        precision: str = "float32",
        opencv_retry: bool = True,
        foreshortened_retry: bool = True,
        partial_boards: bool = True,
        copies_retry: bool = True,
    ) -> None:
        super().__init__()
        if net is None:
            net, sigma = load_corner_unet(weights)
        elif has_batchnorm(net):
            net = copy.deepcopy(net)  # the caller's network (e.g. one in training) is left as it is
        # inference only: batch normalisation folded into the convolutions (same heatmap, less CPU time:
        # docs/measurements.md)
        self.net = fold_batchnorm(net)
        self.sigma = sigma
        self.peak_threshold = peak_threshold
        self.nms_kernel = nms_kernel
        self.max_peaks = max_peaks
        self.fit_window = fit_window
        self.sigma_tolerance = sigma_tolerance
        self.collinearity = collinearity
        self.x_junction_check = x_junction_check
        if refine not in ("saddle", "symmetric", "gradient", "none"):
            raise ValueError(f"refine must be 'symmetric', 'saddle', 'gradient' or 'none', got {refine!r}.")
        self.refine = refine
        self.refiner = CornerRefiner(method=refine) if refine != "none" else None
        # --- scale selection (modules/detection/learned/scale.py) ---
        if scale not in ("auto", "off"):
            raise ValueError(f"scale must be 'auto' or 'off', got {scale!r}.")
        self.scale = scale
        if not max_upsampling >= 1:
            raise ValueError(f"max_upsampling must be >= 1, got {max_upsampling}.")
        self.scale_selector = ScaleSelector(target_square=target_square, max_pixels=max_pixels,
                                            min_factor=1.0 / max_upsampling)
        # the detector's own fallbacks; a caller passes others per call (``forward``'s ``fallbacks``)
        self.fallbacks = Fallbacks(True, tuple(float(f) for f in scale_fallback), bool(scale_finest),
                                   bool(opencv_retry), bool(foreshortened_retry), bool(copies_retry))
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}.")
        self.precision = precision
        self.partial_boards = bool(partial_boards)

    @property
    def selects_scale(self) -> bool:
        """Whether the detector picks its own detection level (callers need not downscale large images)."""
        return self.scale == "auto"

    @property
    def heatmap_net(self) -> torch.nn.Module:
        """The heatmap network (:class:`CornerUNet`)."""
        return self.net

    @property
    def refines_on_image(self) -> bool:
        """Unless ``refine="none"`` (the corners are the network's own)."""
        return self.refine != "none"

    def detection_factor(self, images: torch.Tensor) -> torch.Tensor | float:
        """Full-resolution px per px of each image's primary detection level (``scale="auto"``), else 1."""
        return self.scale_selector(images)[1] if self.scale == "auto" else 1.0

    @torch.no_grad()
    def candidates(
        self, images: torch.Tensor, full: torch.Tensor | None = None, scale: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Heatmap and sigma-filtered sub-pixel peaks: ``heatmap (B,1,H,W), points (B,M,2), mask (B,M)``.

        With ``full`` (the full-resolution images of a downscaled level ``images``, ``x_full + 0.5 = (x + 0.5) * scale``)
        the X-junction test runs on ``full``, where thin board margins are still resolved.
        """
        with stage("heatmap network"), full_threads():
            heat = run_heatmap(self.net, images, self.precision)
        with stage("peaks + Gaussian fit + sigma rejection"):
            seeds, _, mask = heatmap_peaks(heat, self.peak_threshold, self.max_peaks, self.nms_kernel)
            mu, sig, ok = gaussian_fit(heat, seeds, mask, self.fit_window)
            keep = sigma_outlier_rejection(sig, mask & ok, self.sigma, self.sigma_tolerance)
        with stage("X-junction check"):
            if self.x_junction_check and full is not None and scale is not None:
                # --- scale selection: same circle geometry as on the level, sampled at full resolution ---
                f = float(scale.max())
                keep = x_junction_mask(full, (mu + 0.5) * scale.to(mu) - 0.5, keep, max_radius=15.0 * f)
            elif self.x_junction_check:
                keep = x_junction_mask(images, mu, keep)
        return heat, mu, keep

    @torch.no_grad()
    def forward(self, images: torch.Tensor, board_size: tuple[int, int],
                fallbacks: Fallbacks | None = None) -> DetectionResult:
        """Detect the board on every image of ``(B, 1, H, W)``; corners in grid order. ``fallbacks``: what is tried
        where the board is not found at first (default: the detector's own, :attr:`fallbacks`)."""
        board_size = self._check_inputs(images, board_size)
        if images.shape[0] == 0:  # an empty batch (e.g. a folder's last, empty chunk): nothing to look at
            return _empty_result(images, board_size)
        fallbacks = self.fallbacks if fallbacks is None else fallbacks
        with light_stages_single_thread(images.device):
            out = self._grid_checks(images, self._detect(images.float(), board_size, fallbacks), board_size)
            if fallbacks.copies:
                out = self._on_copies(images, out, board_size, fallbacks)
            return out

    @torch.no_grad()
    def foreshortened(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """Only the last resort for boards seen at a grazing angle (``Fallbacks.foreshortened``), on ``(B, 1, H, W)``:
        the finest level allowed compressed along a few directions in turn
        (:func:`~ccs_kornia.modules.detection.learned.foreshortening.detect_foreshortened`), corners refined at full
        resolution and checked as in :meth:`forward`. For callers that first try the cheaper looks (the calibration
        pipeline runs it on the views its other looks missed) with ``Fallbacks.foreshortened`` off."""
        board_size = self._check_inputs(images, board_size)
        if images.shape[0] == 0:
            return _empty_result(images, board_size)
        with light_stages_single_thread(images.device):
            return self._grid_checks(images, self._foreshortened(images.float(), board_size), board_size)

    def _grid_checks(self, images: torch.Tensor, out: DetectionResult, board_size: tuple[int, int]) -> DetectionResult:
        with stage("partial boards"):
            # corners far less point-symmetric than their board's lie on an edge or in a square: left out (partial
            # boards) or, without partial boards, the board is refused (whole boards or nothing)
            out = settle_partial_boards(images, out, board_size)
            if not self.partial_boards:
                left_out = (out.found[:, None] & ~out.valid).sum(-1)
                for b in left_out.nonzero().flatten().tolist():
                    out.found[b], out.reasons[b] = False, f"board refused: {int(left_out[b])} corner(s) not on a junction"
                    out.corners[b], out.sigma[b] = 0.0, float("nan")
        with stage("grid checks"):
            # every other crossing of a grid of lines is a lattice of '+' junctions the network can take for a
            # board (held-out board-free images: docs/measurements.md); a true board has no saddle halfway between
            # corners
            for b in out.found.nonzero().flatten().tolist():
                # and a sub-board: the organiser looks for peaks past the sides, which a coarse level can lack on a
                # whole line (squares of 5 px there, docs/measurements.md); the image shows it
                reason = whole_board_check(images[b, 0].float().cpu().numpy(), out.corners[b].double().cpu().numpy(),
                                           board_size)
                if reason:
                    out.found[b], out.reasons[b] = False, f"board refused: {reason}"
                    out.corners[b], out.sigma[b] = 0.0, float("nan")
        return out

    def _on_copies(self, images: torch.Tensor, out: DetectionResult, board_size: tuple[int, int],
                   fallbacks: Fallbacks) -> DetectionResult:
        """``out`` with the views where no board was found looked at again on the image's enhanced copies in turn
        (:func:`chessboard_copies`), with ``fallbacks`` (the grazing angle's included: a dark fisheye view's board at
        a grazing angle is found by that look on the stretched copy only), until one gives the whole board; a copy's
        board, in the image's pixels, is refined again on the image (a corner that moves more than
        :data:`DISPUTED_PX` there left out) and kept where it measures more corners than the copies before it (at
        least :data:`~ccs_kornia.modules.detection.checks.hidden_corners.PARTIAL_BOARD_FRACTION` of them; all of them
        without partial boards). A board found on the image, whole or partial, is never looked at again."""
        n = board_size[0] * board_size[1]
        todo = (~out.found).nonzero().flatten().tolist()
        if not todo:
            return out
        look = fallbacks.but(copies=False)
        least = math.ceil(PARTIAL_BOARD_FRACTION * n) if self.partial_boards else n
        with stage("enhanced copies"):
            for b in todo:
                gray8 = (images[b, 0].float() * 255.0).round().clamp(0, 255).to(torch.uint8).cpu().numpy()
                best = least - 1
                for name, copy_, scale in chessboard_copies(gray8):
                    x = torch.from_numpy(copy_).to(images.device).float()[None, None] / 255.0
                    got = self._grid_checks(x, self._detect(x, board_size, look), board_size)
                    if not bool(got.found[0]):
                        continue
                    corners = (got.corners[0].double().to(out.corners.device) + 0.5) / scale - 0.5
                    # refined again on the image itself (where its saddle shows: the image's pixels, as every other
                    # look's corners); a corner the copy and the image place more than DISPUTED_PX apart (motion
                    # blur: the image's saddle drifts) is left out
                    refined = self._refine_at_full_size(images[b : b + 1].float(), corners[None].to(images.device)
                                                        .float(), board_size, 1.0)[0].double().to(corners.device)
                    corners = refined.masked_fill(((refined - corners).norm(dim=-1) > DISPUTED_PX)[:, None],
                                                  float("nan"))
                    count = int(corners.isfinite().all(-1).sum())
                    if count <= best:
                        continue
                    best = count
                    out.corners[b] = corners.to(out.corners.dtype)
                    out.found[b], out.reasons[b] = True, f"{got.reasons[0]} (enhanced copy: {name})"
                    if out.sigma is not None:
                        sigma = got.sigma[0] / scale if got.sigma is not None else float("nan")
                        out.sigma[b] = torch.as_tensor(sigma).to(out.sigma).masked_fill(
                            ~corners.isfinite().all(-1).to(out.sigma.device), float("nan"))
                    if count == n:
                        break
        return out

    def _refine_at_full_size(self, full: torch.Tensor, pts: torch.Tensor, board_size: tuple[int, int], factor: float,
                             radius_factor: float | None = None) -> torch.Tensor:
        """Corners found on a level ``factor`` times coarser, refined on the full-resolution images (coarse to fine)."""
        r = self.refiner
        if r is None:
            return pts
        # the full-resolution fit's regions are large enough for both threads (docs/measurements.md); the level's
        # refinement gains nothing from the second
        rf = radius_factor or r.radius_factor
        args = (board_size, factor, rf, r.max_radius, r.method, r.iterations, r.smooth_sigma, r.normalize_sigma)
        with stage("saddle refinement"), full_threads():
            out, ok = refine_from_level(full, pts, *args, return_ok=True, neighbours=False)
        ok = ok.to(out.device)
        failed = (~ok & out.isfinite().all(-1)).any(-1).nonzero().flatten().tolist()
        sharp = full
        if failed:
            with stage("motion deblur"):
                for b in failed:
                    # a straight motion blur widens the edges across it only: the saddle window, widened by the
                    # board's median edge blur, stays too narrow there and the fit fails. Where the image shows
                    # such a blur it is undone (a symmetric line: the saddles stay where they are) and the board
                    # refined again there, kept where more corners find their saddle
                    gray = full[b, 0].double().cpu().numpy()
                    blur = motion_blur(np.clip(np.rint(gray * 255.0), 0, 255).astype(np.uint8))
                    if blur is None:
                        continue
                    deblurred = torch.from_numpy(deblur_motion(gray, *blur, REFINE_NOISE)).to(full)[None, None]
                    with full_threads():
                        out_b, ok_b = refine_from_level(deblurred, pts[b : b + 1], *args, return_ok=True,
                                                        neighbours=False)
                    if int(ok_b.sum()) > int(ok[b].sum()):
                        out[b], ok[b] = out_b[0].to(out), ok_b[0].to(ok)
                        sharp = sharp.clone() if sharp is full else sharp
                        sharp[b] = deblurred[0]
            # the corners still without a saddle, tried again from where their refined neighbours put them (on the
            # image the board was refined on)
            with stage("saddle refinement"), full_threads():
                out, ok = refine_from_neighbours(sharp, pts.to(out.device), out, ok, board_size, rf, r.max_radius,
                                                 r.method, r.iterations, r.smooth_sigma, r.normalize_sigma)
        out, ok = self._refit_noisy(sharp, pts, out, ok, board_size, factor, rf)
        # a corner that found no saddle within its window at full resolution kept its position from the level, which
        # can be px off (a corner at a glare's rim): left out like a hidden one (rare on the real sets:
        # docs/measurements.md); and so is one its row and column neighbours cannot predict: nothing confirms its
        # saddle is its own (a dark board at a grazing angle: such a corner's fit went to the next row's corner)
        out = out.masked_fill((~ok.to(out.device) & out.isfinite().all(-1))[..., None], float("nan"))
        alone = unconfirmed_corners(out.isfinite().all(-1), board_size)
        return out.masked_fill(alone[..., None], float("nan"))

    def _refit_noisy(self, images: torch.Tensor, pts: torch.Tensor, out: torch.Tensor, ok: torch.Tensor,
                     board_size: tuple[int, int], factor: float, radius_factor: float) -> tuple[torch.Tensor, torch.Tensor]:
        """On a noisy board (a photograph taken in the dark: :func:`~ccs_kornia.modules.detection.refine.image_noise.
        noise_to_contrast` above :data:`~ccs_kornia.modules.detection.refine.image_noise.NOISY`) a low-contrast
        corner's Hessian is the noise's: the corners whose fit failed, and the hidden ones (NaN in ``pts``: the level
        found no saddle there and a faded checker) whose neighbours put them inside the image by more than the fit's
        largest window, are fitted again from the level, coarse to fine, with the smoothing doubled; only those corners
        take the new fit, where it finds a saddle. ``images`` :math:`(B, 1, H, W)` (the images the boards were refined
        on), ``pts`` the level's corners, ``out`` / ``ok`` the fit so far :math:`(B, N, 2)` / :math:`(B, N)`."""
        r = self.refiner
        hidden = ~pts.isfinite().all(-1).to(ok.device)
        filled, predicted = predict_missing_corners(pts.nan_to_num(0.0), ~hidden.to(pts.device), board_size,
                                                    passes=max(board_size))
        h, w = images.shape[-2:]
        x, y = filled[..., 0].to(ok.device), filled[..., 1].to(ok.device)
        m = r.max_radius
        inside = (x >= m) & (y >= m) & (x <= w - 1 - m) & (y <= h - 1 - m)
        retry = (~ok & out.isfinite().all(-1)) | (hidden & predicted.to(ok.device) & inside)
        rows = retry.any(-1).nonzero().flatten()
        if not rows.numel():
            return out, ok
        rows = rows[noise_to_contrast(images[rows], out[rows].to(images.device), board_size).cpu() > NOISY]
        if not rows.numel():
            return out, ok
        with stage("saddle refinement"), full_threads():
            again, ok_again = refine_from_level(images[rows], filled[rows].to(images.device), board_size, factor,
                                                radius_factor, r.max_radius, r.method, r.iterations,
                                                2.0 * r.smooth_sigma, r.normalize_sigma, return_ok=True)
        take = retry[rows] & ok_again.to(ok.device)
        out, ok = out.clone(), ok.clone()
        out[rows] = torch.where(take[..., None], again.to(out), out[rows])
        ok[rows] = ok[rows] | take
        return out, ok

    def _foreshortened(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        h, w = images.shape[-2:]
        floor = max(1.0, math.sqrt(w * h / self.scale_selector.max_pixels))

        def compressed(x: torch.Tensor, bs: tuple[int, int]) -> DetectionResult:
            return self.detect_level(x, bs, resampled=True)

        def refine(full: torch.Tensor, pts: torch.Tensor, factor: float) -> torch.Tensor:
            return self._refine_at_full_size(full, pts, board_size, factor)

        return detect_foreshortened(compressed, images, board_size, refine, floor)

    def _detect(self, images: torch.Tensor, board_size: tuple[int, int], fallbacks: Fallbacks) -> DetectionResult:
        if self.scale == "off":
            return self.detect_level(images, board_size)
        # --- scale selection (modules/detection/learned/scale.py): detect on each image's level, refine at full resolution ---
        # the square-size estimate is a few whole-image filters: on a batch of a megapixel or more both threads pay
        # off, on one small image waking the second does not (docs/measurements.md)
        big = images.numel() >= 1e6
        with stage("square-size estimate"), (full_threads() if big else nullcontext()):
            _, factor = self.scale_selector(images)

        def refine(full: torch.Tensor, pts: torch.Tensor, factor: float, radius_factor: float | None = None):
            return self._refine_at_full_size(full, pts, board_size, factor, radius_factor)

        out = detect_at_scale(self.detect_level, images, board_size, factor, fallbacks.levels,
                              self.scale_selector.max_pixels, refine, finest=fallbacks.finest,
                              primary=fallbacks.primary)
        missed = (~out.found).nonzero().flatten()
        if fallbacks.opencv and missed.numel():
            # last resort: OpenCV's quads on one bounded level (they need no square-size estimate), refined with a
            # narrow window (these are mostly boards with marks)
            def opencv_level(x: torch.Tensor, bs: tuple[int, int], full: torch.Tensor, scale: torch.Tensor):
                return self.detect_level(x, bs, full, scale, source="opencv")

            def narrow(full: torch.Tensor, pts: torch.Tensor, factor: float) -> torch.Tensor:
                return refine(full, pts, factor, MARKED_RADIUS_FACTOR)

            h, w = images.shape[-2:]
            levels = torch.full((missed.numel(),), opencv_level_factor((w, h)), dtype=factor.dtype)
            got = detect_at_scale(opencv_level, image_rows(images, missed), board_size, levels, (),
                                  self.scale_selector.max_pixels, narrow)
            c2, f2, r2 = got.corners, got.found, got.reasons
            out.fill(missed, DetectionResult(c2, f2, r2))
            for k, i in enumerate(missed.tolist()):  # why a board the candidates gave was refused
                if not bool(f2[k]) and r2[k].startswith("board refused"):
                    out.reasons[i] = r2[k]
        missed = (~out.found).nonzero().flatten()
        if fallbacks.foreshortened and missed.numel():
            # boards at a grazing angle: the finest level allowed, compressed along one direction at a time
            out.fill(missed, self._foreshortened(image_rows(images, missed), board_size))
        out.corners = out.corners.float()
        return out

    def _opencv_board(self, images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
        """:meth:`detect_level` on :func:`~ccs_kornia.modules.detection.learned.opencv_candidates.opencv_candidates` of
        ``images`` instead of the network's peaks.

        OpenCV's corners are within a px: no coarse search (the marks pull it, ``docs/measurements.md``) and a narrow
        refinement window (:data:`MARKED_RADIUS_FACTOR`). No X-junction check: its circle test
        counts the colour changes around a point, and a mark inside a white square adds changes. In its place, a
        board whose refined corners leave the smooth lattice of their neighbours by more than
        :data:`MAX_LATTICE_DEVIATION` squares is refused (near a mark a corner can converge onto the mark's own
        junctions). A sub-board (OpenCV returns them) is refused by the final checks like any board whose pattern
        continues past a side."""
        with stage("opencv candidates"):
            points, keep = opencv_candidates(images, board_size)
        corners, valid, found = _organize(points, keep, board_size, images)
        refiner = self.refiner
        if refiner is not None:
            refiner = copy.copy(refiner)
            refiner.radius_factor = MARKED_RADIUS_FACTOR
        out = self._complete(images, board_size, corners, valid, found, refiner)
        if bool(out.found.any()):
            off = torch.zeros_like(out.found)
            for b in out.found.nonzero().flatten().tolist():
                reason = whole_board_check(images[b, 0].float().cpu().numpy(), out.corners[b].double().cpu().numpy(),
                                           board_size, MAX_LATTICE_DEVIATION, skipped=False, extends=False)
                if reason:
                    off[b], out.reasons[b] = True, f"board refused: {reason}"
            out.found = out.found & ~off
            out.corners = torch.where(out.found[:, None, None], out.corners, torch.zeros_like(out.corners))
        out.reasons = [("learned (opencv candidates)" if f else r) for f, r in zip(out.found.tolist(), out.reasons)]
        return out

    @torch.no_grad()
    def detect_level(
        self, images: torch.Tensor, board_size: tuple[int, int], full: torch.Tensor | None = None,
        scale: torch.Tensor | None = None, source: str = "network", resampled: bool | None = None,
    ) -> DetectionResult:
        """Detect the board at the resolution of ``images`` :math:`(B, 1, H, W)` (float); corners in grid order.

        ``full`` and ``scale``: see :meth:`candidates`. ``source``: the corner candidates, ``"network"`` (the heatmap's
        peaks) or ``"opencv"`` (OpenCV's classic detector, :meth:`_opencv_board`). ``resampled``: the level is a
        resampled copy whose corners are refined again at full size (no wide polish here; default: ``full`` given).
        """
        if source == "opencv":
            return self._opencv_board(images, board_size)
        _, points, keep = self.candidates(images, full, scale)
        corners, valid, found = _organize(points, keep, board_size, images,
                                          PARTIAL_BOARD_FRACTION if self.partial_boards else None)
        refiner = self.refiner
        if resampled is None:
            resampled = full is not None
        if refiner is not None and resampled:  # a resampled level: its corners are refined again at full size
            refiner = copy.copy(refiner)
            refiner.wide = False
        return self._complete(images, board_size, corners, valid, found, refiner)

    def _complete(self, images: torch.Tensor, board_size: tuple[int, int], corners: torch.Tensor, valid: torch.Tensor,
                  found: torch.Tensor, refiner: CornerRefiner | None = None) -> DetectionResult:
        """Organised boards -> complete, refined boards: missing cells predicted and confirmed on the image
        (``refiner``: default, the detector's)."""
        refiner = self.refiner if refiner is None else refiner
        reasons = ["learned" if f else "board not found" for f in found.tolist()]
        if self.collinearity:
            corners, valid = collinearity_refine(corners, valid & found[:, None], board_size)
        # cells the network missed: predict them from their grid neighbours (local, follows distortion)
        # instead of keeping the organiser's global-homography guess
        missing = found[:, None] & ~valid
        if bool(missing.any()):
            with stage("missing corners"):
                corners, _ = predict_missing_corners(corners, valid, board_size)
                # extrapolated cells can be off by a good part of a square under strong distortion: a coarse
                # search first, then the regular saddle refinement below polishes
                corners = _coarse_search(images, corners, missing, found[:, None].expand_as(valid), board_size)
        cells = found[:, None].expand_as(valid)  # every cell of a found board
        hidden = torch.zeros_like(valid)
        if refiner is not None and bool(found.any()):
            with stage("saddle refinement"):
                corners, ok = refiner(images, corners, cells, board_size, return_ok=True)
            # a predicted cell is accepted only where the image shows a corner there (corner_evidence.py: the
            # board is dropped, or the corner left out where the checker has faded: glare, an occluder)
            evidence = measure_corner_evidence(images, corners, cells, missing, ok, valid, board_size,
                                               contrast=self.partial_boards)
            hidden, refusing = decide_corners(evidence, board_size)
            unverified = refusing.any(1)
            for b in unverified.nonzero().flatten().tolist():
                reasons[b] = f"board incomplete: {int(refusing[b].sum())} corner(s) not confirmed in the image"
            found = found & ~unverified
            # a partial board is checked for skipped lines here already, so that a refused lattice through every
            # other corner (a level where one parity of the corners lost its peaks: ChArUco renders) leaves the
            # other levels and looks their turn (forward's final check would refuse it with nothing else tried)
            for b in (found & hidden.any(1)).nonzero().flatten().tolist():
                shown = corners[b].masked_fill(hidden[b, :, None], float("nan"))
                reason = whole_board_check(images[b, 0].float().cpu().numpy(), shown.double().cpu().numpy(), board_size,
                                           extends=False)
                if reason:
                    found[b], reasons[b] = False, f"board refused: {reason}"
        corners = torch.where(found[:, None, None], corners, torch.zeros_like(corners))
        corners = corners.masked_fill(hidden[..., None] & found[:, None, None], float("nan"))
        return DetectionResult(corners=corners.float(), found=found, reasons=reasons)


def chessboard_copies(gray8: np.ndarray) -> list[tuple[str, np.ndarray, float]]:
    """The enhanced copies of a ``uint8`` grey image ``(H, W)`` (:func:`~ccs_kornia.modules.detection.enhanced_copies.
    enhanced_copies`) that the learned detector looks at where the image gave no board, each with its name and its
    scale to the image: the stretched copy where the image is dim (its 1st to 99th percentiles span fewer than
    :data:`DIM_SPAN` grey levels), the enlarged copy where it is small (at most :data:`SMALL_PIXELS` pixels), the
    deblurred copy where it shows a straight motion blur
    (:func:`~ccs_kornia.modules.detection.motion_deblur.motion_blur`: a board smeared along a line loses its corners'
    peaks across it); none for an image that is none of these (a board-free photograph pays for its cepstrum only).

    Example:
        >>> dim = np.tile(np.arange(20, dtype=np.uint8), (8, 1))
        >>> [(name, c.shape, s) for name, c, s in chessboard_copies(dim)]
        [('stretched', (8, 20), 1.0), ('enlarged', (16, 40), 2.0)]
        >>> chessboard_copies(np.tile(np.arange(0, 250, 5, dtype=np.uint8), (600, 10)))
        []
    """
    lo, hi = np.percentile(gray8, (1.0, 99.0))
    if hi <= lo:
        return []
    dim, small = hi - lo < DIM_SPAN, gray8.size <= SMALL_PIXELS
    out = []
    if dim or small:
        stretched, _, *enlarged = enhanced_copies(gray8, enlarge=small)
        out = ([("stretched", *stretched)] if dim else []) + [("enlarged", *e) for e in enlarged]
    blur = motion_blur(gray8)
    if blur is not None:
        out.append(("deblurred", deblur_motion(gray8, *blur), 1.0))
    return out


def _empty_result(images: torch.Tensor, board_size: tuple[int, int]) -> DetectionResult:
    n = board_size[0] * board_size[1]
    return DetectionResult(corners=images.new_zeros(0, n, 2, dtype=torch.float32),
                           found=torch.zeros(0, dtype=torch.bool, device=images.device), reasons=[])


def _organize(points: torch.Tensor, keep: torch.Tensor, board_size: tuple[int, int], images: torch.Tensor,
              partial_fraction: float | None = None):
    """:func:`organize_grid`, then again with the wide-lens tolerance where no board was found: strongly distorted
    close-ups bend the lattice more than the strict neighbour check allows (every corner is still verified on the
    image afterwards); then, with ``partial_fraction``, again accepting a board of which only that fraction of the
    corners has a peak (a glare over the board's middle: the missing cells must then show no checker, see
    :meth:`LearnedChessboardDetector._complete`)."""
    with stage("grid organiser"):
        corners, valid, found = organize_grid(points, keep, board_size, images)
        retry = (~found).nonzero().flatten()
        if retry.numel():
            c2, v2, f2 = organize_grid(points[retry], keep[retry], board_size, images[retry], check_tolerance=0.25)
            corners[retry], valid[retry], found[retry] = c2, v2, f2
        retry = (~found).nonzero().flatten()
        if partial_fraction is not None and retry.numel():
            c2, v2, f2 = organize_grid(points[retry], keep[retry], board_size, images[retry],
                                       min_fraction=partial_fraction, partial=True)
            corners[retry], valid[retry], found[retry] = c2, v2, f2
    return corners, valid, found


def _coarse_search(images: torch.Tensor, corners: torch.Tensor, cells: torch.Tensor, spaced: torch.Tensor,
                   board_size: tuple[int, int]) -> torch.Tensor:
    """``corners`` with ``cells`` moved by the gradient-orthogonality fixed point, whose basin is the whole window
    (0.45 x the grid spacing measured over the ``spaced`` cells)."""
    spacing = grid_spacing(corners, spaced, board_size)
    coarse = refine_corners(images, corners, cells, 0.45 * spacing, method="gradient", iterations=10, max_radius=40)
    return torch.where(cells[..., None], coarse, corners)
