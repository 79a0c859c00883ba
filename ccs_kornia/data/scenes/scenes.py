"""Rendered data sets with exact ground truth: one camera's calibration set, and random training scenes."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from ccs_kornia.data.batching import (
    batched_argument,
    check_image_size,
    padded_object_points,
)
from ccs_kornia.data.random_draws import seeded_rand, seeded_randint, seeded_uniform
from ccs_kornia.data.render import augment
from ccs_kornia.data.render.lens import project_board
from ccs_kornia.data.render.renderer import render_chessboard, render_images
from ccs_kornia.data.scenes.sampling import (
    RADIAL_LEVELS,
    sample_opencv_distortion,
    sample_poses,
    sample_poses_batched,
    sample_radial_distortion,
)
from ccs_kornia.geometry import camera

__all__ = ["DISTORTION_MODES", "SyntheticBatch", "make_calibration_set", "SyntheticChessboards", "corner_validity"]

#: per-view distortion models of :class:`SyntheticChessboards`
DISTORTION_MODES: tuple[str, ...] = ("none", "opencv", "radial")


@dataclass
class SyntheticBatch:
    """Rendered images with their exact ground truth.

    Attributes:
        images: :math:`(B, 1, H, W)` float in ``[0, 1]``.
        corners: :math:`(B, N_{max}, 2)` distorted pixel coordinates of the inner corners in grid order
            ``n = j * cols + i``, zero-padded.
        corner_valid: :math:`(B, N_{max})` corner exists on the board and lies inside the image with margin.
        board_size: :math:`(B, 2)` long ``(cols, rows)``.
        square: :math:`(B,)` square side in world units.
        K: :math:`(B, 3, 3)`.
        dist: :math:`(B, 5)` OpenCV ``(k1, k2, p1, p2, k3)``; zeros if the view is not OpenCV-distorted.
        radial: :math:`(B, 3)` paper coefficients ``(k0, k1, k2)``; ``(1, 0, 0)`` if not radially distorted.
        rvec: :math:`(B, 3)` world-to-camera axis-angle rotation.
        tvec: :math:`(B, 3)` translation.
        image_size: ``(W, H)``.
        condition: optional :math:`(B,)` long index into :data:`ccs_kornia.data.render.augment.CONDITIONS`.
        fisheye: optional :math:`(B, 5)` Kannala-Brandt lens rows ``(k1, k2, k3, k4, theta_max)``
            (``theta_max = 0``: not a fisheye view), see :mod:`ccs_kornia.data.render.fisheye`.
        marks: optional :math:`(B,)` long index into :data:`ccs_kornia.data.render.marks.MARK_KINDS`.
    """

    images: Tensor
    corners: Tensor
    corner_valid: Tensor
    board_size: Tensor
    square: Tensor
    K: Tensor
    dist: Tensor
    radial: Tensor
    rvec: Tensor
    tvec: Tensor
    image_size: tuple[int, int]
    condition: Tensor | None = None
    fisheye: Tensor | None = None
    marks: Tensor | None = None

    def to(self, device: torch.device | str) -> SyntheticBatch:
        """Copy of the batch with every tensor on ``device``."""
        values = {}
        for f in fields(self):
            v = getattr(self, f.name)
            values[f.name] = v.to(device) if isinstance(v, Tensor) else v
        return SyntheticBatch(**values)

    def __len__(self) -> int:
        return int(self.images.shape[0])


def corner_validity(corners: Tensor, ok: Tensor, exists: Tensor, image_size, margin: float) -> Tensor:
    """The ground truth's ``corner_valid``: the corner exists on its board, the lens shows it (``ok``), its position
    is finite and it lies inside the image with ``margin`` pixels to spare.

    Args:
        corners: :math:`(B, N, 2)` distorted pixels.
        ok: :math:`(B, N)` bool, visible through the lens (:func:`~ccs_kornia.data.render.lens.project_board`).
        exists: :math:`(B, N)` bool, the corner exists (boards of different sizes are zero-padded).
        image_size: ``(W, H)``.
        margin: pixels a valid corner keeps from the image border.

    Returns:
        :math:`(B, N)` bool.

    Example:
        >>> corners = torch.tensor([[[10.0, 10.0], [1.0, 10.0], [10.0, float("nan")]]])
        >>> corner_validity(corners, torch.ones(1, 3, dtype=torch.bool), torch.ones(1, 3, dtype=torch.bool),
        ...                 (32, 24), 2.0).tolist()
        [[True, False, False]]
    """
    w, h = image_size
    x, y = corners[..., 0], corners[..., 1]
    inside = (x >= margin) & (x <= w - 1 - margin) & (y >= margin) & (y <= h - 1 - margin)
    return exists & ok & inside & torch.isfinite(corners).all(-1)


def make_calibration_set(
    K: Tensor,
    board_size: tuple[int, int] = (9, 6),
    square: float = 0.025,
    image_size: tuple[int, int] = (640, 480),
    num_views: int = 15,
    dist: Tensor | None = None,
    radial: Tensor | None = None,
    condition: str = "clean",
    seed: int = 0,
    supersample: int = 4,
    background: str = "texture",
    margin: float = 10.0,
    max_tilt_deg: float = 50.0,
    max_roll_deg: float = 45.0,
    fill_range: tuple[float, float] = (0.35, 0.8),
) -> SyntheticBatch:
    """Views of one board seen by one camera, as a calibration benchmark set.

    Args:
        K: :math:`(3, 3)` camera matrix.
        board_size: ``(cols, rows)`` inner corners.
        square: square side in world units.
        image_size: ``(W, H)``.
        num_views: number of images.
        dist: optional OpenCV coefficients :math:`(5,)`.
        radial: optional paper coefficients :math:`(3,)` (e.g. from :func:`sample_radial_distortion`).
        condition: one of :data:`ccs_kornia.data.render.augment.CONDITIONS`.
        seed: fixes poses, background and degradations.
        supersample: renderer sub-cells per pixel side.
        background: ``texture`` (procedural clutter) or ``plain`` (uniform grey 0.5).
        margin, max_tilt_deg, max_roll_deg, fill_range: pose sampling (see :func:`sample_poses`).

    Returns:
        :class:`SyntheticBatch` with ``B = num_views`` (all corners valid).

    Example:
        >>> K = torch.tensor([[300., 0, 159.5], [0, 300, 119.5], [0, 0, 1]])
        >>> batch = make_calibration_set(K, (6, 4), image_size=(320, 240), num_views=2, supersample=1)
        >>> batch.images.shape, bool(batch.corner_valid.all())
        (torch.Size([2, 1, 240, 320]), True)
    """
    if condition not in augment.CONDITIONS:
        raise ValueError(f"Unknown condition {condition!r}; expected one of {augment.CONDITIONS}.")
    if background not in ("texture", "plain"):
        raise ValueError(f"background must be 'texture' or 'plain', got {background!r}.")
    K = torch.as_tensor(K, dtype=torch.float32)
    if K.shape != (3, 3):
        raise ValueError(f"make_calibration_set takes one (3, 3) camera matrix, got {tuple(K.shape)}.")
    w, h = check_image_size(image_size)
    b = int(num_views)
    gen = torch.Generator().manual_seed(int(seed))
    dist_b = batched_argument(dist, b, (5,), "dist", "cpu", torch.float32)
    radial_b = batched_argument(radial, b, (3,), "radial", "cpu", torch.float32)
    rvec, tvec = sample_poses(
        K, board_size, square, (w, h), b, gen, dist_b, radial_b, margin=margin, max_tilt_deg=max_tilt_deg,
        fill_range=fill_range, max_roll_deg=max_roll_deg,
    )
    bg = augment.textured_background(b, (w, h), gen) if background == "texture" else 0.5
    Kb = K.expand(b, 3, 3).contiguous()
    images, corners = render_chessboard(Kb, rvec, tvec, board_size, square, (w, h), dist_b, radial_b, supersample, bg)
    images = augment.apply_condition(images, condition, gen)
    cols, rows = int(board_size[0]), int(board_size[1])
    exists = torch.ones(b, cols * rows, dtype=torch.bool)
    valid = corner_validity(corners, torch.ones_like(exists), exists, (w, h), 0.0)
    return SyntheticBatch(
        images=images,
        corners=corners,
        corner_valid=valid,
        board_size=torch.tensor([cols, rows], dtype=torch.long).expand(b, 2).clone(),
        square=torch.full((b,), float(square)),
        K=Kb,
        dist=torch.zeros(b, 5) if dist_b is None else dist_b.clone(),
        radial=torch.tensor([1.0, 0.0, 0.0]).expand(b, 3).clone() if radial_b is None else radial_b.clone(),
        rvec=rvec,
        tvec=tvec,
        image_size=(w, h),
        condition=torch.full((b,), augment.CONDITIONS.index(condition), dtype=torch.long),
    )


class SyntheticChessboards:
    """Random chessboard scenes for training and benchmarks: varied cameras, boards, poses, distortion,
    backgrounds and image conditions, with exact ground truth.

    Args:
        image_size: ``(W, H)``.
        board_cols, board_rows: inclusive ranges of inner corners per row / rows.
        fx_range: focal length range in pixels; ``fy = fx * aspect`` with ``aspect ~ U[aspect_range]``.
        pp_jitter: principal point offset from the image centre, as a fraction of ``W`` and ``H``.
        distortion: ``none``, ``opencv``, ``radial``, ``mixed`` (one of the three per view), or a tuple of
            modes drawn uniformly per view.
        radial_level: level for radially distorted views (``any``, ``none``, ``level1``/``mild``,
            ``level2``, ``severe``); see :func:`sample_radial_distortion`.
        conditions: image conditions drawn uniformly per view (:data:`~ccs_kornia.data.render.augment.CONDITIONS`).
        partial_prob: probability that a board may extend beyond the image (at least 30 % of its corners
            stay inside; the others get ``corner_valid = False``).
        supersample: renderer sub-cells per pixel side.
        margin: pixels a valid corner keeps from the image border.
        max_tilt_deg, max_roll_deg, fill_range: pose sampling.
        square_range: square side range in world units.
        dark_range, light_range: grey levels of the dark and light squares.

    Example:
        >>> data = SyntheticChessboards(image_size=(96, 64), board_cols=(4, 5), board_rows=(3, 4), supersample=1)
        >>> batch = data.sample(2, torch.Generator().manual_seed(0))
        >>> batch.images.shape, batch.corners.shape
        (torch.Size([2, 1, 64, 96]), torch.Size([2, 20, 2]))
    """

    def __init__(
        self,
        image_size: tuple[int, int] = (640, 480),
        board_cols: tuple[int, int] = (4, 12),
        board_rows: tuple[int, int] = (3, 9),
        fx_range: tuple[float, float] = (300.0, 900.0),
        aspect_range: tuple[float, float] = (0.95, 1.05),
        pp_jitter: float = 0.08,
        distortion: str | tuple[str, ...] = "mixed",
        radial_level: str = "any",
        conditions: tuple[str, ...] = ("clean", "blur_noise", "bad_lighting", "combined"),
        partial_prob: float = 0.0,
        supersample: int = 3,
        margin: float = 4.0,
        max_tilt_deg: float = 50.0,
        max_roll_deg: float = 180.0,
        fill_range: tuple[float, float] = (0.25, 0.8),
        square_range: tuple[float, float] = (0.02, 0.04),
        dark_range: tuple[float, float] = (0.0, 0.3),
        light_range: tuple[float, float] = (0.65, 1.0),
    ) -> None:
        self.image_size = check_image_size(image_size)
        if board_cols[0] < 2 or board_rows[0] < 2 or board_cols[1] < board_cols[0] or board_rows[1] < board_rows[0]:
            raise ValueError(f"Invalid board ranges cols={board_cols}, rows={board_rows} (need 2 <= low <= high).")
        self.board_cols, self.board_rows = (int(board_cols[0]), int(board_cols[1])), (int(board_rows[0]), int(board_rows[1]))
        self.fx_range, self.aspect_range, self.pp_jitter = tuple(fx_range), tuple(aspect_range), float(pp_jitter)
        if isinstance(distortion, str):
            modes = DISTORTION_MODES if distortion == "mixed" else (distortion,)
        else:
            modes = tuple(distortion)
        for mode in modes:
            if mode not in DISTORTION_MODES:
                raise ValueError(f"Unknown distortion {mode!r}; expected one of {(*DISTORTION_MODES, 'mixed')}.")
        self.modes = modes
        if radial_level not in (*RADIAL_LEVELS, "mild", "any"):
            raise ValueError(f"Unknown radial_level {radial_level!r}.")
        self.radial_level = radial_level
        for c in conditions:
            if c not in augment.CONDITIONS:
                raise ValueError(f"Unknown condition {c!r}; expected some of {augment.CONDITIONS}.")
        if len(conditions) == 0:
            raise ValueError("conditions must not be empty.")
        self.conditions = tuple(conditions)
        if not 0.0 <= partial_prob <= 1.0:
            raise ValueError(f"partial_prob must be in [0, 1], got {partial_prob}.")
        self.partial_prob = float(partial_prob)
        self.supersample = int(supersample)
        self.margin, self.max_tilt_deg, self.max_roll_deg = float(margin), float(max_tilt_deg), float(max_roll_deg)
        self.fill_range, self.square_range = tuple(fill_range), tuple(square_range)
        self.dark_range, self.light_range = tuple(dark_range), tuple(light_range)

    @property
    def max_corners(self) -> int:
        """``N_max`` of every batch: corners of the largest board."""
        return self.board_cols[1] * self.board_rows[1]

    def sample(self, batch_size: int, generator: torch.Generator, device: torch.device | str = "cpu") -> SyntheticBatch:
        """Draw and render ``batch_size`` random views (deterministic for a given generator state).

        Scene parameters are drawn on the generator's device (CPU recommended), rendering happens on ``device``.
        """
        b = int(batch_size)
        if b < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}.")
        w, h = self.image_size
        g = generator
        fx = seeded_uniform(g, (b,), *self.fx_range, "cpu")
        fy = fx * seeded_uniform(g, (b,), *self.aspect_range, "cpu")
        cx = (w - 1) / 2 + self.pp_jitter * w * seeded_uniform(g, (b,), -1.0, 1.0, "cpu")
        cy = (h - 1) / 2 + self.pp_jitter * h * seeded_uniform(g, (b,), -1.0, 1.0, "cpu")
        K = camera.intrinsics_matrix(torch.stack([fx, fy, cx, cy], -1))
        cols = seeded_randint(g, *self.board_cols, (b,), "cpu")
        rows = seeded_randint(g, *self.board_rows, (b,), "cpu")
        square = seeded_uniform(g, (b,), *self.square_range, "cpu")
        mode = seeded_randint(g, 0, len(self.modes) - 1, (b,), "cpu")
        dist = torch.zeros(b, 5, dtype=torch.float64)
        radial = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).repeat(b, 1)
        for k, name in enumerate(self.modes):
            idx = (mode == k).nonzero().squeeze(1)
            if idx.numel() == 0 or name == "none":
                continue
            if name == "opencv":
                dist[idx] = sample_opencv_distortion(K[idx], (w, h), idx.numel(), g).double()
            else:
                radial[idx] = sample_radial_distortion(idx.numel(), self.radial_level, (w, h), g).double()
        cond = seeded_randint(g, 0, len(self.conditions) - 1, (b,), "cpu")
        partial = seeded_rand(g, (b,), "cpu") < self.partial_prob
        dark = seeded_uniform(g, (b,), *self.dark_range, "cpu")
        light = torch.maximum(seeded_uniform(g, (b,), *self.light_range, "cpu"), dark + 0.3)
        rvec, tvec = sample_poses_batched(
            K, cols, rows, square, (w, h), g, dist, radial, self.margin, self.max_tilt_deg, self.fill_range,
            self.max_roll_deg, min_square_px=5.0, partial=partial,
        )
        background = augment.textured_background(b, (w, h), g, device=device)
        f32 = dict(device=device, dtype=torch.float32)
        Kf, rf, tf, sf = K.to(**f32), rvec.to(**f32), tvec.to(**f32), square.to(**f32)
        distf, radf = dist.to(**f32), radial.to(**f32)
        cols_d, rows_d = cols.to(device), rows.to(device)
        images = render_images(
            Kf, rf, tf, cols_d, rows_d, sf, (w, h), distf, radf, self.supersample, background, 1.0,
            dark.to(**f32), light.to(**f32),
        )
        # ground truth in float64 from the float32 parameters actually rendered
        obj, exists = padded_object_points(cols_d, rows_d, sf.double(), self.max_corners)
        pix, ok = project_board(obj, Kf.double(), rf.double(), tf.double(), (w, h), distf.double(), radf.double())
        valid = corner_validity(pix, ok, exists, (w, h), self.margin)
        corners = torch.where(exists.unsqueeze(-1) & torch.isfinite(pix), pix, torch.zeros_like(pix)).to(torch.float32)
        cond_d = cond.to(device)
        for k, name in enumerate(self.conditions):
            idx = (cond_d == k).nonzero().squeeze(1)
            if idx.numel() and name != "clean":
                images[idx] = augment.apply_condition(images[idx], name, g)
        global_cond = torch.tensor([augment.CONDITIONS.index(c) for c in self.conditions], dtype=torch.long)[cond]
        return SyntheticBatch(
            images=images,
            corners=corners,
            corner_valid=valid,
            board_size=torch.stack([cols_d, rows_d], -1),
            square=sf,
            K=Kf,
            dist=distf,
            radial=radf,
            rvec=rf,
            tvec=tf,
            image_size=(w, h),
            condition=global_cond.to(device),
        )
