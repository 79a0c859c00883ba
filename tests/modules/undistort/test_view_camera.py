"""view_camera: the undistorted view's camera from the valid visible region of the normalised plane."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.modules.undistort.view_camera import (
    horizontal_fov,
    valid_region_radii,
    view_camera_matrix,
)

SIZE = (100, 80)
K = torch.tensor([[[100.0, 0, 49.5], [0, 120, 39.5], [0, 0, 1]]], dtype=torch.float64)


def pinhole(plane: torch.Tensor) -> torch.Tensor:
    """No distortion: the normalised plane through K."""
    return plane * K[:, None, [0, 1], [0, 1]] + K[:, None, :2, 2]


def test_region_radii_of_a_pinhole_are_the_image_borders(device):
    dirs = torch.tensor([[[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.6, 0.8]]], dtype=torch.float64, device=device)
    Kd = K.to(device)
    radii = valid_region_radii(lambda p: p * Kd[:, None, [0, 1], [0, 1]] + Kd[:, None, :2, 2],
                               torch.tensor([10.0], dtype=torch.float64, device=device), SIZE, dirs)
    expected = torch.tensor([[49.5 / 100, 49.5 / 100, 39.5 / 120, min(49.5 / 100 / 0.6, 39.5 / 120 / 0.8)]],
                            dtype=torch.float64, device=device)
    torch.testing.assert_close(radii, expected, atol=1e-6, rtol=0)


def test_region_radii_stop_at_the_valid_radius():
    dirs = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]], dtype=torch.float64)
    radii = valid_region_radii(pinhole, torch.tensor([0.2], dtype=torch.float64), SIZE, dirs)
    torch.testing.assert_close(radii, torch.full((1, 2), 0.2, dtype=torch.float64))


def test_pinhole_without_distortion_gets_its_own_camera_back():
    P = view_camera_matrix(pinhole, K, torch.tensor([10.0], dtype=torch.float64), SIZE, 0.0)
    torch.testing.assert_close(P, K, atol=1e-4, rtol=0)
    # the whole image is the region: balance 1 is the same view
    P1 = view_camera_matrix(pinhole, K, torch.tensor([10.0], dtype=torch.float64), SIZE, 1.0)
    torch.testing.assert_close(P1, K, atol=1e-4, rtol=0)


def test_balance_is_linear_in_the_focal_length_and_keeps_aspect_and_centre():
    radius = torch.tensor([0.3], dtype=torch.float64)  # a disc inside the image: corners of the view black at 1
    f = [view_camera_matrix(pinhole, K, radius, SIZE, b) for b in (0.0, 0.5, 1.0)]
    assert f[1][0, 0, 0] < f[0][0, 0, 0]
    torch.testing.assert_close(f[1][0, 0, 0], (f[0][0, 0, 0] + f[2][0, 0, 0]) / 2)
    for P in f:
        assert P[0, 0, 2] == 49.5 and P[0, 1, 2] == 39.5 and P[0, 0, 1] == 0
        torch.testing.assert_close(P[0, 1, 1] / P[0, 0, 0], K[0, 1, 1] / K[0, 0, 0])
    # balance 0: the view's corner on the disc; balance 1: the disc's top and bottom on the view's border
    corner = torch.tensor([49.5 / f[0][0, 0, 0], 39.5 / f[0][0, 1, 1]]).norm()
    assert abs(corner - 0.3) < 1e-5
    assert abs(39.5 / f[2][0, 1, 1] - 0.3) < 1e-3


def test_fov_is_explicit_and_clamped():
    radius = torch.tensor([math.tan(math.radians(40))], dtype=torch.float64)
    P = view_camera_matrix(pinhole, K, radius, (4000, 3000), fov=50.0)  # inside the 80-degree disc and the image
    assert abs(float(horizontal_fov(P, (4000, 3000))[0]) - 50.0) < 1e-6
    P = view_camera_matrix(pinhole, K, radius, (4000, 3000), fov=120.0)
    assert abs(float(horizontal_fov(P, (4000, 3000))[0]) - 80.0) < 0.1  # clamped to the disc's width


def test_batch_is_per_camera():
    Ks = torch.cat([K, K.clone()])
    Ks[1, :2, :2] *= 2.0
    radii = torch.tensor([0.3, 10.0], dtype=torch.float64)

    def two(plane):
        return plane * Ks[:, None, [0, 1], [0, 1]] + Ks[:, None, :2, 2]

    both = view_camera_matrix(two, Ks, radii, SIZE, 0.5)
    one = view_camera_matrix(pinhole, K, radii[:1], SIZE, 0.5)
    torch.testing.assert_close(both[:1], one)


def test_errors():
    r = torch.tensor([1.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="K must be"):
        view_camera_matrix(pinhole, K[0], r, SIZE)
    with pytest.raises(ValueError, match="max_radius"):
        view_camera_matrix(pinhole, K, torch.ones(2, dtype=torch.float64), SIZE)
    with pytest.raises(ValueError, match="balance"):
        view_camera_matrix(pinhole, K, r, SIZE, balance=1.5)
    with pytest.raises(ValueError, match="fov"):
        view_camera_matrix(pinhole, K, r, SIZE, fov=180.0)
    with pytest.raises(ValueError, match="directions"):
        valid_region_radii(pinhole, r, SIZE, torch.ones(1, 2))
    outside = K.clone()
    outside[0, 0, 2] = -50.0  # principal point left of the image
    with pytest.raises(ValueError, match="no part of the image"):
        view_camera_matrix(lambda p: p * 100 + outside[:, None, :2, 2], outside, r, SIZE)
