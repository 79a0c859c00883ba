"""LightningDataModule of radially distorted chessboards for the distortion CNN (rendered on the fly, seeded)."""

from __future__ import annotations

import lightning as L
import torch
from torch.utils.data import DataLoader

from ccs_kornia.data.datamodules.datamodule import (
    DISTORTION_WILD,
    TRAIN_SEED_BASE,
    VAL_SEED_BASE,
    RenderedBatches,
    concat_batches,
    wild_sampler,
)
from ccs_kornia.data.render import augment
from ccs_kornia.data.scenes.sampling import RADIAL_LEVELS
from ccs_kornia.data.scenes.scenes import SyntheticBatch, SyntheticChessboards

__all__ = ["DistortionDataModule", "flip_batch"]

_LEVELS = (*RADIAL_LEVELS, "mild", "any")


def flip_batch(batch: dict[str, torch.Tensor], horizontal: bool, vertical: bool) -> dict[str, torch.Tensor]:
    """Mirror images and corners about the image centre.

    The paper's radial model is symmetric about the image centre ``((W-1)/2, (H-1)/2)``, so a mirrored view has
    exactly the same distortion coefficients; rows and columns of corners stay rows and columns (only their
    direction flips), so grid order and straightness are unchanged.
    """
    if not (horizontal or vertical):
        return batch
    out = dict(batch)
    h, w = batch["image"].shape[-2:]
    dims = ([-1] if horizontal else []) + ([-2] if vertical else [])
    out["image"] = torch.flip(batch["image"], dims)
    c = batch["corners"].clone()
    if horizontal:
        c[..., 0] = (w - 1) - c[..., 0]
    if vertical:
        c[..., 1] = (h - 1) - c[..., 1]
    out["corners"] = torch.where(batch["valid"].unsqueeze(-1), c, batch["corners"])
    return out


class DistortionDataModule(L.LightningDataModule):
    """Rendered chessboards with the paper's radial distortion, for :class:`DistortionLitModule`.

    Each view draws its distortion level uniformly from ``levels`` (repeat a level to weight it): ``none``,
    the paper's ``level1`` and ``level2`` ranges, and ``severe`` (15-25 % barrel at the image corner), see
    :func:`ccs_kornia.data.scenes.sampling.sample_radial_distortion`. Poses, boards, backgrounds and image conditions
    vary as in :class:`~ccs_kornia.data.scenes.scenes.SyntheticChessboards`.

    Rendering costs more than a training step on a small CPU, so ``reuse > 1`` serves each rendered training
    batch that many times, mirrored differently each time (none, horizontal, vertical, both): the radial model
    is centre-symmetric, so the targets stay exact. Validation batches are never reused.

    Batches are dicts: ``image`` (B,1,H,W), ``radial`` (B,3) distortion ``(k0, k1, k2)``, ``corners`` (B,N,2)
    distorted ground-truth corners, ``valid`` (B,N), ``board_size`` (B,2) and ``level`` (B,) index into ``levels``.

    Args:
        image_size: ``(W, H)`` of the rendered views.
        batch_size: views per step.
        levels: radial distortion levels drawn per view.
        fx_range: focal length range in px for the rendered size.
        board_cols, board_rows: board size ranges (inner corners).
        fill_range: fraction of the image the board spans.
        partial_prob: fraction of views whose board may leave the image.
        conditions: image conditions (:data:`ccs_kornia.data.render.augment.CONDITIONS`).
        supersample: renderer sub-cells per pixel side.
        reuse: training steps served by one rendered batch (1..4), see above.
        seed: offset into the training / validation seed ranges.
        val_batches: fixed number of validation batches.
        num_workers: DataLoader workers for training (0 renders in the training process).
        wild_prob: share of each level's views rendered by :class:`~ccs_kornia.data.scenes.wild.WildChessboards` (square
            sizes, marks, blur scaled to the square, glare, shadows, point spread and gamma; 0, the default, keeps
            today's data).
        wild: WildSpec fields of those views (``None``: :data:`~ccs_kornia.data.datamodules.datamodule.DISTORTION_WILD`);
            their lens is set by the level (``none``: an undistorted pinhole).
        board_free_prob: share of each batch that shows no board at all (:func:`~ccs_kornia.data.scenes.distractors.board_free_images`:
            clutter, stripes, tiles, noise ...), with the identity as target (``level`` of ``none``, or 0).
    """

    def __init__(
        self,
        image_size: tuple[int, int] = (256, 192),
        batch_size: int = 16,
        levels: tuple[str, ...] = ("none", "level1", "level2", "severe"),
        fx_range: tuple[float, float] = (120.0, 360.0),
        board_cols: tuple[int, int] = (4, 11),
        board_rows: tuple[int, int] = (3, 8),
        fill_range: tuple[float, float] = (0.4, 1.0),
        partial_prob: float = 0.3,
        conditions: tuple[str, ...] = augment.CONDITIONS,
        supersample: int = 2,
        reuse: int = 1,
        seed: int = 0,
        val_batches: int = 8,
        num_workers: int = 0,
        wild_prob: float = 0.0,
        wild: dict | None = None,
        board_free_prob: float = 0.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if not (0.0 <= wild_prob <= 1.0 and 0.0 <= board_free_prob < 1.0):
            raise ValueError(f"wild_prob must be in [0, 1] and board_free_prob in [0, 1), got {wild_prob}, {board_free_prob}.")
        levels = tuple(levels)
        if not levels:
            raise ValueError("levels must not be empty.")
        for lvl in levels:
            if lvl not in _LEVELS:
                raise ValueError(f"Unknown radial level {lvl!r}; expected some of {_LEVELS}.")
        if not 1 <= int(reuse) <= 4:
            raise ValueError(f"reuse must be in 1..4 (one per mirror variant), got {reuse}.")
        self.levels = levels
        common = dict(
            image_size=tuple(image_size),
            board_cols=tuple(board_cols),
            board_rows=tuple(board_rows),
            fx_range=tuple(fx_range),
            fill_range=tuple(fill_range),
            partial_prob=partial_prob,
            conditions=tuple(conditions),
            supersample=supersample,
            margin=1.0,
        )
        self.scenes = {
            lvl: SyntheticChessboards(distortion="none" if lvl == "none" else "radial", radial_level=lvl, **common)
            for lvl in dict.fromkeys(levels)
        }
        fields = DISTORTION_WILD if wild is None else wild
        self.wild = {
            lvl: wild_sampler(fields, image_size, lenses=("pinhole",) if lvl == "none" else ("radial",),
                              radial_level="none" if lvl == "none" else lvl)
            for lvl in dict.fromkeys(levels)
        } if wild_prob > 0 else None
        self._cached: dict[str, torch.Tensor] | None = None
        self._uses = 0

    def make_batch(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """Render one batch; each view's level drawn from ``levels``."""
        hp = self.hparams
        b = int(hp.batch_size)
        n_free = int(round(b * hp.board_free_prob))
        which = torch.randint(0, len(self.levels), (b - n_free,), generator=generator)
        parts: list[SyntheticBatch] = []
        level_idx: list[torch.Tensor] = []
        for name, scenes in self.scenes.items():
            ids = [k for k, lvl in enumerate(self.levels) if lvl == name]
            count = int(sum(int((which == k).sum()) for k in ids))
            if count == 0:
                continue
            n_wild = int(round(count * hp.wild_prob)) if self.wild is not None else 0
            sub = ([scenes.sample(count - n_wild, generator)] if n_wild < count else []) + \
                ([self.wild[name].sample(n_wild, generator)] if n_wild else [])
            parts.append(concat_batches(sub))
            level_idx.append(torch.full((count,), ids[0], dtype=torch.long))
        if n_free:
            parts.append(self._board_free(n_free, generator))
            level_idx.append(torch.full((n_free,), self.levels.index("none") if "none" in self.levels else 0))
        batch = concat_batches(parts)
        return {
            "image": batch.images,
            "radial": batch.radial,
            "corners": batch.corners,
            "valid": batch.corner_valid,
            "board_size": batch.board_size,
            "level": torch.cat(level_idx),
        }

    def _board_free(self, n: int, generator: torch.Generator) -> SyntheticBatch:
        from ccs_kornia.data.scenes.distractors import board_free_images

        images, _ = board_free_images(n, tuple(self.hparams.image_size), generator)
        return SyntheticBatch(
            images=images, corners=torch.zeros(n, 1, 2), corner_valid=torch.zeros(n, 1, dtype=torch.bool),
            board_size=torch.full((n, 2), 2, dtype=torch.long), square=torch.ones(n), K=torch.eye(3).expand(n, 3, 3),
            dist=torch.zeros(n, 5), radial=torch.tensor([1.0, 0.0, 0.0]).expand(n, 3).clone(), rvec=torch.zeros(n, 3),
            tvec=torch.zeros(n, 3), image_size=tuple(self.hparams.image_size),
        )

    def make_train_batch(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """A fresh batch every ``reuse`` calls; in between, mirrored copies of the last one."""
        if self._cached is None or self._uses >= int(self.hparams.reuse):
            self._cached, self._uses = self.make_batch(generator), 0
        variant = self._uses
        self._uses += 1
        return flip_batch(self._cached, horizontal=variant in (1, 3), vertical=variant in (2, 3))

    def train_dataloader(self) -> DataLoader:
        self._cached, self._uses = None, 0
        ds = RenderedBatches(self.make_train_batch, TRAIN_SEED_BASE + self.hparams.seed)
        return DataLoader(ds, batch_size=None, num_workers=self.hparams.num_workers,
                          persistent_workers=self.hparams.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        ds = RenderedBatches(self.make_batch, VAL_SEED_BASE + self.hparams.seed, self.hparams.val_batches)
        return DataLoader(ds, batch_size=None, num_workers=0)
