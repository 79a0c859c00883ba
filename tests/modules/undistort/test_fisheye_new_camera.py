"""fisheye_new_camera: cv2.fisheye.estimateNewCameraMatrixForUndistortRectify for a fisheye camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, OPENCV5
from ccs_kornia.modules.undistort.fisheye_new_camera import fisheye_new_camera_matrix

K = np.array([[400.0, 0, 330.0], [0, 402.0, 236.0], [0, 0, 1.0]])
D = np.array([0.05, -0.01, 0.002, 0.0])
CAMERA = Camera.from_opencv(FISHEYE, torch.tensor(K), torch.tensor(D), (640, 480))


@pytest.mark.parametrize("balance", [0.0, 0.5, 1.0])
def test_matches_opencv(balance):
    ref = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, (640, 480), np.eye(3), balance=balance)
    ours = fisheye_new_camera_matrix(CAMERA, (640, 480), balance)[0]
    np.testing.assert_allclose(ours.numpy(), ref, atol=1e-6)


def test_fov_scale_divides_the_focal_and_cameras_are_batched(device):
    a = fisheye_new_camera_matrix(CAMERA.to(device), (640, 480), 0.0)
    b = fisheye_new_camera_matrix(CAMERA.to(device), (640, 480), 0.0, fov_scale=2.0)
    assert a.device.type == device.type and a.dtype == torch.float64
    torch.testing.assert_close(b[0, 0, 0] * 2, a[0, 0, 0])
    two = Camera.cat([CAMERA, Camera.from_opencv(FISHEYE, torch.tensor(K) / 2, None, (320, 240))])
    both = fisheye_new_camera_matrix(two, (640, 480), 0.5)
    torch.testing.assert_close(both[:1], fisheye_new_camera_matrix(CAMERA, (640, 480), 0.5))


def test_errors():
    with pytest.raises(ValueError, match="fisheye cameras"):
        fisheye_new_camera_matrix(Camera.from_opencv(OPENCV5, torch.tensor(K)), (640, 480))
    with pytest.raises(ValueError, match="balance"):
        fisheye_new_camera_matrix(CAMERA, (640, 480), balance=2.0)
    with pytest.raises(ValueError, match="fov_scale"):
        fisheye_new_camera_matrix(CAMERA, (640, 480), fov_scale=0.0)
    with pytest.raises(TypeError, match="Camera"):
        fisheye_new_camera_matrix(torch.tensor(K)[None], (640, 480))
