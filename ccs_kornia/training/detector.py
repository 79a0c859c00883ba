"""Lightning training of the heatmap corner detector (paper §III-B, Eq. 2)."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch

from ccs_kornia.losses.heatmap_loss import HeatmapLoss
from ccs_kornia.modules.detection.learned.gaussian_fit import gaussian_fit
from ccs_kornia.modules.detection.learned.heatmap_unet import CornerUNet
from ccs_kornia.modules.detection.learned.peaks import heatmap_peaks
from ccs_kornia.training.common import adamw_one_cycle, load_exported_weights

__all__ = ["DetectorLitModule"]


class DetectorLitModule(L.LightningModule):
    """Trains :class:`CornerUNet` on rendered chessboards against Gaussian target heatmaps.

    Batches are dicts from :class:`ccs_kornia.data.datamodules.datamodule.DetectorDataModule` with ``image``
    (B,1,H,W), ``heatmap`` (B,1,H,W), ``corners`` (B,N,2) and ``valid`` (B,N).

    Validation logs the heatmap loss and two figures that matter for calibration: the sub-pixel
    error of the Gaussian fit seeded at the true corners (``val/fit_err_px``), and the recall and
    false-peak rate of the peak detector (``val/recall``, ``val/false_peaks``).

    Args:
        base_channels: UNet width.
        depth: UNet depth.
        norm: UNet normalisation.
        lr: peak learning rate of the one-cycle schedule.
        weight_decay: AdamW weight decay.
        pos_weight: extra loss weight on pixels near corners (see :class:`HeatmapLoss`).
        sigma: Gaussian sigma of the targets (px), also used by the fit window.
        peak_threshold: heatmap threshold of the validation peak detector.
        init_weights: an exported weight file (:mod:`ccs_kornia.training.export`, e.g. the shipped
            ``ccs_kornia/weights/corner_unet.pt``) to start from (fine-tuning); its network config must match
            ``base_channels`` / ``depth`` / ``norm``. Loaded when fitting starts (``setup("fit")``), before Lightning
            restores a checkpoint, so a resumed run continues from its checkpoint and ``load_from_checkpoint`` never
            needs the file. ``None``: random initialisation.
        teacher_weights: an exported weight file of a trained detector (any width) whose heatmaps the network also
            learns (distillation: a smaller network learns what the teacher sees on the real sets as well as the
            renders' exact targets); the teacher is frozen and never saved in checkpoints. ``None``: no teacher.
        teacher_loss_weight: weight of the distillation term (the heatmap loss against the teacher's heatmap).

    Example:
        >>> m = DetectorLitModule(base_channels=4, depth=2)
        >>> m(torch.zeros(1, 1, 32, 32)).shape
        torch.Size([1, 1, 32, 32])
    """

    def __init__(
        self,
        base_channels: int = 8,
        depth: int = 4,
        norm: str = "batch",
        lr: float = 3e-3,
        weight_decay: float = 1e-4,
        pos_weight: float = 10.0,
        sigma: float = 1.5,
        peak_threshold: float = 0.3,
        init_weights: str | None = None,
        teacher_weights: str | None = None,
        teacher_loss_weight: float = 1.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = CornerUNet(base_channels=base_channels, depth=depth, norm=norm)
        self.loss = HeatmapLoss(pos_weight=pos_weight)
        object.__setattr__(self, "teacher", None)  # not a submodule: never trained, never in a checkpoint

    def load_weights(self, path: str | Path) -> None:
        """Load the network weights of an exported file (raises ``ValueError`` on a config mismatch)."""
        cfg = {"base_channels": self.hparams.base_channels, "depth": self.hparams.depth, "norm": self.hparams.norm}
        load_exported_weights(self.net, path, "CornerUNet", cfg)

    def setup(self, stage: str) -> None:
        if stage == "fit" and self.hparams.init_weights:
            self.load_weights(self.hparams.init_weights)
        if stage == "fit" and self.hparams.teacher_weights and self.teacher is None:
            from ccs_kornia.modules.detection.learned.learned_detector import (
                load_corner_unet,
            )

            teacher, _ = load_corner_unet(self.hparams.teacher_weights)
            object.__setattr__(self, "teacher", teacher.requires_grad_(False).eval())

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        pred = self.net(batch["image"])
        loss = self.loss(pred, batch["heatmap"])
        self.log("train/loss", loss, prog_bar=True, batch_size=pred.shape[0])
        if self.teacher is not None:
            with torch.no_grad():
                soft = self.teacher.to(pred.device)(batch["image"])
            distil = self.loss(pred, soft)
            self.log("train/distil", distil, prog_bar=True, batch_size=pred.shape[0])
            loss = loss + self.hparams.teacher_loss_weight * distil
        return loss

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        pred = self.net(batch["image"])
        bs = pred.shape[0]
        self.log("val/loss", self.loss(pred, batch["heatmap"]), prog_bar=True, batch_size=bs)
        corners, valid = batch["corners"], batch["valid"]
        mu, _, ok = gaussian_fit(pred, corners, valid, window=2 * round(2 * self.hparams.sigma) + 1)
        good = ok & valid
        err = (mu - corners).norm(dim=-1)[good]
        if err.numel():
            self.log("val/fit_err_px", err.mean(), prog_bar=True, batch_size=bs)
        seeds, _, pmask = heatmap_peaks(pred, threshold=self.hparams.peak_threshold)
        # a true corner is recalled when a peak lies within 2 px; a peak is false when no corner is within 2 px
        d = torch.cdist(seeds.float(), corners.float())  # (B,M,N)
        d = d.masked_fill(~pmask[..., :, None] | ~valid[..., None, :], float("inf"))
        recall = (d.min(dim=1).values < 2.0)[valid].float().mean()
        false = ((d.min(dim=2).values >= 2.0) & pmask).sum() / max(bs, 1)
        self.log("val/recall", recall, prog_bar=True, batch_size=bs)
        self.log("val/false_peaks", false, batch_size=bs)

    def configure_optimizers(self):
        return adamw_one_cycle(self, self.hparams.lr, self.hparams.weight_decay)

    def export(self) -> dict:
        """The shippable checkpoint: network config and weights only (a few hundred kB)."""
        return {
            "kind": "CornerUNet",
            "config": {"base_channels": self.hparams.base_channels, "depth": self.hparams.depth, "norm": self.hparams.norm},
            "sigma": self.hparams.sigma,
            "state_dict": {k: v.detach().cpu() for k, v in self.net.state_dict().items()},
        }
