"""Tests of the OpenCV-model undistortion of images, the view's camera and the point maps."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.modules.undistort.opencv_warp import (
    opencv_distorted_frame,
    opencv_undistort_image,
    opencv_undistorted_frame,
    opencv_valid_radius,
    opencv_view_camera_matrix,
)

SIZE = (640, 480)


def test_opencv_undistort_image_matches_cv2():
    K = torch.tensor([[[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    dist = torch.tensor([[-0.3, 0.1, 0.001, -0.0005, 0.0]], dtype=torch.float64)
    s = make_calibration_set(K[0].float(), (9, 6), 0.025, SIZE, num_views=1, supersample=1, seed=3)
    img = s.images[0, 0].numpy()
    ours = opencv_undistort_image(s.images, K, dist)[0, 0].numpy()
    ref = cv2.undistort(img.astype(np.float32), K[0].numpy(), dist[0].numpy())
    inner = (slice(40, 440), slice(40, 600))
    assert np.abs(ours[inner] - ref[inner]).mean() < 2e-3


def test_opencv_frame_maps_round_trip_and_zoom():
    K = torch.tensor([[[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    dist = torch.tensor([[-0.3, 0.1, 0.001, -0.0005, 0.0]], dtype=torch.float64)
    p = torch.tensor([[[100.0, 80.0], [320.0, 240.0], [600.0, 400.0]]], dtype=torch.float64)
    for zoom in (1.0, 0.7):
        u = opencv_undistorted_frame(p, K, dist, zoom)
        torch.testing.assert_close(opencv_distorted_frame(u, K, dist, zoom), p, atol=1e-6, rtol=0)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    ref = cv2.undistortPoints(p[0].numpy().reshape(-1, 1, 2), K[0].numpy(), dist[0].numpy(), R=None, P=K[0].numpy(),
                              criteria=criteria)
    np.testing.assert_allclose(opencv_undistorted_frame(p, K, dist)[0].numpy(), ref.reshape(-1, 2), atol=1e-4)


# ----------------------------------------------------------------------------------------------
# the view framed within the lens's valid field
# ----------------------------------------------------------------------------------------------

K_VIEW = torch.tensor([[[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)


@pytest.mark.parametrize("balance", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("dist", [[-0.3, 0.1, 0.001, -0.0005, 0.0], [0.1, -0.02, 0.0, 0.0, 0.0]], ids=["barrel", "pincushion"])
def test_view_camera_matrix_matches_opencv_optimal_matrix(balance, dist):
    # a lens monotonic over the image: OpenCV's alpha with the principal point centred is the same framing
    d = torch.tensor([dist], dtype=torch.float64)
    ref, _ = cv2.getOptimalNewCameraMatrix(K_VIEW[0].numpy(), d[0].numpy(), SIZE, balance, centerPrincipalPoint=True)
    ours = opencv_view_camera_matrix(K_VIEW, d, SIZE, balance)[0].numpy()
    np.testing.assert_allclose(ours[[0, 1], [0, 1]], ref[[0, 1], [0, 1]], rtol=3e-3)  # cv2 samples a 9x9 grid
    np.testing.assert_allclose(ours[:2, 2], [319.5, 239.5])


def test_folding_lens_is_framed_before_the_fold():
    # r_d = r (1 - 0.5 r^2) folds at r = 1 / sqrt(1.5), 0.816, whose image radius 0.544 f = 228 px is inside the image
    d = torch.tensor([[-0.5, 0.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    radius = opencv_valid_radius(K_VIEW, d)
    assert abs(float(radius[0]) - 1 / math.sqrt(1.5)) < 2e-3 and float(radius[0]) <= 1 / math.sqrt(1.5)
    for balance in (0.0, 1.0):
        P = opencv_view_camera_matrix(K_VIEW, d, SIZE, balance)
        # no pixel of the view sees past the fold at balance 0; at 1 the view's borders reach the fold, not beyond
        corner = torch.tensor([319.5 / P[0, 0, 0], 239.5 / P[0, 1, 1]]).norm()
        edge = min(319.5 / P[0, 0, 0], 239.5 / P[0, 1, 1])
        assert (corner <= radius[0] + 1e-6) if balance == 0.0 else (abs(edge - radius[0]) < 1e-3)
    img = torch.ones(1, 1, SIZE[1], SIZE[0], dtype=torch.float64)
    out = opencv_undistort_image(img, K_VIEW, d, new_K=P, max_radius=radius)[0, 0]
    v, u = torch.meshgrid(torch.arange(SIZE[1], dtype=torch.float64), torch.arange(SIZE[0], dtype=torch.float64),
                          indexing="ij")
    r = torch.hypot((u - P[0, 0, 2]) / P[0, 0, 0], (v - P[0, 1, 2]) / P[0, 1, 1])
    assert bool((out[r > radius[0] + 1e-3] == 0).all())  # nothing folded back into the corners
    assert bool(((out[r < radius[0] - 1e-2] - 1).abs() < 1e-9).all())


def test_valid_radius_is_bounded_by_the_corners_seen():
    d = torch.tensor([[-0.3, 0.1, 0.001, -0.0005, 0.0]], dtype=torch.float64)
    plane = torch.tensor([[[0.3, 0.0], [0.0, -0.45], [float("nan"), float("nan")]]], dtype=torch.float64)
    pix = opencv_distorted_frame(plane * K_VIEW[:, None, [0, 1], [0, 1]] + K_VIEW[:, None, :2, 2], K_VIEW, d)
    assert abs(float(opencv_valid_radius(K_VIEW, d, pix)[0]) - 0.45) < 1e-6
    with pytest.raises(ValueError, match="points"):
        opencv_valid_radius(K_VIEW, d, pix[0])
    with pytest.raises(ValueError, match="dist"):
        opencv_valid_radius(K_VIEW, d[:, :3])


def test_undistort_image_with_new_camera_matches_cv2():
    dist = torch.tensor([[-0.3, 0.1, 0.001, -0.0005, 0.0]], dtype=torch.float64)
    s = make_calibration_set(K_VIEW[0].float(), (9, 6), 0.025, SIZE, num_views=1, supersample=1, seed=3)
    for balance in (0.0, 1.0):
        P = opencv_view_camera_matrix(K_VIEW, dist, SIZE, balance)
        ours = opencv_undistort_image(s.images.double(), K_VIEW, dist, new_K=P)[0, 0].numpy()
        ref = cv2.undistort(s.images[0, 0].numpy().astype(np.float32), K_VIEW[0].numpy(), dist[0].numpy(),
                            newCameraMatrix=P[0].numpy())
        inner = (slice(40, 440), slice(40, 600))
        assert np.abs(ours[inner] - ref[inner]).mean() < 2e-3
    # balance 1 shows more of the scene than 0: black corners
    assert (ours == 0).mean() > 0.01
    zero = opencv_undistort_image(s.images.double(), K_VIEW, dist, new_K=opencv_view_camera_matrix(K_VIEW, dist, SIZE))
    assert float((zero == 0).double().mean()) == 0.0
