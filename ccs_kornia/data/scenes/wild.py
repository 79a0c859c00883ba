"""Chessboards in the wild: every square size, image size, lens, mark, blur and light a user's photos show.

:class:`WildChessboards` draws scenes far outside the 640x480 comfort zone of
:class:`~ccs_kornia.data.scenes.scenes.SyntheticChessboards`, with the same exact ground truth: squares of 8 to 300 px
(log-uniform, the distance set from the square size), images from 320x240 to 6000x4000 (rendered in bands,
memory-bounded), strong perspective (tilt up to 75 degrees), boards whose outer squares or corners leave the
image, pinhole / OpenCV / the paper's radial / Kannala-Brandt fisheye lenses (fields of view 120-200 degrees),
ArUco-like or dot / tile marks in the light squares, and the camera chain of :func:`ccs_kornia.data.render.optics.apply_optics`
(shadows, glare, box / Gaussian / motion blur scaled to the square size, a 0.3-1 px optical point spread,
noise, gamma, JPEG). Every option is a parameter, so training configurations and the ``wild`` benchmark use
the same sampler.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import torch

from ccs_kornia.data.batching import padded_object_points
from ccs_kornia.data.random_draws import seeded_randint, seeded_uniform
from ccs_kornia.data.render import augment
from ccs_kornia.data.render.fisheye import (
    is_fisheye,
    sample_fisheye_cameras,
    sample_fisheye_poses,
)
from ccs_kornia.data.render.lens import project_board
from ccs_kornia.data.render.marks import MARK_KINDS, make_marks
from ccs_kornia.data.render.optics import BLUR_KINDS, apply_optics, square_size_px
from ccs_kornia.data.render.renderer import render_images
from ccs_kornia.data.scenes.sampling import (
    sample_opencv_distortion,
    sample_poses_batched,
    sample_radial_distortion,
)
from ccs_kornia.data.scenes.scenes import SyntheticBatch, corner_validity
from ccs_kornia.geometry import camera

__all__ = ["LENSES", "WildSpec", "WildChessboards"]

#: lens kinds of :class:`WildSpec`
LENSES: tuple[str, ...] = ("pinhole", "opencv", "radial", "fisheye")


@dataclass(frozen=True)
class WildSpec:
    """What :class:`WildChessboards` draws (ranges are inclusive; tuples of names are drawn uniformly per view).

    Attributes:
        image_sizes: ``(W, H)`` sizes; one is drawn per batch.
        board_cols, board_rows: inner-corner ranges.
        square_px: range of the square size in px (log-uniform; a fronto-parallel square at the board's distance),
            clamped so that the board fits the image unless it may be cut.
        fx_over_w: pinhole focal length as a fraction of the image width.
        min_tilt_deg, max_tilt_deg, max_roll_deg: board orientation.
        lenses: per-view lens kinds of :data:`LENSES`.
        radial_level: level of ``radial`` views (:func:`~ccs_kornia.data.scenes.sampling.sample_radial_distortion`).
        fov_deg: fisheye field-of-view range; fisheye_span_deg: angle the board spans; fisheye_border_bias: below 1
            puts fisheye boards near the edge of the field (see :func:`~ccs_kornia.data.render.fisheye.sample_fisheye_poses`).
        partial_prob: probability that some inner corners leave the image (their ``corner_valid`` is False).
        cut_prob: probability that all inner corners stay inside while the outer squares cross the border.
        marks: per-view kinds of :data:`~ccs_kornia.data.render.marks.MARK_KINDS`.
        aruco_fill, dot_fill: ArUco marker side / dot area fraction ranges.
        blur: per-view kinds of :data:`~ccs_kornia.data.render.optics.BLUR_KINDS`; blur_fraction: width / square size.
        psf_sigma, gamma: the optical point spread (px) and tone curve applied to every view.
        glare_prob, shadow_prob: probabilities of a saturating glare / a soft shadow on the board.
        noise_sigma: read-noise range; jpeg_prob and jpeg_quality: JPEG compression.
        lighting_prob: probability of the Phong shading + vignetting of ``augment``'s ``bad_lighting``.
        background: ``texture`` (procedural clutter) or ``plain``.
        border_squares: range of the light margin around the checker area, in squares (uniform per view; the
            default ``(1, 1)`` draws nothing). Thin margins against a dark surround are where a detector working on
            a coarse level sees an extra row of false corners.
        surround_prob: probability that the surround (the background outside the board's margin) becomes a flat
            grey level drawn from ``surround_level``, independent of the board's paper (dark frames, tablets, dark
            tables, white walls), keeping ``surround_texture`` (fraction range) of the clutter's contrast.
        supersample: renderer sub-cells per pixel side.
        margin: px a valid corner keeps from the border.
        min_square_px: smallest spacing between neighbouring corners accepted by the pose sampler.
    """

    image_sizes: tuple[tuple[int, int], ...] = ((640, 480),)
    board_cols: tuple[int, int] = (4, 11)
    board_rows: tuple[int, int] = (3, 8)
    square_px: tuple[float, float] = (12.0, 60.0)
    fx_over_w: tuple[float, float] = (0.6, 1.4)
    min_tilt_deg: float = 0.0
    max_tilt_deg: float = 60.0
    max_roll_deg: float = 180.0
    lenses: tuple[str, ...] = ("pinhole",)
    radial_level: str = "any"
    fov_deg: tuple[float, float] = (120.0, 200.0)
    fisheye_span_deg: tuple[float, float] = (25.0, 100.0)
    fisheye_border_bias: float = 0.5
    partial_prob: float = 0.0
    cut_prob: float = 0.0
    marks: tuple[str, ...] = ("none",)
    aruco_fill: tuple[float, float] = (0.5, 0.85)
    dot_fill: tuple[float, float] = (0.1, 0.4)
    blur: tuple[str, ...] = ("none",)
    blur_fraction: tuple[float, float] = (0.0, 0.3)
    psf_sigma: tuple[float, float] = (0.3, 1.0)
    gamma: tuple[float, float] = (1.8, 2.4)
    glare_prob: float = 0.0
    shadow_prob: float = 0.0
    noise_sigma: tuple[float, float] = (0.0, 0.01)
    jpeg_prob: float = 0.0
    jpeg_quality: tuple[int, int] = (30, 90)
    lighting_prob: float = 0.0
    background: str = "texture"
    border_squares: tuple[float, float] = (1.0, 1.0)
    surround_prob: float = 0.0
    surround_level: tuple[float, float] = (0.0, 1.0)
    surround_texture: tuple[float, float] = (0.0, 0.5)
    supersample: int = 2
    margin: float = 4.0
    min_square_px: float = 5.0

    def __post_init__(self) -> None:
        for name, allowed in (("lenses", LENSES), ("marks", MARK_KINDS), ("blur", BLUR_KINDS)):
            values = getattr(self, name)
            if not values or any(v not in allowed for v in values):
                raise ValueError(f"{name} must be a non-empty tuple of {allowed}, got {values}.")
        if self.background not in ("texture", "plain"):
            raise ValueError(f"background must be 'texture' or 'plain', got {self.background!r}.")
        if not 0 < self.square_px[0] <= self.square_px[1]:
            raise ValueError(f"square_px must satisfy 0 < low <= high, got {self.square_px}.")
        if not 0 <= self.border_squares[0] <= self.border_squares[1]:
            raise ValueError(f"border_squares must satisfy 0 <= low <= high, got {self.border_squares}.")
        if not 0 <= self.surround_prob <= 1:
            raise ValueError(f"surround_prob must be in [0, 1], got {self.surround_prob}.")

    def replace(self, **changes) -> WildSpec:
        return replace(self, **changes)

    def to_dict(self) -> dict:
        return asdict(self)


def _pick(g: torch.Generator, names: tuple[str, ...], b: int) -> list[str]:
    idx = seeded_randint(g, 0, len(names) - 1, (b,), "cpu")
    return [names[int(i)] for i in idx]


class WildChessboards:
    """Random chessboard scenes from a :class:`WildSpec`, with exact ground truth.

    Example:
        >>> spec = WildSpec(image_sizes=((160, 120),), board_cols=(4, 5), board_rows=(3, 4), square_px=(10, 20),
        ...                 supersample=1, lenses=("pinhole", "fisheye"), marks=("aruco",))
        >>> batch = WildChessboards(spec).sample(2, torch.Generator().manual_seed(0))
        >>> batch.images.shape, batch.corners.shape
        (torch.Size([2, 1, 120, 160]), torch.Size([2, 20, 2]))
    """

    def __init__(self, spec: WildSpec | None = None, **overrides) -> None:
        self.spec = (spec or WildSpec()).replace(**overrides) if overrides else (spec or WildSpec())

    @property
    def max_corners(self) -> int:
        return self.spec.board_cols[1] * self.spec.board_rows[1]

    def sample(self, batch_size: int, generator: torch.Generator, device: torch.device | str = "cpu") -> SyntheticBatch:
        """Draw and render ``batch_size`` views (deterministic for a generator state); parameters are drawn on
        the CPU, rendering happens on ``device``."""
        sp, g, b = self.spec, generator, int(batch_size)
        if b < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}.")
        w, h = sp.image_sizes[int(seeded_randint(g, 0, len(sp.image_sizes) - 1, (1,), "cpu"))]
        cols = seeded_randint(g, *sp.board_cols, (b,), "cpu")
        rows = seeded_randint(g, *sp.board_rows, (b,), "cpu")
        lens = _pick(g, sp.lenses, b)
        views_of = {kind: [k for k, n in enumerate(lens) if n == kind] for kind in LENSES}  # per lens kind
        fe_mask = torch.zeros(b, dtype=torch.bool)
        fe_mask[views_of["fisheye"]] = True
        # pinhole cameras (every view; fisheye views replace theirs)
        fx = w * seeded_uniform(g, (b,), *sp.fx_over_w, "cpu")
        fy = fx * seeded_uniform(g, (b,), 0.97, 1.03, "cpu")
        cx = (w - 1) / 2 + 0.04 * w * seeded_uniform(g, (b,), -1.0, 1.0, "cpu")
        cy = (h - 1) / 2 + 0.04 * h * seeded_uniform(g, (b,), -1.0, 1.0, "cpu")
        K = camera.intrinsics_matrix(torch.stack([fx, fy, cx, cy], -1))
        K_pin = K.clone()
        fisheye = torch.zeros(b, 5, dtype=torch.float64)
        fidx = fe_mask.nonzero().squeeze(1)
        if fidx.numel():
            Kf, fe = sample_fisheye_cameras(fidx.numel(), (w, h), g, fov_range=sp.fov_deg)
            K[fidx], fisheye[fidx] = Kf, fe
        dist = torch.zeros(b, 5, dtype=torch.float64)
        radial = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).repeat(b, 1)
        for name in ("opencv", "radial"):
            idx = torch.tensor(views_of[name], dtype=torch.long)
            if idx.numel() and name == "opencv":
                dist[idx] = sample_opencv_distortion(K[idx], (w, h), idx.numel(), g).double()
            elif idx.numel():
                radial[idx] = sample_radial_distortion(idx.numel(), sp.radial_level, (w, h), g).double()
        square = seeded_uniform(g, (b,), 0.02, 0.04, "cpu")
        partial = seeded_uniform(g, (b,), 0.0, 1.0, "cpu") < sp.partial_prob
        cut = (seeded_uniform(g, (b,), 0.0, 1.0, "cpu") < sp.cut_prob) & ~partial
        lo, hi = math.log(sp.square_px[0]), math.log(sp.square_px[1])
        sq_px = seeded_uniform(g, (b,), lo, hi, "cpu").exp()
        fit = torch.minimum(torch.full((b,), float(w)), torch.full((b,), float(h))) / torch.hypot(
            (cols + 1).double(), (rows + 1).double()) * 0.95
        sq_px = torch.where(partial | cut, sq_px, torch.minimum(sq_px, fit))
        rvec, tvec = torch.zeros(b, 3, dtype=torch.float64), torch.zeros(b, 3, dtype=torch.float64)
        done = torch.ones(b, dtype=torch.bool)
        pidx = (~fe_mask).nonzero().squeeze(1)
        if pidx.numel():
            rvec[pidx], tvec[pidx], done[pidx] = sample_poses_batched(
                K[pidx], cols[pidx], rows[pidx], square[pidx], (w, h), g, dist[pidx], radial[pidx], sp.margin,
                sp.max_tilt_deg, (0.3, 0.8), sp.max_roll_deg, sp.min_square_px, partial=partial[pidx],
                square_px=sq_px[pidx], min_tilt_deg=sp.min_tilt_deg, cut=cut[pidx], max_rounds=100, strict=False,
            )
        if fidx.numel():
            rvec[fidx], tvec[fidx], done[fidx] = sample_fisheye_poses(
                K[fidx], fisheye[fidx], cols[fidx], rows[fidx], square[fidx], (w, h), g, max_tilt_deg=sp.max_tilt_deg,
                span_deg=sp.fisheye_span_deg, border_bias=sp.fisheye_border_bias, margin=sp.margin,
                min_square_px=sp.min_square_px, partial=partial[fidx], strict=False,
            )
        if not bool(done.all()):
            # a board that cannot be placed as drawn (e.g. a cut view of a big board at large squares, or a
            # spacing the lens cannot give) must not end the batch: retry it as a full, less tilted view of
            # squares that fit, then place it fronto-parallel and centred without lens distortion
            self._fallback_poses(~done, K, K_pin, dist, radial, fisheye, cols, rows, square, sq_px, fit, rvec, tvec,
                                 (w, h), g)
            fidx = is_fisheye(fisheye).nonzero().squeeze(1)
        mark_names = _pick(g, sp.marks, b)
        mark_kind = torch.tensor([MARK_KINDS.index(m) for m in mark_names], dtype=torch.long)
        fill = torch.where(mark_kind == MARK_KINDS.index("aruco"), seeded_uniform(g, (b,), *sp.aruco_fill, "cpu"),
                           seeded_uniform(g, (b,), *sp.dot_fill, "cpu"))
        marks = make_marks(mark_kind, cols, rows, g, fill, device=device) if bool((mark_kind > 0).any()) else None
        # linear reflectances (printed black 0-10 %, paper 50-100 %): the gamma of the camera chain lifts them
        dark = seeded_uniform(g, (b,), 0.0, 0.1, "cpu")
        light = torch.maximum(seeded_uniform(g, (b,), 0.5, 1.0, "cpu"), dark + 0.35)
        bg = augment.textured_background(b, (w, h), g, device=device) if sp.background == "texture" else 0.5
        # margin and surround (drawn only when asked for, so the default spec's stream is unchanged)
        border: float | torch.Tensor = 1.0
        if tuple(sp.border_squares) != (1.0, 1.0):
            border = seeded_uniform(g, (b,), *sp.border_squares, "cpu").float()
        if sp.surround_prob > 0:
            bg = self._surround(bg, b, (w, h), g, device)
        f32 = dict(device=device, dtype=torch.float32)
        Kf, rf, tf, sf = K.to(**f32), rvec.to(**f32), tvec.to(**f32), square.to(**f32)
        distf, radf = dist.to(**f32), radial.to(**f32)
        fe_d = fisheye.to(device) if fidx.numel() else None
        images = render_images(Kf, rf, tf, cols.to(device), rows.to(device), sf, (w, h), distf, radf, sp.supersample, bg, border,
                         dark.to(**f32), light.to(**f32), fe_d, marks)
        obj, exists = padded_object_points(cols, rows, sf.double().cpu(), self.max_corners)
        pix, ok = project_board(obj, Kf.double().cpu(), rf.double().cpu(), tf.double().cpu(), (w, h), distf.double().cpu(),
                                radf.double().cpu(), None if fe_d is None else fisheye)
        valid = corner_validity(pix, ok, exists, (w, h), sp.margin)
        corners = torch.where(exists.unsqueeze(-1) & torch.isfinite(pix), pix, torch.zeros_like(pix))
        board_size = torch.stack([cols, rows], -1)
        images = self._camera(images, g, corners, valid, board_size)
        return SyntheticBatch(
            images=images, corners=corners.to(**f32), corner_valid=valid.to(device), board_size=board_size.to(device),
            square=sf, K=Kf, dist=distf, radial=radf, rvec=rf, tvec=tf, image_size=(w, h),
            fisheye=fisheye.to(**f32), marks=mark_kind.to(device),
        )

    def _fallback_poses(self, fail, K, K_pin, dist, radial, fisheye, cols, rows, square, sq_px, fit, rvec, tvec,
                        size: tuple[int, int], g: torch.Generator) -> None:
        """Poses (in place) for the views ``fail`` (B,) the sampler could not place: first a retry as full views
        (no partial / cut) with squares that fit, tilt up to 45 degrees, the spec's margin and spacing; what
        still fails becomes a pinhole view (distortion and fisheye removed) of the board fronto-parallel and
        centred, its inner corners spanning 60 % of the image (always inside, so sampling never raises)."""
        sp = self.spec
        w, h = size
        tilt = min(sp.max_tilt_deg, 45.0)
        fe = is_fisheye(fisheye)
        left = fail.clone()
        pidx = (fail & ~fe).nonzero().squeeze(1)
        if pidx.numel():
            rv, tv, ok = sample_poses_batched(
                K[pidx], cols[pidx], rows[pidx], square[pidx], size, g, dist[pidx], radial[pidx], sp.margin, tilt,
                (0.3, 0.8), sp.max_roll_deg, sp.min_square_px, square_px=torch.minimum(sq_px[pidx], fit[pidx]) * 0.8,
                max_rounds=20, strict=False,
            )
            rvec[pidx[ok]], tvec[pidx[ok]], left[pidx[ok]] = rv[ok], tv[ok], False
        fidx = (fail & fe).nonzero().squeeze(1)
        if fidx.numel():
            span = (sp.fisheye_span_deg[0], max(sp.fisheye_span_deg[0], 0.5 * sum(sp.fisheye_span_deg)))
            rv, tv, ok = sample_fisheye_poses(
                K[fidx], fisheye[fidx], cols[fidx], rows[fidx], square[fidx], size, g, max_tilt_deg=tilt,
                span_deg=span, border_bias=1.0, margin=sp.margin, min_square_px=sp.min_square_px, max_rounds=20,
                strict=False,
            )
            rvec[fidx[ok]], tvec[fidx[ok]], left[fidx[ok]] = rv[ok], tv[ok], False
        idx = left.nonzero().squeeze(1)
        if idx.numel() == 0:
            return
        K[idx], dist[idx], fisheye[idx] = K_pin[idx], 0.0, 0.0
        radial[idx] = torch.tensor([1.0, 0.0, 0.0], dtype=radial.dtype)
        c, r, s = cols[idx].double(), rows[idx].double(), square[idx].double()
        # inner corners span 60 % of the smaller image side (about the principal point, at most 4 % off centre)
        spacing = 0.6 * torch.minimum((w - 1) / (c - 1).clamp_min(1), (h - 1) / (r - 1).clamp_min(1))
        z = torch.sqrt(K[idx, 0, 0] * K[idx, 1, 1]) * s / spacing
        rvec[idx] = 0.0
        tvec[idx] = torch.stack([-(c - 1) * s / 2, -(r - 1) * s / 2, z], -1)

    def _surround(self, bg, b: int, size: tuple[int, int], g: torch.Generator, device) -> torch.Tensor:
        """Flat surrounds of independent grey level (with a little of the clutter's texture) for some views."""
        sp = self.spec
        pick = seeded_uniform(g, (b,), 0.0, 1.0, "cpu") < sp.surround_prob
        level = seeded_uniform(g, (b,), *sp.surround_level, "cpu").float().to(device).view(b, 1, 1, 1)
        keep = seeded_uniform(g, (b,), *sp.surround_texture, "cpu").float().to(device).view(b, 1, 1, 1)
        w, h = size
        if not isinstance(bg, torch.Tensor):
            bg = torch.full((b, 1, h, w), float(bg), device=device)
        flat = (level + keep * (bg - bg.mean(dim=(-2, -1), keepdim=True))).clamp(0.0, 1.0)
        return torch.where(pick.to(device).view(b, 1, 1, 1), flat, bg)

    def _camera(self, images, g, corners, valid, board_size):
        sp = self.spec
        b = images.shape[0]
        sq = square_size_px(corners, valid, board_size)
        vf = valid.double().unsqueeze(-1)
        centre = (corners * vf).sum(1) / vf.sum(1).clamp_min(1.0)
        span = torch.where(valid.unsqueeze(-1), corners, centre.unsqueeze(1)).amax(1) - \
            torch.where(valid.unsqueeze(-1), corners, centre.unsqueeze(1)).amin(1)
        size = span.norm(dim=-1).clamp_min(8.0)
        if sp.lighting_prob > 0:
            pick = (seeded_uniform(g, (b,), 0.0, 1.0, "cpu") < sp.lighting_prob).nonzero().squeeze(1)
            if pick.numel():
                images = images.clone()
                images[pick] = augment.vignetting(augment.phong_lighting(images[pick], g), g)
        jpeg = sp.jpeg_quality if sp.jpeg_prob > 0 else None
        out = apply_optics(
            images, g, sq, centre, size, blur=sp.blur, blur_fraction=sp.blur_fraction, psf_sigma=sp.psf_sigma,
            gamma=sp.gamma, glare_prob=sp.glare_prob, shadow_prob=sp.shadow_prob, noise_sigma=sp.noise_sigma,
        )
        if jpeg is not None:
            pick = (seeded_uniform(g, (b,), 0.0, 1.0, "cpu") < sp.jpeg_prob).nonzero().squeeze(1)
            if pick.numel():
                out[pick] = augment.jpeg(out[pick], g, quality=tuple(jpeg))
        return out
