"""Undistortion and stereo rectification of a splined camera go through its own maps: a spline set to an OpenCV lens
undistorts and rectifies as that lens does."""

from __future__ import annotations

import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import K1K2, SplinedStereographicModel
from ccs_kornia.modules.calibration.splined import spline_from_camera
from ccs_kornia.modules.rig.stereo import stereo_rectify
from ccs_kornia.modules.undistort.undistort_image import undistortion_map
from ccs_kornia.outputs.calibration_file import camera_record_fields
from ccs_kornia.outputs.rig_records import rectify_maps

SIZE = (64, 48)


def _pair() -> tuple[Camera, Camera]:
    K = torch.tensor([[40.0, 0, 31.5], [0, 40, 23.5], [0, 0, 1]], dtype=torch.float64)
    lens = Camera.from_opencv(K1K2, K, torch.tensor([-0.2, 0.05], dtype=torch.float64), SIZE)
    model = SplinedStereographicModel(12, 9, 100)
    return lens, Camera(model, spline_from_camera(model, lens, SIZE), SIZE)


def test_undistortion_map_of_a_spline_is_its_lens():
    lens, spline = _pair()
    a, b = undistortion_map(lens, SIZE), undistortion_map(spline, SIZE)
    inside = (a[..., 0] > 0) & (a[..., 0] < SIZE[0] - 1) & (a[..., 1] > 0) & (a[..., 1] < SIZE[1] - 1)
    assert float((a - b).norm(dim=-1)[inside].max()) < 0.02


def test_rectification_maps_of_a_spline_are_its_lens():
    lens, spline = _pair()
    R, T = torch.eye(3, dtype=torch.float64), torch.tensor([-0.1, 0.0, 0.0], dtype=torch.float64)
    rect = stereo_rectify(lens, lens, SIZE, R, T)
    rect = {**{k: np.asarray(v).tolist() for k, v in rect.items() if k[0] in "RP"}, "image_size": list(SIZE)}
    cams = [camera_record_fields(c) for c in (lens, spline)]
    (ax, ay), (bx, by) = rectify_maps({"cameras": cams}, rect, 0, 1)
    inside = (ax > 0) & (ax < SIZE[0] - 1) & (ay > 0) & (ay < SIZE[1] - 1)
    assert float(np.hypot(ax - bx, ay - by)[inside].max()) < 0.02
    # the splined camera's pair is rectified as the undistorted pair (no OpenCV coefficients for it)
    assert stereo_rectify(spline, spline, SIZE, R, T)["P2"][0, 3] < 0
