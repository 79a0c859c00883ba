"""End-to-end training of the heatmap network through the solver: the data, one step, the command line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from ccs_kornia.data.datamodules.calibration_datamodule import CalibrationSetDataModule
from ccs_kornia.training.end_to_end import EndToEndLitModule, intrinsic_error

REPO = Path(__file__).resolve().parents[2]
TINY = dict(image_size=(200, 150), num_views=4, board_size=(5, 4), fx_range=(150.0, 220.0), supersample=1)


@pytest.fixture(scope="module")
def batch():
    return CalibrationSetDataModule(**TINY).make_batch(torch.Generator().manual_seed(3))


def test_calibration_sets_are_seeded_and_exact(batch):
    again = CalibrationSetDataModule(**TINY).make_batch(torch.Generator().manual_seed(3))
    assert torch.equal(batch["image"], again["image"]) and torch.equal(batch["K"], again["K"])
    assert batch["heatmap"].shape == batch["image"].shape and batch["heatmap"].max() > 0.5
    assert batch["dist"].shape == (5,) and tuple(batch["board"].tolist()) == TINY["board_size"]
    plain = CalibrationSetDataModule(**TINY, distortion=False).make_batch(torch.Generator().manual_seed(3))
    assert torch.equal(plain["dist"], torch.zeros(5, dtype=torch.float64))


def test_intrinsic_error_matches_the_paper_definition():
    K = torch.tensor([[300.0, 0, 160], [0, 302, 119], [0, 0, 1]])
    assert float(intrinsic_error(K, torch.tensor([[301.0, 0, 158], [0, 300, 120], [0, 0, 1]]))) == pytest.approx(3.0)


def test_training_step_reaches_the_network_through_the_solver(batch):
    module = EndToEndLitModule(heatmap_weight=0.0)  # the camera's error alone
    module.setup("fit")
    module.train()
    assert not module.net.training  # normalisation frozen
    out = module.calibrate(batch)
    assert out["found"].all() and out["success"] and out["K"].requires_grad
    assert float(intrinsic_error(out["K"].detach(), batch["K"])) < 5.0
    loss = module.training_step(batch, 0)
    loss.backward()
    grads = [p.grad for p in module.net.parameters() if p.grad is not None]
    assert loss.isfinite() and grads and all(g.isfinite().all() for g in grads)
    assert sum(float(g.abs().sum()) for g in grads) > 0


def test_cli_fit_fast_dev_run(tmp_path):
    size = ",".join(str(v) for v in TINY["image_size"])
    board = ",".join(str(v) for v in TINY["board_size"])
    cmd = [
        sys.executable, "-m", "ccs_kornia", "fit", "--config", str(REPO / "lightning_configs" / "end_to_end.yaml"),
        "--trainer.fast_dev_run=1", "--trainer.enable_progress_bar=false",
        f"--trainer.default_root_dir={tmp_path}", f"--trainer.logger.init_args.save_dir={tmp_path}",
        f"--trainer.callbacks.init_args.dirpath={tmp_path / 'ckpt'}",
        f"--model.init_args.init_weights={REPO / 'ccs_kornia' / 'weights' / 'corner_unet.pt'}",
        f"--data.init_args.image_size=[{size}]", f"--data.init_args.board_size=[{board}]",
        "--data.init_args.num_views=3", "--data.init_args.fx_range=[150,220]", "--data.init_args.val_batches=1",
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO)}  # this checkout's package, whatever is installed
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "fast_dev_run" in (out.stdout + out.stderr)
