"""LightningDataModules that render training data on the fly (seeded, batched torch synthesis)."""

from __future__ import annotations

from typing import Iterator

import lightning as L
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from ccs_kornia.data.scenes import SyntheticChessboards
from ccs_kornia.data.targets import gaussian_heatmaps

__all__ = ["RenderedBatches", "DetectorDataModule", "TRAIN_SEED_BASE", "VAL_SEED_BASE", "BENCH_SEED_BASE"]

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


class DetectorDataModule(L.LightningDataModule):
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
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
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
        for attempt in range(5):
            try:
                b = self.scenes.sample(hp.batch_size, generator)
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
        return {"image": b.images, "heatmap": heatmap, "corners": c, "valid": b.corner_valid}

    def train_dataloader(self) -> DataLoader:
        ds = RenderedBatches(self.make_batch, TRAIN_SEED_BASE + self.hparams.seed)
        return DataLoader(ds, batch_size=None, num_workers=self.hparams.num_workers,
                          persistent_workers=self.hparams.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        ds = RenderedBatches(self.make_batch, VAL_SEED_BASE + self.hparams.seed, self.hparams.val_batches)
        return DataLoader(ds, batch_size=None, num_workers=0)
