"""Tests of the distortion CNN's training: data module, LightningModule, CLI recipe and weight export."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

from ccs_kornia.data.datamodules.distortion_datamodule import (
    DistortionDataModule,
    flip_batch,
)
from ccs_kornia.modules.correction.distortion_net import DistortionNet
from ccs_kornia.modules.correction.straightness import straightness_rms
from ccs_kornia.training.distortion import DistortionLitModule
from ccs_kornia.training.export import export_checkpoint

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data() -> DistortionDataModule:
    return DistortionDataModule(image_size=(96, 72), batch_size=8, fx_range=(50.0, 130.0), supersample=1, reuse=4,
                                val_batches=2)


@pytest.fixture(scope="module")
def batch(data) -> dict[str, torch.Tensor]:
    return data.make_batch(torch.Generator().manual_seed(3))


def test_batch_contents(data, batch):
    assert batch["image"].shape == (8, 1, 72, 96)
    assert batch["radial"].shape == (8, 3)
    n = batch["corners"].shape[1]
    assert batch["valid"].shape == (8, n) and batch["board_size"].shape == (8, 2) and batch["level"].shape == (8,)
    assert 0 <= float(batch["image"].min()) and float(batch["image"].max()) <= 1
    none = batch["level"] == data.levels.index("none")
    ident = torch.tensor([1.0, 0.0, 0.0])
    assert torch.equal(batch["radial"][none], ident.expand(int(none.sum()), 3))
    assert (batch["radial"][~none, 1] < 0).all()  # every radial level is barrel
    assert batch["valid"].any(-1).all()


def test_batches_are_seeded(data, batch):
    again = data.make_batch(torch.Generator().manual_seed(3))
    for key in batch:
        assert torch.equal(batch[key], again[key])
    other = data.make_batch(torch.Generator().manual_seed(4))
    assert not torch.equal(batch["image"], other["image"])


def test_train_and_validation_streams_differ(data):
    train = next(iter(data.train_dataloader()))
    val = next(iter(data.val_dataloader()))
    assert not torch.equal(train["radial"], val["radial"])
    assert len(list(data.val_dataloader())) == 2


def test_reuse_mirrors_the_cached_batch(data):
    it = iter(data.train_dataloader())
    first = [next(it) for _ in range(4)]
    fresh = next(it)
    base = first[0]
    torch.testing.assert_close(first[1]["image"], base["image"].flip(-1))
    torch.testing.assert_close(first[2]["image"], base["image"].flip(-2))
    torch.testing.assert_close(first[3]["image"], base["image"].flip(-1, -2))
    for b in first:
        assert torch.equal(b["radial"], base["radial"])
    assert not torch.equal(fresh["image"], base["image"])


def test_flip_keeps_corners_on_the_image_and_lines_straight(batch):
    flipped = flip_batch(batch, horizontal=True, vertical=True)
    v = batch["valid"]
    w, h = 96, 72
    torch.testing.assert_close(flipped["corners"][v], torch.tensor([w - 1.0, h - 1.0]) - batch["corners"][v])
    before, _ = straightness_rms(batch["corners"], v, batch["board_size"])
    after, _ = straightness_rms(flipped["corners"], v, batch["board_size"])
    torch.testing.assert_close(before, after, atol=1e-4, rtol=1e-4)
    assert flip_batch(batch, False, False) is batch


def test_datamodule_rejects_bad_settings():
    with pytest.raises(ValueError, match="level"):
        DistortionDataModule(levels=("level3",))
    with pytest.raises(ValueError, match="reuse"):
        DistortionDataModule(reuse=5)
    with pytest.raises(ValueError, match="levels"):
        DistortionDataModule(levels=())


def test_lit_module_steps_and_export(batch):
    torch.manual_seed(0)
    module = DistortionLitModule(base_channels=4, input_size=64, hidden=(32, 16), grid_size=8, lr=3e-3)
    loss = module.training_step(batch, 0)
    assert loss.ndim == 0 and torch.isfinite(loss) and float(loss) > 0
    module.eval()
    with torch.no_grad():
        module.validation_step(batch, 0)  # logs without a trainer; must not fail
    payload = module.export()
    assert payload["kind"] == "DistortionNet"
    net = DistortionNet.from_export(payload)
    with torch.no_grad():
        torch.testing.assert_close(net(batch["image"]), module(batch["image"]))


def test_fix_scale_targets():
    radial = torch.tensor([[0.8, -0.4, -0.2], [1.0, -0.3, 0.0]])
    fixed = DistortionLitModule(base_channels=4, input_size=32, hidden=(8, 8))
    raw = DistortionLitModule(base_channels=4, input_size=32, hidden=(8, 8), fix_scale=False)
    assert torch.equal(raw.target_distortion(radial), radial)
    t = fixed.target_distortion(radial)
    torch.testing.assert_close(t, torch.tensor([[1.0, -0.4 / 0.8**3, -0.2 / 0.8**5], [1.0, -0.3, 0.0]]))


def test_a_few_steps_reduce_the_loss(batch):
    torch.manual_seed(0)
    module = DistortionLitModule(base_channels=4, input_size=64, hidden=(32, 16), grid_size=8)
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    first = None
    for _ in range(25):
        opt.zero_grad()
        loss = module.training_step(batch, 0)
        loss.backward()
        opt.step()
        first = float(loss) if first is None else first
    assert float(loss) < 0.7 * first, (first, float(loss))


def test_cli_fast_dev_run_and_export(tmp_path):
    cfg = REPO / "lightning_configs" / "distortion.yaml"
    cmd = [
        sys.executable, "-m", "ccs_kornia", "fit", "--config", str(cfg),
        "--trainer.fast_dev_run=1",
        "--trainer.enable_progress_bar=false",
        f"--trainer.default_root_dir={tmp_path / 'run'}",
        f"--trainer.logger.init_args.save_dir={tmp_path / 'run'}",
        f"--trainer.callbacks.init_args.dirpath={tmp_path / 'ckpt'}",
        # keep the recipe's model and data classes, render less (the test runs on a shared 2-core machine)
        "--data.init_args.batch_size=4",
        "--data.init_args.image_size=[128, 96]",
        "--data.init_args.supersample=1",
        "--data.init_args.num_workers=0",
    ]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "max_steps=1" in proc.stderr + proc.stdout
    ckpt = tmp_path / "ckpt" / "last.ckpt"
    assert ckpt.exists()
    payload = export_checkpoint(ckpt, tmp_path / "distortion_net.pt")
    assert payload["trained_steps"] == 1 and payload["config"]["input_size"] == 256
    net = DistortionNet.from_export(tmp_path / "distortion_net.pt")
    with torch.no_grad():
        assert net(torch.rand(1, 1, 120, 160)).shape == (1, 5)


def test_init_weights_starts_from_the_shipped_file():
    path = REPO / "ccs_kornia" / "weights" / "distortion_net.pt"
    payload = torch.load(path, map_location="cpu", weights_only=True)
    module = DistortionLitModule(**payload["config"], init_weights=str(path))
    assert not all(torch.equal(module.net.state_dict()[k], v) for k, v in payload["state_dict"].items())
    module.setup("fit")
    assert all(torch.equal(module.net.state_dict()[k], v) for k, v in payload["state_dict"].items())
    small = DistortionLitModule(base_channels=4, input_size=64, hidden=(16, 8), init_weights=str(path))
    with pytest.raises(ValueError, match="expected DistortionNet"):
        small.setup("fit")
