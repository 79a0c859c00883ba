"""Rendered calibration sets with exact cameras, one set per batch, for training through the calibration solver."""

from __future__ import annotations

import lightning as L
import torch
from torch.utils.data import DataLoader

from ccs_kornia.data.datamodules.datamodule import (
    TRAIN_SEED_BASE,
    VAL_SEED_BASE,
    RenderedBatches,
)
from ccs_kornia.data.scenes.sampling import sample_opencv_distortion
from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.data.scenes.targets import gaussian_heatmaps

__all__ = ["CalibrationSetDataModule"]


class CalibrationSetDataModule(L.LightningDataModule):
    """Calibration sets of one random camera each (:func:`~ccs_kornia.data.scenes.scenes.make_calibration_set`): ``V`` views
    of one board, the camera's ``K`` and OpenCV distortion exact.

    A batch is a dict: ``image`` (V, 1, H, W), ``heatmap`` (V, 1, H, W) targets, ``corners`` (V, N, 2) and ``valid``
    (V, N) truth, ``K`` (3, 3), ``dist`` (5,), ``board`` (2,) long, ``square`` (,). Training streams draw their scenes
    from :data:`~ccs_kornia.data.datamodules.datamodule.TRAIN_SEED_BASE`, validation from ``VAL_SEED_BASE`` (the benchmark's
    seeds, ``BENCH_SEED_BASE`` upwards, are never drawn).

    Args:
        image_size: ``(W, H)`` of the views.
        num_views: views per set.
        board_size: ``(cols, rows)`` inner corners.
        square: square side (m).
        fx_range: focal length range in px (``fy`` within 2 %, principal point within 5 % of the centre).
        distortion: draw OpenCV distortion (``k1`` in ``[-0.3, 0.1]``); ``False``: none.
        sigma: target heatmap sigma (px).
        supersample: renderer sub-cells per pixel side.
        seed: offset into the seed ranges.
        val_batches: fixed number of validation sets.

    Example:
        >>> dm = CalibrationSetDataModule(image_size=(160, 120), num_views=3, board_size=(4, 3), supersample=1)
        >>> b = dm.make_batch(torch.Generator().manual_seed(0))
        >>> b["image"].shape, b["corners"].shape, b["K"].shape
        (torch.Size([3, 1, 120, 160]), torch.Size([3, 12, 2]), torch.Size([3, 3]))
    """

    def __init__(
        self,
        image_size: tuple[int, int] = (320, 240),
        num_views: int = 8,
        board_size: tuple[int, int] = (7, 5),
        square: float = 0.025,
        fx_range: tuple[float, float] = (220.0, 420.0),
        distortion: bool = True,
        sigma: float = 1.5,
        supersample: int = 2,
        seed: int = 0,
        val_batches: int = 8,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()

    def make_batch(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        hp = self.hparams
        w, h = int(hp.image_size[0]), int(hp.image_size[1])
        u = torch.rand(4, generator=generator, dtype=torch.float64)
        fx = hp.fx_range[0] + (hp.fx_range[1] - hp.fx_range[0]) * u[0]
        K = torch.tensor([[fx, 0.0, w / 2 + 0.05 * w * (2 * u[2] - 1)],
                          [0.0, fx * (1 + 0.02 * (2 * u[1] - 1)), h / 2 + 0.05 * h * (2 * u[3] - 1)],
                          [0.0, 0.0, 1.0]], dtype=torch.float64)
        dist = None
        if hp.distortion:
            dist = sample_opencv_distortion(K, (w, h), 1, generator, k1_range=(-0.3, 0.1))[0]
        scene = int(torch.randint(0, 2**31 - 1, (1,), generator=generator))
        s = make_calibration_set(K, tuple(hp.board_size), hp.square, (w, h), num_views=hp.num_views, dist=dist,
                                 seed=scene, supersample=hp.supersample)
        visible = s.corner_valid & s.corners.isfinite().all(-1)
        return {"image": s.images, "heatmap": gaussian_heatmaps(s.corners, visible, (w, h), hp.sigma),
                "corners": s.corners, "valid": s.corner_valid, "K": K,
                "dist": torch.zeros(5, dtype=torch.float64) if dist is None else dist.double(),
                "board": torch.tensor(hp.board_size), "square": torch.tensor(float(hp.square))}

    def train_dataloader(self) -> DataLoader:
        return DataLoader(RenderedBatches(self.make_batch, TRAIN_SEED_BASE + self.hparams.seed), batch_size=None)

    def val_dataloader(self) -> DataLoader:
        ds = RenderedBatches(self.make_batch, VAL_SEED_BASE + self.hparams.seed, self.hparams.val_batches)
        return DataLoader(ds, batch_size=None)
