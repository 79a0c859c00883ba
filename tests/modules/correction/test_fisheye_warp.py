"""fisheye_warp: cv2.fisheye's new camera matrix and undistortImage, batched, on any device."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.modules.correction.fisheye_warp import fisheye_new_camera_matrix, fisheye_undistort_image

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
