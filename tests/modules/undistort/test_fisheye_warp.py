"""fisheye_warp: the view framed within the valid field, cv2.fisheye's new camera matrix and undistortImage."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.camera import kb_project_points
from ccs_kornia.modules.undistort.fisheye_warp import (
    fisheye_new_camera_matrix,
    fisheye_undistort_image,
    fisheye_valid_angle,
    fisheye_view_camera_matrix,
)
from ccs_kornia.modules.undistort.view_camera import MAX_VIEW_ANGLE_DEG, horizontal_fov

K = np.array([[400.0, 0, 330.0], [0, 402.0, 236.0], [0, 0, 1.0]])
D = np.array([0.05, -0.01, 0.002, 0.0])


@pytest.mark.parametrize("balance", [0.0, 0.5, 1.0])
def test_new_camera_matrix_matches_opencv(balance):
    ref = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (640, 480), np.eye(3), balance=balance)
    ours = fisheye_new_camera_matrix(torch.tensor(K)[None], torch.tensor(D)[None], (640, 480), balance)[0]
    np.testing.assert_allclose(ours.numpy(), ref, atol=1e-6)


def test_fov_scale_divides_the_focal():
    a = fisheye_new_camera_matrix(torch.tensor(K)[None], torch.tensor(D)[None], (640, 480), 0.0)
    b = fisheye_new_camera_matrix(torch.tensor(K)[None], torch.tensor(D)[None], (640, 480), 0.0, fov_scale=2.0)
    assert torch.allclose(b[0, 0, 0] * 2, a[0, 0, 0])


def test_undistort_image_matches_opencv(device):
    g = np.random.default_rng(0)
    img = cv2.GaussianBlur(g.random((480, 640)), (0, 0), 3.0)  # smooth: interpolation differences stay small
    P = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (640, 480), np.eye(3), balance=0.5)
    ref = cv2.fisheye.undistortImage(img, K, D, Knew=P)
    t = lambda a: torch.tensor(a, device=device)[None]  # noqa: E731
    out = fisheye_undistort_image(t(img)[None], t(K), t(D), t(P))[0, 0].cpu().numpy()
    inner = (slice(20, -20), slice(20, -20))
    assert np.abs(out[inner] - ref[inner]).max() < 2e-3


def test_batch_is_per_image():
    imgs = torch.rand(2, 1, 48, 64, dtype=torch.float64)
    Ks = torch.tensor(K)[None].repeat(2, 1, 1) * torch.tensor([0.1, 0.1, 1.0], dtype=torch.float64)[None, :, None]
    Ds = torch.tensor(D)[None].repeat(2, 1)
    Ds[1] = 0.0
    both = fisheye_undistort_image(imgs, Ks, Ds)
    one = fisheye_undistort_image(imgs[1:], Ks[1:], Ds[1:])
    assert torch.equal(both[1:], one)


def test_shape_errors():
    with pytest.raises(ValueError, match="K must be"):
        fisheye_undistort_image(torch.rand(1, 1, 8, 8), torch.eye(3), torch.zeros(1, 4))
    with pytest.raises(ValueError, match="D must be"):
        fisheye_new_camera_matrix(torch.eye(3)[None], torch.zeros(1, 5), (8, 8))
    with pytest.raises(ValueError, match="balance"):
        fisheye_new_camera_matrix(torch.eye(3)[None], torch.zeros(1, 4), (8, 8), balance=2.0)


# ----------------------------------------------------------------------------------------------
# the view framed within the lens's valid field
# ----------------------------------------------------------------------------------------------

WIDE_K = torch.tensor([[[200.0, 0, 322.0], [0, 201.0, 236.0], [0, 0, 1]]], dtype=torch.float64)
WIDE_D = torch.tensor([[-0.02, -0.005, 0.001, 0.0]], dtype=torch.float64)  # monotonic; 640x480 sees ~100 degrees


def _source_map(K_, D_, P, size):
    """Where each pixel of the view comes from, and its ray's angle from the axis."""
    w, h = size
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    x, y = (u - P[0, 0, 2]) / P[0, 0, 0], (v - P[0, 1, 2]) / P[0, 1, 1]
    src = kb_project_points(torch.stack([x, y, torch.ones_like(x)], -1).reshape(1, -1, 3), K_, D_)[0]
    return src.reshape(h, w, 2), torch.atan(torch.hypot(x, y))


def test_valid_angle_stops_at_a_known_fold_over():
    # theta_d = theta (1 + k1 theta^2 + k2 theta^4): slope 1 + 3 k1 t^2 + 5 k2 t^4 = 0 at t^2 = 1 / 0.6 for
    # k1 = -0.5, k2 = 1 / 60: the root 1 / sqrt(0.6) rad = 73.97 degrees
    D_ = torch.tensor([[-0.5, 1.0 / 60.0, 0.0, 0.0]], dtype=torch.float64)
    t = torch.linspace(0.0, 1.4, 2001, dtype=torch.float64)
    slope = 1 + 3 * D_[0, 0] * t**2 + 5 * D_[0, 1] * t**4
    fold = t[(slope <= 0).nonzero()[0, 0]]
    angle = fisheye_valid_angle(WIDE_K, D_)
    assert abs(float(angle[0]) - float(fold)) < math.radians(0.05)
    assert float(angle[0]) < float(fold)  # conservative: the last angle before the fold


def test_valid_angle_without_fold_is_the_cap_and_corners_bound_it():
    assert abs(math.degrees(float(fisheye_valid_angle(WIDE_K, WIDE_D)[0])) - MAX_VIEW_ANGLE_DEG) < 1e-9
    # corners seen up to 50 degrees from the axis (one hidden corner: NaN)
    phi = torch.linspace(0, 2 * math.pi, 9, dtype=torch.float64)[:-1]
    theta = torch.full_like(phi, math.radians(50.0))
    theta[::2] = math.radians(20.0)
    rays = torch.stack([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], -1)
    pts = kb_project_points(rays, WIDE_K[0], WIDE_D[0])
    pts = torch.cat([pts, torch.full((1, 2), float("nan"), dtype=torch.float64)])[None]
    assert abs(math.degrees(float(fisheye_valid_angle(WIDE_K, WIDE_D, pts)[0])) - 50.0) < 1e-6


@pytest.mark.parametrize("balance", [0.0, 0.5])
def test_view_without_black_pixels_at_low_balance(balance):
    size = (640, 480)
    angle = torch.tensor([math.radians(70.0)], dtype=torch.float64)
    P = fisheye_view_camera_matrix(WIDE_K, WIDE_D, size, balance, max_angle=angle)
    src, theta = _source_map(WIDE_K, WIDE_D, P, size)
    inside = (src[..., 0] >= 0) & (src[..., 0] <= 639) & (src[..., 1] >= 0) & (src[..., 1] <= 479)
    inside &= theta <= angle[0] + 1e-9
    if balance == 0.0:  # every pixel in the image and in the valid field
        assert bool(inside.all())
    else:
        assert 0.0 < 1 - inside.double().mean() < 0.3
    # centred on the axis, no shear, the aspect of K kept
    assert (P[0, 0, 2], P[0, 1, 2], P[0, 0, 1]) == (319.5, 239.5, 0.0)
    torch.testing.assert_close(P[0, 1, 1] / P[0, 0, 0], WIDE_K[0, 1, 1] / WIDE_K[0, 0, 0])


def test_balance_one_shows_the_whole_valid_field():
    size = (640, 480)
    angle = torch.tensor([math.radians(60.0)], dtype=torch.float64)
    P0 = fisheye_view_camera_matrix(WIDE_K, WIDE_D, size, 0.0, max_angle=angle)
    P1 = fisheye_view_camera_matrix(WIDE_K, WIDE_D, size, 1.0, max_angle=angle)
    assert P1[0, 0, 0] < P0[0, 0, 0]  # more field
    # every ray of the valid field that lands in the image lands in the view too
    phi = torch.linspace(0, 2 * math.pi, 721, dtype=torch.float64)
    theta = torch.linspace(0, float(angle[0]), 61, dtype=torch.float64)
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    rays = torch.stack([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()], -1).reshape(1, -1, 3)
    src = kb_project_points(rays, WIDE_K, WIDE_D)[0]
    seen = (src[:, 0] >= 0) & (src[:, 0] <= 639) & (src[:, 1] >= 0) & (src[:, 1] <= 479)
    view = rays[0, seen, :2] / rays[0, seen, 2:] * P1[0, [0, 1], [0, 1]] + P1[0, :2, 2]
    assert bool(((view >= -1e-3) & (view <= torch.tensor([639.001, 479.001], dtype=torch.float64))).all())
    # while the view at balance 0 cuts some of it off
    view0 = rays[0, seen, :2] / rays[0, seen, 2:] * P0[0, [0, 1], [0, 1]] + P0[0, :2, 2]
    assert not bool(((view0 >= 0) & (view0 <= torch.tensor([639.0, 479.0], dtype=torch.float64))).all())


def test_fov_clamps_to_the_valid_field():
    size = (640, 480)
    angle = torch.tensor([math.radians(60.0)], dtype=torch.float64)
    P = fisheye_view_camera_matrix(WIDE_K, WIDE_D, size, fov=90.0, max_angle=angle)
    assert abs(float(horizontal_fov(P, size)[0]) - 90.0) < 1e-9
    P = fisheye_view_camera_matrix(WIDE_K, WIDE_D, size, fov=170.0, max_angle=angle)
    assert abs(float(horizontal_fov(P, size)[0]) - 120.0) < 0.1  # the 60-degree disc, both sides


def test_undistort_image_blanks_rays_beyond_the_valid_field():
    size = (160, 120)
    K_ = WIDE_K.clone()
    K_[0, :2] /= 4.0  # the same lens on a quarter-size image
    angle = torch.tensor([math.radians(40.0)], dtype=torch.float64)
    P = fisheye_view_camera_matrix(K_, WIDE_D, size, 1.0, max_angle=angle)
    out = fisheye_undistort_image(torch.ones(1, 1, 120, 160, dtype=torch.float64), K_, WIDE_D, P, max_angle=angle)
    src, theta = _source_map(K_, WIDE_D, P, size)
    in_image = (src[..., 0] >= 1) & (src[..., 0] <= 158) & (src[..., 1] >= 1) & (src[..., 1] <= 118)
    assert bool((out[0, 0][theta > angle[0] + 1e-3] == 0).all())
    kept = out[0, 0][(theta < angle[0] - 1e-3) & in_image]
    assert kept.numel() > 1000 and bool(((kept - 1).abs() < 1e-9).all())


def test_view_camera_matrix_on_every_device(device):
    size = (640, 480)
    on = [fisheye_view_camera_matrix(WIDE_K.to(device), WIDE_D.to(device), size, b) for b in (0.0, 1.0)]
    off = [fisheye_view_camera_matrix(WIDE_K, WIDE_D, size, b) for b in (0.0, 1.0)]
    for a, b in zip(on, off):
        assert a.device.type == device.type
        torch.testing.assert_close(a.cpu(), b)
    small = WIDE_K.clone()
    small[0, :2] /= 10.0  # the same lens on a 64x48 image
    angle = fisheye_valid_angle(small.to(device), WIDE_D.to(device))
    out = fisheye_undistort_image(torch.ones(1, 1, 48, 64, device=device), small.to(device), WIDE_D.to(device),
                                  max_angle=angle)
    assert out.shape == (1, 1, 48, 64) and out.device.type == device.type
