"""valid_field: the lens's valid field on the normalized plane, every model through the same function."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, OPENCV5, RATIONAL, CentredRadialModel
from ccs_kornia.modules.undistort.valid_field import MAX_VIEW_ANGLE_DEG, valid_radius

F64 = torch.float64
K = torch.tensor([[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]], dtype=F64)
SIZE = (640, 480)
#: lenses monotonic up to the 80-degree cap, one per family
MILD = {"opencv5": Camera.from_opencv(OPENCV5, K, torch.tensor([0.1, 0.01, 0.0, 0.0, 0.0]), SIZE),
        "rational": Camera.from_opencv(RATIONAL, K, torch.tensor([0.1, 0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0]), SIZE),
        "fisheye": Camera.from_opencv(FISHEYE, K * 0.5, torch.tensor([-0.02, -0.005, 0.001, 0.0]), SIZE)}
FOLDING = {"opencv5": Camera.from_opencv(OPENCV5, K, torch.tensor([-0.5, 0.0, 0.0, 0.0, 0.0]), SIZE),
           "fisheye": Camera.from_opencv(FISHEYE, K, torch.tensor([-0.5, 1 / 60, 0.0, 0.0]), SIZE)}


@pytest.mark.parametrize("name", list(MILD))
def test_without_a_turn_the_field_is_the_cap(name):
    radius = valid_radius(MILD[name])
    assert radius.shape == (1,) and radius.dtype == F64
    assert float(radius[0]) == math.tan(math.radians(MAX_VIEW_ANGLE_DEG))


@pytest.mark.parametrize("name", list(FOLDING))
def test_a_folding_lens_is_bounded_by_its_model_rule(name):
    camera = FOLDING[name]
    radius = valid_radius(camera)
    torch.testing.assert_close(radius, camera.model.monotonic_radius(camera.params, math.radians(MAX_VIEW_ANGLE_DEG)))
    assert float(radius[0]) < 1.2


@pytest.mark.parametrize("name", list(MILD))
def test_the_corners_seen_bound_it(name):
    camera = MILD[name]
    # corners seen up to 0.45 on the normalized plane, a hidden one (NaN) ignored
    plane = torch.tensor([[[0.3, 0.0], [0.0, -0.45], [0.2, 0.2]]], dtype=F64)
    pix = torch.cat([camera.distort(plane), torch.full((1, 1, 2), float("nan"), dtype=F64)], 1)
    assert abs(float(valid_radius(camera, pix)[0]) - 0.45) < 1e-9
    # inside a folding lens's monotonic range too
    folding = FOLDING["opencv5"]
    wide = folding.distort(torch.tensor([[[0.5, 0.0], [0.0, 0.6]]], dtype=F64))
    assert abs(float(valid_radius(folding, wide)[0]) - 0.6) < 1e-9 and float(valid_radius(folding)[0]) > 0.8


def test_a_fisheye_corner_beyond_90_degrees_bounds_nothing():
    camera = MILD["fisheye"]
    theta = torch.tensor([math.radians(30.0), math.radians(100.0)], dtype=F64)
    rays = torch.stack([theta.sin(), torch.zeros_like(theta), theta.cos()], -1)[None]
    pix = camera.project(rays)
    assert abs(float(valid_radius(camera, pix[:, 1:])[0]) - math.tan(math.radians(MAX_VIEW_ANGLE_DEG))) < 1e-12
    assert abs(float(valid_radius(camera, pix)[0]) - math.tan(math.radians(100.0))) > 1  # not tan(100 deg) < 0
    assert abs(float(valid_radius(camera, pix[:, :1])[0]) - math.tan(math.radians(30.0))) < 1e-9


def test_cameras_of_several_models_in_one_batch():
    cameras = Camera.cat([FOLDING["opencv5"], MILD["fisheye"], FOLDING["fisheye"]])
    alone = torch.cat([valid_radius(c) for c in (FOLDING["opencv5"], MILD["fisheye"], FOLDING["fisheye"])])
    assert torch.equal(valid_radius(cameras), alone)
    points = torch.cat([c.distort(torch.tensor([[[0.4, 0.1]]], dtype=F64))
                        for c in (FOLDING["opencv5"], MILD["fisheye"], FOLDING["fisheye"])])
    torch.testing.assert_close(valid_radius(cameras, points), torch.minimum(alone, torch.full_like(alone, 0.4**2 + 0.01)
                                                                            .sqrt()))


def test_device_and_dtype(device, dtype):
    camera = FOLDING["fisheye"].to(device=device, dtype=dtype)
    points = FOLDING["fisheye"].distort(torch.tensor([[[0.3, 0.1]]], dtype=F64)).to(device=device, dtype=dtype)
    radius = valid_radius(camera, points)
    assert radius.device.type == device.type and radius.dtype == F64
    expected = valid_radius(FOLDING["fisheye"], points.cpu().double())
    torch.testing.assert_close(radius.cpu(), expected, atol=1e-6 if dtype == torch.float32 else 1e-12, rtol=0)


def test_errors():
    camera = MILD["opencv5"]
    with pytest.raises(ValueError, match="points"):
        valid_radius(camera, torch.zeros(3, 2, dtype=F64))
    with pytest.raises(ValueError, match="points"):
        valid_radius(camera, torch.zeros(2, 3, 2, dtype=F64))
    with pytest.raises(TypeError, match="Camera"):
        valid_radius(K[None])


def test_the_paper_radial_model_has_its_valid_field_too():
    # rho = r 400 / 640; rho (1 - 0.3 rho^2) turns at rho = 1 / sqrt(0.9)
    radial = Camera(CentredRadialModel(SIZE), torch.tensor([400.0, 400, 320, 240, -0.3, 0, 0, 0, 0], dtype=F64))
    fold = 640 / 400 / math.sqrt(0.9)
    assert fold < math.tan(math.radians(MAX_VIEW_ANGLE_DEG))
    assert fold - 4e-3 < float(valid_radius(radial)[0]) <= fold
