"""The ``precision`` benchmark section (mrcal's published corners) and its markdown; end to end on the whole set, the
board's sag, the held-out error and the model-fit flag against mrcal's figures."""

from __future__ import annotations

import json
import math

import pytest
from _real_data import REAL_DATA

from ccs_kornia import cli
from ccs_kornia.bench.config import SECTIONS, BenchConfig
from ccs_kornia.bench.sections.precision import SET, precision_md, run_precision

FIGUEROA = REAL_DATA / SET


def test_markdown_of_a_result():
    row = {"rms_px": 1.03, "fit_s": 3.2, "warp_mm": [-1.04, 0.525], "warp_std_mm": [0.006, 0.006],
           "residual_structure": {"rms_cell_means_px": 0.285, "cells_significant": 22, "cells": 24},
           "split_index": {"heldout_median_px": 0.555, "projection_difference_px": 0.4},
           "split_time": {"heldout_median_px": 0.6, "projection_difference_px": 1.3}, "vs_mrcal_opencv8_px": 0.1}
    sec = {"views": 186, "corners": 18597, "models": {"rational bent": row},
           "mrcal": {"opencv8": {"lensmodel": "LENSMODEL_OPENCV8", "calobject_warp": [-0.00104, 0.000525]}}}
    md = "\n".join(precision_md(sec))
    assert "| rational bent | 1.030 | -1.040 / +0.525 (0.006) | 0.285 / 22 of 24 | 0.555 / 0.600 |" in md
    assert "opencv8: -1.040 / +0.525 mm" in md
    assert precision_md({"skipped": "no set"}) == ["Not run: no set"]


@pytest.mark.skipif(not FIGUEROA.is_dir(), reason=f"real data not present in {REAL_DATA}")
def test_the_set_is_read_without_solving():
    assert "precision" in SECTIONS
    sec = run_precision(BenchConfig.tiny(real_dir=str(REAL_DATA)), log=lambda *_: None)
    assert sec["views"] == 186 and sec["corners"] == 18597 and sec["models"] == {}
    warp = sec["mrcal"]["opencv8"]["calobject_warp"]
    assert warp == pytest.approx([-1.0398e-3, 5.2493e-4], abs=1e-7)


@pytest.mark.e2e
@pytest.mark.skipif(not FIGUEROA.is_dir(), reason=f"real data not present in {REAL_DATA}")
def test_figueroa_end_to_end(tmp_path):
    common = ["calibrate", "--corners", str(FIGUEROA / "corners.vnl"), "--board", "10x10", "--square", "0.077",
              "--image-size", "6016x4016"]
    out = tmp_path / "rational.json"
    assert cli.main([*common, "--model", "rational", "--output", str(out)]) == 0
    data = json.loads(out.read_text())
    flat = data["board_flatness"]
    assert flat["kept"]
    assert flat["warp_m"] == pytest.approx([-1.0398e-3, 5.2493e-4], rel=0.01)  # mrcal's calobject_warp
    held = flat["heldout_median_px"]
    assert held["warp"] < 0.6 and held["flat"] > 0.9
    assert data["residual_structure"]["model_fit"] != "does not fit"
    out = tmp_path / "opencv5.json"
    assert cli.main([*common, "--model", "opencv5", "--flat-board", "--output", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["success"] and data["residual_structure"]["model_fit"] == "does not fit"
    assert data["diagnostics"]["verdict"].startswith("not reliable")


def test_mrcal_way_fits_the_rotation_near_the_centre_and_measures_where_both_saw():
    import torch

    from ccs_kornia.bench.sections.precision import mrcal_projection_difference
    from ccs_kornia.geometry.camera import Camera
    from ccs_kornia.geometry.models import K1K2

    K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
    a = Camera.from_opencv(K1K2, K, torch.tensor([-0.1, 0.01], dtype=torch.float64), (640, 480))
    shifted = Camera.from_opencv(K1K2, K + torch.tensor([[0, 0, 2.0], [0, 0, 0], [0, 0, 0]], dtype=torch.float64),
                                 torch.tensor([-0.1, 0.01], dtype=torch.float64), (640, 480))
    everywhere = torch.tensor([[x, y] for x in range(0, 640, 10) for y in range(0, 480, 10)], dtype=torch.float64)
    # a principal point 2 px over is nearly a rotation: what is left is far below the shift
    assert mrcal_projection_difference(a, shifted, everywhere, everywhere) < 0.5
    bent = Camera.from_opencv(K1K2, K, torch.tensor([-0.1, 0.03], dtype=torch.float64), (640, 480))
    centre = torch.tensor([[320.0, 240.0]], dtype=torch.float64)
    corner = torch.tensor([[5.0, 5.0]], dtype=torch.float64)
    # k2 moves the corners of the image, not its centre; a grid point only one calibration saw does not count
    assert mrcal_projection_difference(a, bent, centre, centre) < 0.01
    assert mrcal_projection_difference(a, bent, corner, corner) > 1.0
    assert math.isnan(mrcal_projection_difference(a, bent, centre, corner))
