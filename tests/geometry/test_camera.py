from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import (
    Camera,
    intrinsics_matrix,
    intrinsics_params,
    project_points,
)
from ccs_kornia.geometry.models import K1K2, OPENCV5, PINHOLE
from ccs_kornia.geometry.radial import (
    fit_radial_correction,
    radial_correct_points,
    radial_distort_points,
    radial_undistort_points,
)

F64 = torch.float64


def _camera():
    K = intrinsics_matrix(torch.tensor([520.0, 530.0, 330.0, 235.0], dtype=F64))
    r = torch.tensor([0.2, -0.3, 0.1], dtype=F64)
    t = torch.tensor([-0.1, -0.05, 0.5], dtype=F64)
    return K, r, t


def test_board_object_points_order():
    obj = board_object_points(9, 6, 0.025)
    assert obj.shape == (54, 3)
    # n = j*cols + i -> (i*s, j*s, 0)
    assert torch.allclose(obj[1], torch.tensor([0.025, 0.0, 0.0]))
    assert torch.allclose(obj[9], torch.tensor([0.0, 0.025, 0.0]))
    assert torch.allclose(obj[-1], torch.tensor([8 * 0.025, 5 * 0.025, 0.0]))
    with pytest.raises(ValueError):
        board_object_points(1, 5)


def test_intrinsics_roundtrip_and_shape_checks():
    p = torch.rand(4, 4, dtype=F64) * 100 + 1
    assert torch.allclose(intrinsics_params(intrinsics_matrix(p)), p)
    with pytest.raises(ValueError):
        intrinsics_matrix(torch.rand(3))
    with pytest.raises(ValueError):
        intrinsics_params(torch.rand(2, 2))


@pytest.mark.parametrize("ncoef", [0, 4, 5, 8])
def test_project_points_matches_opencv(ncoef):
    K, r, t = _camera()
    dist = torch.tensor([-0.3, 0.12, 0.001, -0.002, -0.03, 0.1, 0.02, 0.01], dtype=F64)[:ncoef]
    obj = board_object_points(9, 6, 0.025, dtype=F64)
    p = project_points(obj, K, dist if ncoef else None, r, t)
    ref, _ = cv2.projectPoints(obj.numpy(), r.numpy(), t.numpy(), K.numpy(), dist.numpy() if ncoef else None)
    np.testing.assert_allclose(p.numpy(), ref.reshape(-1, 2), atol=1e-9)


def test_project_points_batched_matches_single():
    K, r, t = _camera()
    obj = board_object_points(4, 3, 0.1, dtype=F64)
    rb = torch.stack([r, r * 0.5, -r])
    tb = torch.stack([t, t + 0.1, t - 0.02])
    dist = torch.tensor([-0.2, 0.05, 0.0, 0.0, 0.0], dtype=F64)
    pb = project_points(obj.expand(3, -1, -1), K.expand(3, 3, 3), dist.expand(3, 5), rb, tb)
    for b in range(3):
        assert torch.allclose(pb[b], project_points(obj, K, dist, rb[b], tb[b]))
    with pytest.raises(ValueError):
        project_points(torch.rand(5, 2), K)


def test_undistort_and_fit_opencv_distortion():
    K, r, t = _camera()
    dist = torch.tensor([-0.3, 0.12, 0.001, -0.002, -0.03], dtype=F64)
    obj = board_object_points(9, 6, 0.025, dtype=F64)
    ideal = project_points(obj, K, None, r, t)[None]
    distorted = project_points(obj, K, dist, r, t)[None]
    camera = Camera.from_opencv(OPENCV5, K, dist)
    assert (camera.undistort(distorted, K[None]) - ideal).abs().max() < 1e-8
    fitted = OPENCV5.fit_coeffs(ideal, distorted, K[None])
    assert torch.allclose(fitted[0], dist, atol=1e-9)
    fitted2 = K1K2.fit_coeffs(ideal, distorted, K[None])
    assert fitted2.shape == (1, 5) and torch.all(fitted2[0, 2:] == 0)
    assert PINHOLE.fit_coeffs(ideal, distorted, K[None]).shape == (1, 0)


def test_radial_model_roundtrip_and_correction():
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(2, 200, 2, generator=g, dtype=F64) * torch.tensor([640.0, 480.0], dtype=F64)
    coeffs = torch.tensor([[1.0, -0.3, -0.05], [1.1, -0.45, -0.2]], dtype=F64)
    d = radial_distort_points(pts, coeffs, (640, 480))
    assert (radial_undistort_points(d, coeffs, (640, 480)) - pts).abs().max() < 1e-9
    # identity model and image centre fixed point
    c = torch.tensor([[319.5, 239.5]], dtype=F64)[None]
    assert torch.allclose(radial_distort_points(c, coeffs[:1], (640, 480)), c)
    corr = fit_radial_correction(coeffs, (640, 480))
    assert corr.shape == (2, 5)
    err = (radial_correct_points(d, corr, (640, 480)) - pts).norm(dim=-1)
    # the 5-term correction inverts level-1 distortion to a small fraction of a pixel
    assert err[0].max() < 0.2
    assert err[1].max() < 2.0
    with pytest.raises(ValueError):
        radial_distort_points(pts, coeffs[:, :2], (640, 480))
    with pytest.raises(ValueError):
        radial_correct_points(pts, coeffs, (640, 480))


def test_undistort_pixels_strong_barrel():
    # fx=300 at 640x480 with k1=-0.37: kornia's fixed point alone oscillates near the corners (#4285)
    K = intrinsics_matrix(torch.tensor([300.0, 300.0, 320.0, 240.0], dtype=F64))[None]
    dist = torch.tensor([[-0.37, 0.08, 0.0, 0.0, 0.0]], dtype=F64)
    ideal = torch.stack(torch.meshgrid(torch.linspace(20, 620, 13, dtype=F64), torch.linspace(20, 460, 9, dtype=F64), indexing="xy"), -1).reshape(1, -1, 2)
    camera = Camera.from_opencv(K1K2, K, dist)
    distorted = camera.distort((ideal - K[:, :2, 2]) / K[:, [0, 1], [0, 1]])
    back = camera.undistort(distorted, K)
    assert (back - ideal).abs().max() < 1e-6
