"""Rig solver on a real stereo head: BoofCV's Bumblebee2 pair (11 frames, 4x6 board, 30 mm squares).

The reference is BoofCV's own stereo calibration shipped with the images (``reference/stereo.yaml``: right-to-left
transform, ``x_left = R x_right + T``), so ``x_right = R^T x_left - R^T T`` in the solver's convention.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.rig import RigSolver

LEFT, RIGHT = REAL_DATA / "boofcv_bumblebee2_left", REAL_DATA / "boofcv_bumblebee2_right"


def _reference():
    yaml = pytest.importorskip("yaml")
    ref = yaml.safe_load((LEFT / "reference" / "stereo.yaml").read_text())["rightToLeft"]
    R_rl = torch.tensor(ref["rotation"], dtype=torch.float64).reshape(3, 3)
    T_rl = torch.tensor([ref["x"], ref["y"], ref["z"]], dtype=torch.float64)
    return R_rl.T, -R_rl.T @ T_rl


@pytest.mark.skipif(not (LEFT.is_dir() and RIGHT.is_dir()), reason=f"real data not present in {REAL_DATA}")
def test_bumblebee2_baseline_and_rotation_match_boofcv():
    from ccs_kornia import CalibrationPipeline
    from ccs_kornia.io.images import load_image_gray
    images = []
    for side, folder in (("left", LEFT), ("right", RIGHT)):
        row = [torch.from_numpy(np.asarray(load_image_gray(folder / f"{side}{i:02d}.jpg")[0], dtype=np.float32))[None]
               for i in range(1, 12)]
        images.append(torch.stack(row))
    det = CalibrationPipeline(model=K1K2).detect(torch.stack(images), (4, 6))
    assert bool(det.found.all())
    obj = board_object_points(4, 6, 30.0, dtype=torch.float64)
    res = RigSolver(K1K2)(det.corners.double(), det.valid, obj, [(640, 480)] * 2, names=["left", "right"])
    R_ref, T_ref = _reference()
    assert res.success and res.verdict == "good", res.reasons
    assert abs(float(res.T[1].norm()) / float(T_ref.norm()) - 1) < 0.01  # baseline within 1 % (120.05 mm)
    assert float(log_so3(res.R[1] @ R_ref.T).norm()) * 180 / math.pi < 1.0
    assert res.rms < 0.2 and float(res.heldout_epipolar_rms[0, 1]) < 0.2
