"""Lightning fine-tuning of the heatmap network through the calibration solver (end to end)."""

from __future__ import annotations

import copy

import lightning as L
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models.factory import camera_model
from ccs_kornia.losses.heatmap_loss import HeatmapLoss
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.detection.base import measured_corners
from ccs_kornia.modules.detection.learned.heatmap_unet import CornerUNet
from ccs_kornia.modules.detection.learned.learned_detector import (
    DEFAULT_DETECTOR_WEIGHTS,
    LearnedChessboardDetector,
)
from ccs_kornia.modules.detection.refine.differentiable_refine import (
    DifferentiableCorners,
)
from ccs_kornia.training.common import adamw_one_cycle, load_exported_weights

__all__ = ["EndToEndLitModule", "intrinsic_error"]


def intrinsic_error(K: torch.Tensor, K_true: torch.Tensor) -> torch.Tensor:
    """The paper's E_IP, ``(|fx - fx*| + |fy - fy*| + |cx - cx*| + |cy - cy*|) / 2`` in px, of :math:`(..., 3, 3)`.

    Example:
        >>> K = torch.tensor([[501., 0, 321], [0, 499, 240], [0, 0, 1]])
        >>> intrinsic_error(K, torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]]))
        tensor(1.5000)
    """
    idx = ([0, 1, 0, 1], [0, 1, 2, 2])
    return 0.5 * (K[..., idx[0], idx[1]] - K_true[..., idx[0], idx[1]]).abs().sum(-1)


class EndToEndLitModule(L.LightningModule):
    """Fine-tunes :class:`CornerUNet` on the camera the solver makes from its corners.

    Each batch is one rendered calibration set with its exact camera
    (:class:`~ccs_kornia.data.datamodules.calibration_datamodule.CalibrationSetDataModule`). A step:

    1. the learned detector, without image refinement (``refine="none"``: its corners are the network's own Gaussian
       fits) and with the current weights, finds the boards without autograd (every discrete decision);
    2. their corners are made differentiable functions of the network
       (:class:`~ccs_kornia.modules.detection.refine.differentiable_refine.DifferentiableCorners`, ``steps=0``: the values
       stay the detector's, the gradient is the Gaussian fit's on the network's heatmap);
    3. the solver calibrates the camera from them; its implicit gradient carries the corners' gradient to ``K``;
    4. loss: E_IP of ``K`` against the truth (px), plus ``heatmap_weight`` times the heatmap loss against the
       rendered targets (keeps the heatmap what the peak finder and the sigma check expect).

    Batch normalisation runs on its running statistics throughout (one calibration set is not a batch of the
    statistics it learned: a fine-tune, the network's normalisation frozen).

    Validation logs ``val/e_ip`` (px), ``val/corner_err`` (px, the network's corners against the truth on found
    boards), ``val/found`` (fraction of views) and the heatmap loss.

    Args:
        base_channels, depth, norm: the network (those of ``init_weights``).
        init_weights: exported weights to start from (default: the shipped detector); ``None`` or ``""``: random.
        model: the solver's camera model by its name (as the recipes' YAML writes it, e.g. ``opencv5``; read by
            :func:`~ccs_kornia.geometry.models.factory.camera_model`).
        lr: peak learning rate of the one-cycle schedule.
        weight_decay: AdamW weight decay.
        heatmap_weight: weight of the heatmap loss.
        heatmap_views: views of each set the heatmap loss sees (the network's forward and backward at full size cost
            more than the rest of the step).
        pos_weight: the heatmap loss's extra weight near corners.
        sigma: the heatmaps' training sigma.

    Example:
        >>> m = EndToEndLitModule(base_channels=4, depth=2, init_weights=None)
        >>> m(torch.zeros(1, 1, 32, 32)).shape
        torch.Size([1, 1, 32, 32])
    """

    def __init__(
        self,
        base_channels: int = 8,
        depth: int = 4,
        norm: str = "batch",
        init_weights: str | None = str(DEFAULT_DETECTOR_WEIGHTS),
        model: str = "opencv5",
        lr: float = 1e-4,
        weight_decay: float = 1e-4,
        heatmap_weight: float = 1.0,
        heatmap_views: int = 2,
        pos_weight: float = 10.0,
        sigma: float = 1.5,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = CornerUNet(base_channels=base_channels, depth=depth, norm=norm)
        self.heatmap_loss = HeatmapLoss(pos_weight=pos_weight)
        self.solver = CalibrationSolver(model=camera_model(model))

    def setup(self, stage: str) -> None:
        # every stage: ``validate`` without a checkpoint measures the starting weights (a checkpoint, restored after
        # setup, replaces them)
        if self.hparams.init_weights:
            cfg = {"base_channels": self.hparams.base_channels, "depth": self.hparams.depth, "norm": self.hparams.norm}
            load_exported_weights(self.net, self.hparams.init_weights, "CornerUNet", cfg)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)

    def train(self, mode: bool = True):
        super().train(mode)
        self.net.eval()  # normalisation on its running statistics (see the class doc)
        return self

    def detector(self) -> LearnedChessboardDetector:
        """The learned detector with the current weights (a folded copy), without image refinement."""
        return LearnedChessboardDetector(net=copy.deepcopy(self.net), sigma=self.hparams.sigma, refine="none")

    def calibrate(self, batch: dict) -> dict:
        """Detect (no autograd), differentiable corners, solve: ``K`` (3, 3) with grad, corners, found, valid."""
        images, board = batch["image"], tuple(int(x) for x in batch["board"].tolist())
        detector = self.detector()
        with torch.no_grad():
            det = detector(images, board)
            factor = detector.detection_factor(images)
        valid = measured_corners(det.corners, det.found)
        corners, _ = DifferentiableCorners(self.net, steps=0, fit_window=detector.fit_window)(
            images, det.corners, valid, board, factor)
        obj = board_object_points(*board, float(batch["square"]), device=images.device, dtype=torch.float64)
        size = (images.shape[-1], images.shape[-2])
        res = self.solver(corners.double()[None], valid[None], obj, size)
        return {"K": res.K[0], "success": bool(res.success[0]), "corners": corners, "valid": valid, "found": det.found}

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        out = self.calibrate(batch)
        k = self.hparams.heatmap_views
        heat = self.heatmap_loss(self.net(batch["image"][:k]), batch["heatmap"][:k])
        loss = self.hparams.heatmap_weight * heat
        if out["success"] and out["K"].requires_grad:
            e_ip = intrinsic_error(out["K"], batch["K"].to(out["K"]))
            loss = loss + e_ip.to(loss.dtype)
            self.log("train/e_ip", e_ip.detach().float(), prog_bar=True, batch_size=1)
        self.log("train/heatmap", heat.detach(), prog_bar=True, batch_size=1)
        return loss

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        out = self.calibrate(batch)
        k = self.hparams.heatmap_views
        self.log("val/heatmap", self.heatmap_loss(self.net(batch["image"][:k]), batch["heatmap"][:k]), batch_size=1)
        self.log("val/found", out["found"].float().mean(), batch_size=1)
        if out["success"]:
            self.log("val/e_ip", intrinsic_error(out["K"].detach(), batch["K"].to(out["K"])).float(), prog_bar=True,
                     batch_size=1)
        ok = out["valid"] & batch["valid"]
        if bool(ok.any()):
            err = (out["corners"].detach() - batch["corners"].to(out["corners"])).norm(dim=-1)[ok]
            self.log("val/corner_err", err.mean().float(), prog_bar=True, batch_size=1)

    def configure_optimizers(self):
        return adamw_one_cycle(self, self.hparams.lr, self.hparams.weight_decay)

    def export(self) -> dict:
        """The shippable checkpoint (the detector's format: network config and weights)."""
        return {
            "kind": "CornerUNet",
            "config": {"base_channels": self.hparams.base_channels, "depth": self.hparams.depth,
                       "norm": self.hparams.norm},
            "sigma": self.hparams.sigma,
            "state_dict": {k: v.detach().cpu() for k, v in self.net.state_dict().items()},
        }

