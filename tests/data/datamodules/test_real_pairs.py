"""Self-labelled real pairs: shapes of the batches, corners that stay on the image's corners under every degradation,
and the self-training recipe that parses."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.datamodules.real_pairs_datamodule import (
    DEGRADATIONS,
    HELD_OUT_SETS,
    SELF_TRAINING_SETS,
    RealPairsDataModule,
    _draw,
    degrade_crop,
)

REPO = Path(__file__).resolve().parents[3]


def _dots(size=(160, 200), spacing=24.0, offset=(20.3, 17.6)):
    """A dark image with bright Gaussian dots at known sub-pixel positions (a stand-in for corners)."""
    h, w = size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.array([[offset[0] + i * spacing, offset[1] + j * spacing] for j in range(5) for i in range(6)])
    img = np.full(size, 30.0)
    for x, y in pts:
        img += 200.0 * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 3.0 ** 2))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), pts


def _centroid(view, p, r=4):
    x0, y0 = round(p[0]), round(p[1])
    win = view[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1].astype(np.float64)
    win = np.clip(win - np.median(view), 0, None)
    ys, xs = np.mgrid[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1]
    return np.array([(win * xs).sum(), (win * ys).sum()]) / win.sum()


@pytest.mark.parametrize("condition", ["clean", *DEGRADATIONS])
def test_degraded_crop_keeps_the_labels_on_the_dots(condition):
    img, pts = _dots()
    rng = np.random.default_rng(3)
    params = _draw(rng, (condition,))
    params.pop("motion", None)  # a line blur moves no centroid but smears the dots into each other's windows
    view, moved = degrade_crop(img, pts, pts[14], 24.0, 14.0, 64, params, rng)
    assert view.shape == (64, 64) and view.dtype == np.float32 and moved.shape == pts.shape
    inside = [p for p in moved if 6 <= p[0] <= 57 and 6 <= p[1] <= 57]
    assert len(inside) >= 4
    err = [np.linalg.norm(_centroid(view, p) - p) for p in inside]
    assert max(err) < 0.35, err


def test_mixed_degradations_keep_the_labels_on_the_dots():
    img, pts = _dots()
    rng = np.random.default_rng(4)
    view, moved = degrade_crop(img, pts, pts[14], 24.0, 12.0, 64, {"small": 0.5, "light": 0.3, "jpeg": 40}, rng)
    inside = [p for p in moved if 6 <= p[0] <= 57 and 6 <= p[1] <= 57]
    assert len(inside) >= 4
    assert max(np.linalg.norm(_centroid(view, p) - p) for p in inside) < 0.5


def test_batches_hold_targets_at_the_labels(tmp_path):
    img, pts = _dots()
    cv2.imwrite(str(tmp_path / "a.png"), img)
    labels = {"real_dir": str(tmp_path), "views": [{"set": "s", "file": "a.png", "corners": pts.tolist(),
                                                    "square_px": 24.0}], "left_out": {}}
    (tmp_path / "labels.json").write_text(json.dumps(labels))
    dm = RealPairsDataModule(str(tmp_path / "labels.json"), crop=48, batch_size=3, level_square=(10.0, 14.0),
                             rendered_prob=0.0)
    a = dm.make_batch(torch.Generator().manual_seed(1))
    b = dm.make_batch(torch.Generator().manual_seed(1))
    assert a["image"].shape == (3, 1, 48, 48) and a["heatmap"].shape == (3, 1, 48, 48)
    assert a["corners"].shape[0] == 3 and a["corners"].shape[-1] == 2 and a["valid"].shape == a["corners"].shape[:2]
    assert torch.equal(a["image"], b["image"]) and torch.equal(a["corners"], b["corners"])
    # each valid label sits on a target peak
    for i, j in a["valid"].nonzero().tolist():
        x, y = a["corners"][i, j].round().long().tolist()
        assert float(a["heatmap"][i, 0, y, x]) > 0.7
    assert int(a["valid"].sum()) > 0


def test_split_keeps_the_benchmark_sets_out_of_training():
    assert not set(SELF_TRAINING_SETS) & set(HELD_OUT_SETS)
    with pytest.raises(ValueError):
        _draw(np.random.default_rng(0), ("fog",))


def test_selftrain_recipe_parses():
    from lightning.pytorch.cli import LightningCLI

    cli = LightningCLI(subclass_mode_model=True, subclass_mode_data=True, run=False, save_config_callback=None,
                       args=["--config", str(REPO / "lightning_configs" / "detector_selftrain.yaml")])
    assert type(cli.datamodule).__name__ == "RealPairsDataModule"
    assert cli.model.hparams.init_weights == "ccs_kornia/weights/corner_unet.pt"
    assert cli.datamodule.hparams.rendered_prob == 0.25
