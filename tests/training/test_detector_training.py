from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

from ccs_kornia.data.datamodules.datamodule import DetectorDataModule, RenderedBatches
from ccs_kornia.training.detector import DetectorLitModule

REPO = Path(__file__).resolve().parents[2]


def test_datamodule_batches_are_seeded_and_shaped():
    dm = DetectorDataModule(image_size=(96, 64), batch_size=3, supersample=1, val_batches=2)
    a = dm.make_batch(torch.Generator().manual_seed(5))
    b = dm.make_batch(torch.Generator().manual_seed(5))
    assert a["image"].shape == (3, 1, 64, 96) and a["heatmap"].shape == (3, 1, 64, 96)
    assert torch.equal(a["image"], b["image"]) and torch.equal(a["corners"], b["corners"])
    assert a["heatmap"].max() <= 1.0 and a["heatmap"].max() > 0.5
    val = list(RenderedBatches(dm.make_batch, seed=1_000_000, num_batches=2))
    assert len(val) == 2


def test_lit_module_step_reduces_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    dm = DetectorDataModule(image_size=(96, 96), batch_size=4, supersample=1, board_cols=(3, 5), board_rows=(2, 4))
    batch = dm.make_batch(torch.Generator().manual_seed(0))
    module = DetectorLitModule(base_channels=4, depth=2)
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    first = None
    for _ in range(15):
        loss = module.loss(module(batch["image"]), batch["heatmap"])
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < first
    exported = module.export()
    assert exported["config"] == {"base_channels": 4, "depth": 2, "norm": "batch"}


def test_cli_fit_fast_dev_run(tmp_path):
    cmd = [
        sys.executable, "-m", "ccs_kornia", "fit", "--config", str(REPO / "lightning_configs" / "detector.yaml"),
        "--trainer.fast_dev_run=1", "--trainer.enable_progress_bar=false",
        f"--trainer.default_root_dir={tmp_path}", f"--trainer.logger.init_args.save_dir={tmp_path}",
        f"--trainer.callbacks.init_args.dirpath={tmp_path / 'ckpt'}",
        "--data.init_args.image_size=[96,64]", "--data.init_args.batch_size=2", "--data.init_args.num_workers=0",
        "--data.init_args.val_batches=1",
    ]
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "fast_dev_run" in (out.stdout + out.stderr)


def test_init_weights_starts_from_an_exported_file(tmp_path):
    torch.manual_seed(0)
    src = DetectorLitModule(base_channels=4, depth=2)
    path = tmp_path / "w.pt"
    torch.save(src.export(), path)
    torch.manual_seed(1)
    module = DetectorLitModule(base_channels=4, depth=2, init_weights=str(path))
    x = torch.rand(1, 1, 32, 32)
    src.eval(), module.eval()
    assert not torch.allclose(module(x), src(x))  # not loaded at construction (load_from_checkpoint needs no file)
    module.setup("fit")
    for k, v in src.net.state_dict().items():
        assert torch.equal(module.net.state_dict()[k], v)
    assert torch.allclose(module(x), src(x))
    module.setup("validate")  # only fitting loads
    other = DetectorLitModule(base_channels=8, depth=2, init_weights=str(path))
    with pytest.raises(ValueError, match="expected CornerUNet"):
        other.setup("fit")


def test_init_weights_loads_the_shipped_file():
    path = REPO / "ccs_kornia" / "weights" / "corner_unet.pt"
    payload = torch.load(path, map_location="cpu", weights_only=True)
    module = DetectorLitModule(**payload["config"], init_weights=str(path))
    module.setup("fit")
    state = module.net.state_dict()
    assert all(torch.equal(state[k], v) for k, v in payload["state_dict"].items())


def test_teacher_heatmaps_add_a_distillation_term_and_stay_out_of_checkpoints(tmp_path):
    """A narrower student learns the shipped network's heatmaps as well as the exact targets; the frozen teacher is no
    submodule: not in the state dict, the optimiser or the export."""
    torch.manual_seed(0)
    dm = DetectorDataModule(image_size=(64, 64), batch_size=2, supersample=1, board_cols=(3, 5), board_rows=(2, 4))
    batch = dm.make_batch(torch.Generator().manual_seed(0))
    teacher = DetectorLitModule(base_channels=4, depth=2)
    path = tmp_path / "teacher.pt"
    torch.save(teacher.export(), path)
    student = DetectorLitModule(base_channels=2, depth=2, teacher_weights=str(path), teacher_loss_weight=0.5)
    assert student.teacher is None  # loaded when fitting starts
    student.setup("fit")
    student.log = lambda *a, **k: None  # no trainer attached
    loss = student.training_step(batch, 0)
    pred = student(batch["image"])
    with torch.no_grad():
        soft = teacher.eval()(batch["image"])
    expected = student.loss(pred, batch["heatmap"]) + 0.5 * student.loss(pred, soft)
    assert torch.allclose(loss, expected)
    assert not any(k.startswith("teacher") for k in student.state_dict())
    assert all(not p.requires_grad for p in student.teacher.parameters())
    assert sum(p.numel() for p in student.parameters()) == sum(p.numel() for p in student.net.parameters())
    assert student.export()["config"]["base_channels"] == 2
