"""Tests of the OpenCV-model undistortion of images and its point maps."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from ccs_kornia.data.scenes import make_calibration_set
from ccs_kornia.modules.correction.opencv_warp import (
    opencv_distorted_frame,
    opencv_undistort_image,
    opencv_undistorted_frame,
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
