"""Lightning training of the radial distortion CNN (paper Sec. III-A, Eq. 1), and its weight export.

    python -m ccs_kornia fit --config lightning_configs/distortion.yaml
    python -m ccs_kornia.training.export runs/distortion/checkpoints/last.ckpt ccs_kornia/weights/distortion_net.pt
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch

from ccs_kornia.geometry.radial import fit_radial_correction
from ccs_kornia.losses.grid_loss import (
    GridLoss,
    grid_loss,
    grid_targets,
    normalize_distortion_scale,
)
from ccs_kornia.modules.correction.distortion_net import DistortionNet
from ccs_kornia.modules.correction.radial_warp import correct_points
from ccs_kornia.modules.correction.straightness import straightness_rms
from ccs_kornia.training.common import adamw_one_cycle, load_exported_weights

__all__ = ["DistortionLitModule"]


class DistortionLitModule(L.LightningModule):
    """Trains :class:`DistortionNet` with the sampling-grid loss on rendered, radially distorted boards.

    Batches are dicts from :class:`ccs_kornia.data.datamodules.distortion_datamodule.DistortionDataModule` with ``image``
    (B,1,H,W), ``radial`` (B,3), ``corners`` (B,N,2), ``valid`` (B,N), ``board_size`` (B,2), ``level`` (B,).

    Validation logs, all in pixels of the rendered views:

    * ``val/grid_loss``: Eq. 1 with the predicted correction; ``val/grid_loss_identity`` (no correction) and
      ``val/grid_loss_oracle`` (``fit_radial_correction`` of the true coefficients) bracket it;
      ``val/grid_loss_level{i}`` and ``val/grid_loss_identity_level{i}`` per distortion level index;
    * ``val/straightness``: RMS distance of the ground-truth corners, corrected with the predicted coefficients,
      from lines fitted to each board row and column; ``val/straightness_before`` for the distorted corners.

    Scale: ``k0`` of the distortion only zooms the image about its centre, which one image cannot tell from a
    different focal length (the paper's level2 draws ``k0`` in ``[0.8, 1.2]``, i.e. an unlearnable zoom worth up
    to ~15 px of grid loss at 256 px). With ``fix_scale`` (default) the targets use the equivalent distortion
    with ``k0 = 1`` (:func:`ccs_kornia.losses.grid_loss.normalize_distortion_scale`): the network learns the
    learnable part, a correction that keeps the scale at the image centre; corrected corners and straightness
    are unaffected. ``fix_scale=False`` trains on the raw coefficients as the paper does.

    Args:
        base_channels, input_size, norm, pool, hidden, output_scale: :class:`DistortionNet` settings.
        grid_size: sampling points per side of the grid loss.
        fix_scale: train on scale-normalised distortion targets (see above).
        lr: peak learning rate of the one-cycle schedule.
        weight_decay: AdamW weight decay.
        init_weights: an exported weight file (e.g. the shipped ``ccs_kornia/weights/distortion_net.pt``) to start
            from (fine-tuning); its network config must match. Loaded when fitting starts (``setup("fit")``, before
            Lightning restores a checkpoint), so resumed runs and ``load_from_checkpoint`` never need the file.
    """

    def __init__(
        self,
        base_channels: int = 16,
        input_size: int = 256,
        norm: str = "batch",
        pool: int = 4,
        hidden: tuple[int, int] = (256, 64),
        output_scale: float = 0.25,
        grid_size: int = 16,
        fix_scale: bool = True,
        lr: float = 2e-3,
        weight_decay: float = 1e-4,
        init_weights: str | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = DistortionNet(
            base_channels=base_channels, input_size=input_size, norm=norm, pool=pool, hidden=tuple(hidden),
            output_scale=output_scale,
        )
        self.loss = GridLoss(grid_size=grid_size)

    def load_weights(self, path: str | Path) -> None:
        """Load the network weights of an exported file (raises ``ValueError`` on a config mismatch)."""
        load_exported_weights(self.net, path, "DistortionNet", dict(self.net.config))

    def setup(self, stage: str) -> None:
        if stage == "fit" and self.hparams.init_weights:
            self.load_weights(self.hparams.init_weights)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)

    def target_distortion(self, radial: torch.Tensor) -> torch.Tensor:
        """The distortion the grid loss compares with (scale-normalised if ``fix_scale``)."""
        return normalize_distortion_scale(radial) if self.hparams.fix_scale else radial

    @staticmethod
    def _size(batch: dict[str, torch.Tensor]) -> tuple[int, int]:
        h, w = batch["image"].shape[-2:]
        return int(w), int(h)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        pred = self.net(batch["image"])
        loss = self.loss(pred, self.target_distortion(batch["radial"]), self._size(batch))
        self.log("train/grid_loss", loss, prog_bar=True, batch_size=pred.shape[0])
        return loss

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        size = self._size(batch)
        radial = self.target_distortion(batch["radial"])
        pred = self.net(batch["image"])
        bs = pred.shape[0]
        grid = self.hparams.grid_size
        err = grid_loss(pred, radial, size, grid, reduction="none")
        _, _, point_valid = grid_targets(radial, size, grid)
        ident = torch.zeros_like(pred)
        ident[:, 0] = 1.0
        oracle = fit_radial_correction(radial.double(), size).to(pred.dtype)
        self.log("val/grid_loss", self.loss(pred, radial, size), prog_bar=True, batch_size=bs)
        self.log("val/grid_loss_identity", self.loss(ident, radial, size), batch_size=bs)
        self.log("val/grid_loss_oracle", self.loss(oracle, radial, size), batch_size=bs)
        # per-level figures (each image's valid points weigh equally within its level)
        npts = point_valid.sum(-1).clamp_min(1)
        per_image = err.sum(-1) / npts
        per_image_identity = grid_loss(ident, radial, size, grid, reduction="none").sum(-1) / npts
        for lvl in batch["level"].unique().tolist():
            sel = batch["level"] == lvl
            self.log(f"val/grid_loss_level{lvl}", per_image[sel].mean(), batch_size=int(sel.sum()))
            self.log(f"val/grid_loss_identity_level{lvl}", per_image_identity[sel].mean(), batch_size=int(sel.sum()))
        corners, valid, board = batch["corners"], batch["valid"], batch["board_size"]
        before, n_before = straightness_rms(corners, valid, board)
        after, _ = straightness_rms(correct_points(corners, pred, size), valid, board)
        has = n_before > 0
        if bool(has.any()):
            m = int(has.sum())
            self.log("val/straightness", after[has].mean(), prog_bar=True, batch_size=m)
            self.log("val/straightness_before", before[has].mean(), batch_size=m)

    def configure_optimizers(self):
        return adamw_one_cycle(self, self.hparams.lr, self.hparams.weight_decay)

    def export(self) -> dict:
        """The shippable checkpoint: network config and weights only (loadable by ``DistortionNet.from_export``)."""
        return {
            "kind": "DistortionNet",
            "config": dict(self.net.config),
            "state_dict": {k: v.detach().cpu() for k, v in self.net.state_dict().items()},
        }
