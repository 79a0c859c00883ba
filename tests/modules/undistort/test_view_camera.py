"""view_camera: the undistorted view's camera from the valid visible region, every model through the same code."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, PINHOLE
from ccs_kornia.modules.undistort.valid_field import valid_radius
from ccs_kornia.modules.undistort.view_camera import (
    horizontal_fov,
    valid_region_radii,
    view_camera_matrix,
)

F64 = torch.float64
SIZE = (100, 80)
K = torch.tensor([[[100.0, 0, 49.5], [0, 120, 39.5], [0, 0, 1]]], dtype=F64)
PIN = Camera.from_opencv(PINHOLE, K, None, SIZE)

VIEW_SIZE = (640, 480)
K_VIEW = torch.tensor([[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]], dtype=F64)
BARREL = Camera.from_opencv(OPENCV5, K_VIEW, torch.tensor([-0.3, 0.1, 0.001, -0.0005, 0.0]), VIEW_SIZE)
#: monotonic; 640x480 sees about 100 degrees
WIDE = Camera.from_opencv(FISHEYE, torch.tensor([[200.0, 0, 322.0], [0, 201.0, 236.0], [0, 0, 1]], dtype=F64),
                          torch.tensor([-0.02, -0.005, 0.001, 0.0]), VIEW_SIZE)
LENSES = {"opencv5": BARREL, "fisheye": WIDE}


def _rays_of_view(P: torch.Tensor, size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Each pixel of the view on the normalized plane :math:`(1, H W, 2)`, and its radius :math:`(H, W)`."""
    w, h = size
    v, u = torch.meshgrid(torch.arange(h, dtype=F64), torch.arange(w, dtype=F64), indexing="ij")
    x, y = (u - P[0, 0, 2]) / P[0, 0, 0], (v - P[0, 1, 2]) / P[0, 1, 1]
    return torch.stack([x, y], -1).reshape(1, -1, 2), torch.hypot(x, y)


def test_region_radii_of_a_pinhole_are_the_image_borders(device):
    dirs = torch.tensor([[[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.6, 0.8]]], dtype=F64, device=device)
    radii = valid_region_radii(PIN.to(device), torch.tensor([10.0], dtype=F64, device=device), SIZE, dirs)
    expected = torch.tensor([[49.5 / 100, 49.5 / 100, 39.5 / 120, min(49.5 / 100 / 0.6, 39.5 / 120 / 0.8)]],
                            dtype=F64, device=device)
    torch.testing.assert_close(radii, expected, atol=1e-6, rtol=0)


def test_region_radii_stop_at_the_valid_radius():
    dirs = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]], dtype=F64)
    radii = valid_region_radii(PIN, torch.tensor([0.2], dtype=F64), SIZE, dirs)
    torch.testing.assert_close(radii, torch.full((1, 2), 0.2, dtype=F64))


def test_pinhole_without_distortion_gets_its_own_camera_back():
    for balance in (0.0, 1.0):  # the whole image is the region: balance 1 is the same view
        torch.testing.assert_close(view_camera_matrix(PIN, SIZE, balance), K, atol=1e-4, rtol=0)


def test_balance_is_linear_in_the_focal_length_and_keeps_aspect_and_centre():
    radius = torch.tensor([0.3], dtype=F64)  # a disc inside the image: corners of the view black at 1
    f = [view_camera_matrix(PIN, SIZE, b, max_radius=radius) for b in (0.0, 0.5, 1.0)]
    assert f[1][0, 0, 0] < f[0][0, 0, 0]
    torch.testing.assert_close(f[1][0, 0, 0], (f[0][0, 0, 0] + f[2][0, 0, 0]) / 2)
    for P in f:
        assert P[0, 0, 2] == 49.5 and P[0, 1, 2] == 39.5 and P[0, 0, 1] == 0
        torch.testing.assert_close(P[0, 1, 1] / P[0, 0, 0], K[0, 1, 1] / K[0, 0, 0])
    # balance 0: the view's corner on the disc; balance 1: the disc's top and bottom on the view's border
    corner = torch.tensor([49.5 / f[0][0, 0, 0], 39.5 / f[0][0, 1, 1]]).norm()
    assert abs(corner - 0.3) < 1e-5
    assert abs(39.5 / f[2][0, 1, 1] - 0.3) < 1e-3


@pytest.mark.parametrize("balance", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("dist", [[-0.3, 0.1, 0.001, -0.0005, 0.0], [0.1, -0.02, 0.0, 0.0, 0.0]], ids=["barrel", "pincushion"])
def test_opencv_lens_matches_cv2_optimal_new_camera_matrix(balance, dist):
    # a lens monotonic over the image: OpenCV's alpha with the principal point centred is the same framing
    camera = Camera.from_opencv(OPENCV5, K_VIEW, torch.tensor(dist), VIEW_SIZE)
    ref, _ = cv2.getOptimalNewCameraMatrix(K_VIEW.numpy(), np.array(dist), VIEW_SIZE, balance, centerPrincipalPoint=True)
    ours = view_camera_matrix(camera, VIEW_SIZE, balance)[0].numpy()
    np.testing.assert_allclose(ours[[0, 1], [0, 1]], ref[[0, 1], [0, 1]], rtol=3e-3)  # cv2 samples a 9x9 grid
    np.testing.assert_allclose(ours[:2, 2], [319.5, 239.5])


@pytest.mark.parametrize("balance", [0.0, 0.5])
@pytest.mark.parametrize("name", list(LENSES))
def test_no_black_pixels_at_balance_zero(name, balance):
    camera = LENSES[name]
    radius = torch.tensor([math.tan(math.radians(50.0 if name == "opencv5" else 70.0))], dtype=F64)
    P = view_camera_matrix(camera, VIEW_SIZE, balance, max_radius=radius)
    plane, r = _rays_of_view(P, VIEW_SIZE)
    src = camera.distort(plane)[0].reshape(*r.shape, 2)
    slack = 1e-3  # px: the border is traced at 257 points a side, the region may bend in between
    inside = (src[..., 0] >= -slack) & (src[..., 0] <= 639 + slack) & (src[..., 1] >= -slack)
    inside &= (src[..., 1] <= 479 + slack) & (r <= radius[0] + 1e-9)
    if balance == 0.0:  # every pixel in the image and in the valid field
        assert bool(inside.all())
    else:
        assert 0.0 < 1 - inside.double().mean() < 0.3
    # centred on the axis, no shear, the aspect of K kept
    assert (P[0, 0, 2], P[0, 1, 2], P[0, 0, 1]) == (319.5, 239.5, 0.0)
    torch.testing.assert_close(P[0, 1, 1] / P[0, 0, 0], camera.K[0, 1, 1] / camera.K[0, 0, 0])


def test_balance_one_shows_the_whole_valid_field_of_a_fisheye():
    radius = torch.tensor([math.tan(math.radians(60.0))], dtype=F64)
    P0 = view_camera_matrix(WIDE, VIEW_SIZE, 0.0, max_radius=radius)
    P1 = view_camera_matrix(WIDE, VIEW_SIZE, 1.0, max_radius=radius)
    assert P1[0, 0, 0] < P0[0, 0, 0]  # more field
    # every ray of the valid field that lands in the image lands in the view too
    phi = torch.linspace(0, 2 * math.pi, 721, dtype=F64)
    theta = torch.linspace(0, math.radians(60.0), 61, dtype=F64)
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    rays = torch.stack([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()], -1).reshape(1, -1, 3)
    src = WIDE.project(rays)[0]
    seen = (src[:, 0] >= 0) & (src[:, 0] <= 639) & (src[:, 1] >= 0) & (src[:, 1] <= 479)
    view = rays[0, seen, :2] / rays[0, seen, 2:] * P1[0, [0, 1], [0, 1]] + P1[0, :2, 2]
    assert bool(((view >= -1e-3) & (view <= torch.tensor([639.001, 479.001], dtype=F64))).all())
    # while the view at balance 0 cuts some of it off
    view0 = rays[0, seen, :2] / rays[0, seen, 2:] * P0[0, [0, 1], [0, 1]] + P0[0, :2, 2]
    assert not bool(((view0 >= 0) & (view0 <= torch.tensor([639.0, 479.0], dtype=F64))).all())


def test_folding_lens_is_framed_before_the_fold():
    # r_d = r (1 - 0.5 r^2) folds at r = 1 / sqrt(1.5), 0.816, whose image radius 0.544 f = 228 px is inside the image
    camera = Camera.from_opencv(K1K2, K_VIEW, torch.tensor([-0.5, 0.0]), VIEW_SIZE)
    radius = valid_radius(camera)
    for balance in (0.0, 1.0):
        P = view_camera_matrix(camera, VIEW_SIZE, balance)
        # no pixel of the view sees past the fold at balance 0; at 1 the view's borders reach the fold, not beyond
        corner = torch.tensor([319.5 / P[0, 0, 0], 239.5 / P[0, 1, 1]]).norm()
        edge = min(319.5 / P[0, 0, 0], 239.5 / P[0, 1, 1])
        assert (corner <= radius[0] + 1e-6) if balance == 0.0 else (abs(edge - radius[0]) < 1e-3)


@pytest.mark.parametrize("name", list(LENSES))
def test_fov_is_explicit_and_clamped_to_the_valid_field(name):
    radius = torch.tensor([math.tan(math.radians(40.0))], dtype=F64)
    P = view_camera_matrix(LENSES[name], VIEW_SIZE, fov=50.0, max_radius=radius)
    assert abs(float(horizontal_fov(P, VIEW_SIZE)[0]) - 50.0) < 1e-9
    P = view_camera_matrix(LENSES[name], VIEW_SIZE, fov=120.0, max_radius=radius)
    assert abs(float(horizontal_fov(P, VIEW_SIZE)[0]) - 80.0) < 0.1  # the 40-degree disc, both sides


def test_batch_is_per_camera_of_any_model():
    both = view_camera_matrix(Camera.cat([BARREL, WIDE]), VIEW_SIZE, 0.5)
    alone = torch.cat([view_camera_matrix(BARREL, VIEW_SIZE, 0.5), view_camera_matrix(WIDE, VIEW_SIZE, 0.5)])
    torch.testing.assert_close(both, alone, atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", list(LENSES))
def test_device_and_dtype(name, device, dtype):
    camera = LENSES[name]
    on = [view_camera_matrix(camera.to(device=device, dtype=dtype), VIEW_SIZE, b) for b in (0.0, 1.0)]
    off = [view_camera_matrix(camera.to(dtype=dtype), VIEW_SIZE, b) for b in (0.0, 1.0)]
    for a, b in zip(on, off):
        assert a.device.type == device.type and a.dtype == F64  # framed in float64
        torch.testing.assert_close(a.cpu(), b)


def test_errors():
    r = torch.tensor([1.0], dtype=F64)
    with pytest.raises(TypeError, match="Camera"):
        view_camera_matrix(K, SIZE)
    with pytest.raises(ValueError, match="max_radius"):
        view_camera_matrix(PIN, SIZE, max_radius=torch.ones(2, dtype=F64))
    with pytest.raises(ValueError, match="balance"):
        view_camera_matrix(PIN, SIZE, balance=1.5)
    with pytest.raises(ValueError, match="fov"):
        view_camera_matrix(PIN, SIZE, fov=180.0)
    with pytest.raises(ValueError, match="directions"):
        valid_region_radii(PIN, r, SIZE, torch.ones(1, 2))
    with pytest.raises(ValueError, match=r"directions must be \(B, P, 2\) \(one per camera\) with B=1, got"):
        valid_region_radii(PIN, r, SIZE, torch.ones(2, 1, 2))
    outside = K.clone()
    outside[0, 0, 2] = -50.0  # principal point left of the image
    with pytest.raises(ValueError, match="no part of the image"):
        view_camera_matrix(Camera.from_opencv(PINHOLE, outside, None, SIZE), SIZE, max_radius=r)
