"""LightningDataModules that render training data on the fly (seeded, batched torch synthesis)."""

from __future__ import annotations

from typing import Iterator

import lightning as L
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from ccs_kornia.data.scenes.scenes import SyntheticBatch, SyntheticChessboards
from ccs_kornia.data.scenes.targets import gaussian_heatmaps

__all__ = [
    "BatchStreams", "RenderedBatches", "DetectorDataModule", "TRAIN_SEED_BASE", "VAL_SEED_BASE", "BENCH_SEED_BASE",
    "wild_sampler",
    "concat_batches", "DETECTOR_WILD", "DISTORTION_WILD",
]

#: recommended :class:`~ccs_kornia.data.scenes.wild.WildSpec` fields for the detector's training views (used with
#: ``wild_prob``; the datamodule's ``image_size`` replaces ``image_sizes``): squares from 6 to 60 px (the pyramid
#: brings bigger ones into this range), every lens, marks, blur up to 30 % of the square, glare, shadows, noise,
#: JPEG, the realistic point spread and gamma on every view, light margins of 0.05-1.5 squares and, on a third of the
#: views, a flat surround of any grey level (dark frames, tablets, white walls)
DETECTOR_WILD: dict = {
    "board_cols": (3, 11), "board_rows": (2, 8), "square_px": (6.0, 60.0), "max_tilt_deg": 75.0,
    "lenses": ("pinhole", "pinhole", "opencv", "radial", "fisheye"), "fov_deg": (120.0, 200.0),
    "partial_prob": 0.6, "cut_prob": 0.2, "marks": ("none", "none", "aruco", "dots", "tiles"),
    "blur": ("none", "box", "gaussian", "motion"), "blur_fraction": (0.0, 0.3), "psf_sigma": (0.3, 1.0),
    "gamma": (1.0, 2.4), "glare_prob": 0.15, "shadow_prob": 0.2, "noise_sigma": (0.0, 0.04), "jpeg_prob": 0.2,
    "jpeg_quality": (20, 90), "lighting_prob": 0.2, "supersample": 3, "margin": 1.0, "min_square_px": 4.0,
    "border_squares": (0.05, 1.5), "surround_prob": 0.35, "surround_level": (0.0, 1.0),
}
#: recommended fields for the distortion network's views (``radial`` lenses get the datamodule's level;
#: undistorted views stay pinhole): the wider world of sizes, blur and light, boards of any size
DISTORTION_WILD: dict = {
    "board_cols": (4, 11), "board_rows": (3, 8), "square_px": (5.0, 40.0), "max_tilt_deg": 70.0,
    "partial_prob": 0.3, "cut_prob": 0.1, "marks": ("none", "none", "aruco", "dots"),
    "blur": ("none", "box", "gaussian", "motion"), "blur_fraction": (0.0, 0.25), "psf_sigma": (0.3, 1.0),
    "gamma": (1.0, 2.4), "glare_prob": 0.1, "shadow_prob": 0.15, "noise_sigma": (0.0, 0.03), "jpeg_prob": 0.2,
    "jpeg_quality": (30, 90), "lighting_prob": 0.2, "supersample": 2, "margin": 1.0,
}


def wild_sampler(fields: dict | None, image_size: tuple[int, int], **forced):
    """A :class:`~ccs_kornia.data.scenes.wild.WildChessboards` rendering at ``image_size`` from WildSpec ``fields``
    (YAML-friendly: lists become tuples)."""
    from ccs_kornia.data.scenes.wild import WildChessboards, WildSpec

    def tup(v):
        return tuple(tup(x) for x in v) if isinstance(v, (list, tuple)) else v

    kw = {k: tup(v) for k, v in (fields or {}).items()}
    kw.update(forced)
    kw["image_sizes"] = (tuple(int(x) for x in image_size),)
    return WildChessboards(WildSpec(**kw))


def concat_batches(parts: list[SyntheticBatch]) -> SyntheticBatch:
    """One :class:`SyntheticBatch` from several of the same image size (corners zero-padded to the largest N)."""
    if len(parts) == 1:
        return parts[0]
    n = max(p.corners.shape[1] for p in parts)

    def pad(t, fill=0):
        return torch.nn.functional.pad(t, (0, 0, 0, n - t.shape[1]) if t.dim() == 3 else (0, n - t.shape[1]), value=fill)

    fisheye = torch.cat([p.fisheye if p.fisheye is not None else torch.zeros(len(p), 5) for p in parts])
    marks = torch.cat([p.marks if p.marks is not None else torch.zeros(len(p), dtype=torch.long) for p in parts])
    cond = [p.condition for p in parts]
    return SyntheticBatch(
        images=torch.cat([p.images for p in parts]), corners=torch.cat([pad(p.corners) for p in parts]),
        corner_valid=torch.cat([pad(p.corner_valid, False) for p in parts]),
        board_size=torch.cat([p.board_size for p in parts]), square=torch.cat([p.square for p in parts]),
        K=torch.cat([p.K for p in parts]), dist=torch.cat([p.dist for p in parts]),
        radial=torch.cat([p.radial for p in parts]), rvec=torch.cat([p.rvec for p in parts]),
        tvec=torch.cat([p.tvec for p in parts]), image_size=parts[0].image_size,
        condition=None if any(c is None for c in cond) else torch.cat(cond), fisheye=fisheye, marks=marks,
    )


#: Seed ranges. Training streams start at TRAIN_SEED_BASE + seed, validation at VAL_SEED_BASE + seed and
#: benchmarks use BENCH_SEED_BASE and above, so the three never share a generator state.
TRAIN_SEED_BASE = 0
VAL_SEED_BASE = 1_000_000
BENCH_SEED_BASE = 9_000_000


class RenderedBatches(IterableDataset):
    """An iterable of ready-made batches produced by ``make_batch(generator)``.

    Each DataLoader worker gets its own generator (``seed + 7919 * worker_id``); ``num_batches=None``
    streams forever (training), a number gives a fixed, repeatable set (validation).
    """

    def __init__(self, make_batch, seed: int, num_batches: int | None = None) -> None:
        super().__init__()
        self.make_batch = make_batch
        self.seed = int(seed)
        self.num_batches = num_batches

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        info = get_worker_info()
        wid, nw = (info.id, info.num_workers) if info is not None else (0, 1)
        g = torch.Generator().manual_seed(self.seed + 7919 * wid)
        i = 0
        while self.num_batches is None or i < self.num_batches:
            if self.num_batches is None or i % nw == wid:
                yield self.make_batch(g)
            elif self.num_batches is not None:
                # keep the validation set identical whatever the worker count: every worker walks the
                # same stream and yields only its share
                self.make_batch(g)
            i += 1


class BatchStreams:
    """The DataLoaders of a data module whose ``make_batch(generator)`` makes a whole batch: training streams from
    ``TRAIN_SEED_BASE + seed`` on ``num_workers`` workers, validation is ``val_batches`` fixed batches from
    ``VAL_SEED_BASE + seed`` (``seed``, ``num_workers`` and ``val_batches`` are the module's hyperparameters)."""

    def train_dataloader(self) -> DataLoader:
        ds = RenderedBatches(self.make_batch, TRAIN_SEED_BASE + self.hparams.seed)
        return DataLoader(ds, batch_size=None, num_workers=self.hparams.num_workers,
                          persistent_workers=self.hparams.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        ds = RenderedBatches(self.make_batch, VAL_SEED_BASE + self.hparams.seed, self.hparams.val_batches)
        return DataLoader(ds, batch_size=None, num_workers=0)


class DetectorDataModule(BatchStreams, L.LightningDataModule):
    """Rendered chessboards with Gaussian target heatmaps for :class:`DetectorLitModule`.

    Small images (default 192x144) with partial boards stand in for crops of full-size photos: the
    detector is fully convolutional and corners are local, so it trains on many small views per step
    (fast on 2 CPU cores) and runs on full images at inference.

    Args:
        image_size: ``(W, H)`` of the rendered training views.
        batch_size: views per step.
        sigma: target Gaussian sigma in px.
        fx_range: focal range in px for the rendered size.
        board_cols, board_rows: board size ranges.
        partial_prob: fraction of views whose board leaves the image.
        supersample: renderer sub-cells per pixel side.
        seed: offset into the training / validation seed ranges.
        val_batches: fixed number of validation batches.
        num_workers: DataLoader workers (0 renders in the training process).
        wild_prob: share of each batch rendered by :class:`~ccs_kornia.data.scenes.wild.WildChessboards` (0: today's data
            only, the default).
        wild: WildSpec fields of those views (``None``: :data:`DETECTOR_WILD`, the recommended recipe).
        board_free_prob: share of each batch without a board (:func:`~ccs_kornia.data.scenes.distractors.board_free_images`
            without its checker patches, whose corners are real corners), with an empty target heatmap.
    """

    def __init__(
        self,
        image_size: tuple[int, int] = (192, 144),
        batch_size: int = 16,
        sigma: float = 1.5,
        fx_range: tuple[float, float] = (90.0, 300.0),
        board_cols: tuple[int, int] = (3, 11),
        board_rows: tuple[int, int] = (2, 8),
        partial_prob: float = 0.5,
        fill_range: tuple[float, float] = (0.35, 1.2),
        supersample: int = 3,
        seed: int = 0,
        val_batches: int = 16,
        num_workers: int = 0,
        wild_prob: float = 0.0,
        wild: dict | None = None,
        board_free_prob: float = 0.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if not (0.0 <= wild_prob <= 1.0 and 0.0 <= board_free_prob < 1.0):
            raise ValueError(f"wild_prob must be in [0, 1] and board_free_prob in [0, 1), got {wild_prob}, {board_free_prob}.")
        self.wild = wild_sampler(DETECTOR_WILD if wild is None else wild, image_size) if wild_prob > 0 else None
        self.scenes = SyntheticChessboards(
            image_size=tuple(image_size),
            board_cols=tuple(board_cols),
            board_rows=tuple(board_rows),
            fx_range=tuple(fx_range),
            partial_prob=partial_prob,
            fill_range=tuple(fill_range),
            supersample=supersample,
            margin=1.0,
        )

    def make_batch(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        hp = self.hparams
        n_free = int(round(hp.batch_size * hp.board_free_prob))
        n_board = hp.batch_size - n_free
        n_wild = int(round(n_board * hp.wild_prob)) if self.wild is not None else 0
        for attempt in range(5):
            try:
                parts = [self.scenes.sample(n_board - n_wild, generator)] if n_wild < n_board else []
                if n_wild:
                    parts.append(self.wild.sample(n_wild, generator))
                b = concat_batches(parts)
                break
            except RuntimeError:
                # a rare scene whose board cannot be placed: draw again (the generator has moved on, so
                # the stream stays deterministic)
                if attempt == 4:
                    raise
        w, h = b.image_size
        cols, rows = b.board_size[:, 0:1], b.board_size[:, 1:2]
        n = torch.arange(b.corners.shape[1]).unsqueeze(0)
        exists = n < cols * rows
        c = b.corners
        inside = (c[..., 0] > -0.5) & (c[..., 0] < w - 0.5) & (c[..., 1] > -0.5) & (c[..., 1] < h - 0.5)
        # every visible corner is a target, even one too close to the border to count as a valid detection
        visible = exists & inside & torch.isfinite(c).all(-1)
        heatmap = gaussian_heatmaps(c, visible, (w, h), hp.sigma)
        out = {"image": b.images, "heatmap": heatmap, "corners": c, "valid": b.corner_valid}
        if n_free:
            from ccs_kornia.data.scenes.distractors import (
                DISTRACTOR_KINDS,
                board_free_images,
            )

            kinds = tuple(k for k in DISTRACTOR_KINDS if k != "checker_patches")
            free, _ = board_free_images(n_free, (w, h), generator, kinds=kinds)
            n = c.shape[1]
            out = {"image": torch.cat([b.images, free]), "heatmap": torch.cat([heatmap, torch.zeros_like(free)]),
                   "corners": torch.cat([c, torch.zeros(n_free, n, 2)]),
                   "valid": torch.cat([b.corner_valid, torch.zeros(n_free, n, dtype=torch.bool)])}
        return out
