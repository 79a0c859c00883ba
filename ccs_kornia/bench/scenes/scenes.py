"""Seeded benchmark scenes and the corner bookkeeping against their ground truth.

Everything here is deterministic for a given :class:`~ccs_kornia.bench.config.BenchConfig`: scenes are rendered
from seeds at :data:`ccs_kornia.data.datamodules.datamodule.BENCH_SEED_BASE` and above, which training and validation never
use. Every method sees the same images, quantised to 8 bits as a camera would deliver them (the OpenCV peers
get the ``uint8`` array, the torch methods the same values divided by 255).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from ccs_kornia.bench.config import (
    CONDITION_PARTS,
    OPTICS_CONDITIONS,
    SECTION_SEED_OFFSETS,
    BenchConfig,
)
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.data.scenes.sampling import sample_radial_distortion
from ccs_kornia.data.scenes.scenes import make_calibration_set

__all__ = ["Scenes", "render_scenes", "random_cameras", "quantize", "orient_grid", "lattice_orderings", "corner_errors"]


def quantize(images: torch.Tensor) -> torch.Tensor:
    """8-bit quantisation, as a camera delivers images: ``round(255 x) / 255``."""
    return torch.round(images.clamp(0, 1) * 255.0) / 255.0


def random_cameras(num: int, image_size: tuple[int, int], generator: torch.Generator) -> torch.Tensor:
    """Random pinhole cameras ``(num, 3, 3)``: fx in ``[0.7, 1.2] W``, fy/fx in ``[0.97, 1.03]``, principal
    point within 3 % of the image centre (independent fx, fy, cx, cy, as the design asks)."""
    w, h = image_size
    u = torch.rand(num, 4, generator=generator, dtype=torch.float64)
    fx = w * (0.7 + 0.5 * u[:, 0])
    fy = fx * (0.97 + 0.06 * u[:, 1])
    cx = (w - 1) / 2 + 0.03 * w * (2 * u[:, 2] - 1)
    cy = (h - 1) / 2 + 0.03 * h * (2 * u[:, 3] - 1)
    K = torch.zeros(num, 3, 3, dtype=torch.float64)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, cx, cy, 1.0
    return K


@dataclass
class Scenes:
    """Rendered views of ``C`` cameras with ``V`` views each, with exact ground truth.

    Attributes:
        images: :math:`(C, V, 1, H, W)` float in ``[0, 1]``, 8-bit quantised.
        corners: :math:`(C, V, N, 2)` true (distorted) corner pixels, float64.
        K: :math:`(C, 3, 3)` float64.
        radial: :math:`(C, 3)` the paper's radial coefficients of each camera (``(1, 0, 0)`` if none).
        condition: the condition name.
        render_seconds: wall time of the rendering.
    """

    images: torch.Tensor
    corners: torch.Tensor
    K: torch.Tensor
    radial: torch.Tensor
    condition: str
    render_seconds: float

    @property
    def flat_images(self) -> torch.Tensor:
        return self.images.reshape(-1, *self.images.shape[2:])

    @property
    def flat_corners(self) -> torch.Tensor:
        return self.corners.reshape(-1, *self.corners.shape[2:])


def render_scenes(
    cfg: BenchConfig, condition: str, cameras: int, views: int, section: str, radial: tuple[float, float, float] | None = None
) -> Scenes:
    """Render ``cameras x views`` images of ``cfg.board`` under a named condition.

    Args:
        cfg: benchmark configuration (image size, board, supersampling).
        condition: a key of the corner / calibration conditions (``clean``, ``blur_noise``, ``bad_lighting``,
            ``combined``, ``mild``/``level1``, ``level2``, ``severe``, and ``optics`` / ``optics_blur_noise``: ``clean``
            / ``blur_noise`` through the camera's last mile of the wild renders, see ``OPTICS_CONDITIONS``).
        cameras: number of random cameras.
        views: views per camera.
        section: section name (selects a disjoint seed range).
        radial: fixed radial coefficients for every camera (overrides the condition's level).

    Returns:
        :class:`Scenes`.
    """
    if condition not in CONDITION_PARTS:
        raise ValueError(f"Unknown condition {condition!r}; expected one of {sorted(CONDITION_PARTS)}.")
    photometric, level = CONDITION_PARTS[condition]
    # seed index: the older conditions in sorted order, the optics ones after them (their seeds never move)
    names = sorted(c for c in CONDITION_PARTS if c not in OPTICS_CONDITIONS) + list(OPTICS_CONDITIONS)
    cond_index = names.index(condition)
    base = BENCH_SEED_BASE + SECTION_SEED_OFFSETS[section] + 1000 * cond_index
    gen = torch.Generator().manual_seed(base)
    Ks = random_cameras(cameras, cfg.image_size, gen)
    if radial is not None:
        rad = torch.tensor(radial, dtype=torch.float32).expand(cameras, 3).clone()
    elif level is not None:
        rad = sample_radial_distortion(cameras, level, cfg.image_size, gen)
    else:
        rad = torch.tensor([1.0, 0.0, 0.0]).expand(cameras, 3).clone()
    t0 = time.perf_counter()
    imgs, pts = [], []
    for c in range(cameras):
        batch = make_calibration_set(
            Ks[c].float(), cfg.board, cfg.square, cfg.image_size, views,
            radial=rad[c] if (level is not None or radial is not None) else None,
            condition=photometric, seed=base + 1 + c, supersample=cfg.supersample,
        )
        images = batch.images
        if condition in OPTICS_CONDITIONS:
            from ccs_kornia.data.render.optics import apply_optics

            v = images.shape[0]  # no blur, glare or shadow: the square size and the board's place are not used
            images = apply_optics(images, torch.Generator().manual_seed(base + 501 + c), torch.zeros(v),
                                  torch.zeros(v, 2), torch.zeros(v), noise_sigma=(0.0, 0.01))
        imgs.append(quantize(images))
        pts.append(batch.corners.double())
    return Scenes(
        images=torch.stack(imgs), corners=torch.stack(pts), K=Ks, radial=rad, condition=condition,
        render_seconds=time.perf_counter() - t0,
    )


# ----------------------------------------------------------------------------------------------
# grid orderings and errors
# ----------------------------------------------------------------------------------------------


def lattice_orderings(grid: np.ndarray, square_board: bool) -> list[np.ndarray]:
    """All index orderings of a ``(rows, cols, 2)`` lattice describing the same set of corners.

    The 180-degree rotation and both mirrors (a mirrored board gives the same intrinsics), plus the
    transposes for square boards.
    """
    out = [grid, grid[::-1, ::-1], grid[::-1, :], grid[:, ::-1]]
    if square_board:
        out += [g.transpose(1, 0, 2) for g in list(out)]
    return out


def orient_grid(corners: np.ndarray, board: tuple[int, int]) -> np.ndarray:
    """Give a detected lattice the board's handedness and the canonical 180-degree orientation.

    A board seen from its front keeps ``(step along i) x (step along j) > 0`` in image coordinates
    (y down); a detector that returns the mirrored order gets its columns flipped. Then
    :func:`ccs_kornia.modules.detection.checks.board_checks.canonical_corner_order` picks the orientation whose first
    corner is nearest the image's top-left, so every method and view follows one convention.
    """
    from ccs_kornia.modules.detection.checks.board_checks import canonical_corner_order

    cols, rows = board
    g = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    u = (g[:, -1] - g[:, 0]).mean(0) if cols > 1 else np.array([1.0, 0.0])
    v = (g[-1] - g[0]).mean(0) if rows > 1 else np.array([0.0, 1.0])
    if u[0] * v[1] - u[1] * v[0] < 0:
        g = g[:, ::-1]
    return canonical_corner_order(g.reshape(-1, 2), board)


def corner_errors(pred: np.ndarray, truth: np.ndarray, board: tuple[int, int]) -> np.ndarray:
    """Per-corner distance ``(N,)`` to the truth under the best of :func:`lattice_orderings` (NaN at the hidden
    corners of a partial board, which the ordering ignores)."""
    cols, rows = board
    g = np.asarray(pred, dtype=np.float64).reshape(rows, cols, 2)
    t = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    best, best_mean = None, np.inf
    for cand in lattice_orderings(g, cols == rows):
        cand = cand.reshape(-1, 2)
        if cand.shape != t.shape:
            continue
        err = np.linalg.norm(cand - t, axis=-1)
        if np.isfinite(err).any() and np.nanmean(err) < best_mean:
            best, best_mean = err, np.nanmean(err)
    return best
