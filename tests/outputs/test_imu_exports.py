"""Kalibr's YAML files out (``outputs/imu_exports.py``): written, then read back by ``io/kalibr.py`` with the same
numbers; the camchain's camera lines shared with the rig's camchain."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import yaml

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, RATIONAL
from ccs_kornia.io.imu import ImuNoise
from ccs_kornia.io.kalibr import read_camchain, read_imu_yaml
from ccs_kornia.outputs.imu_exports import camchain_imucam_yaml, imu_yaml
from ccs_kornia.outputs.rig_exports import yaml_float


def _pose(axis, angle: float, t) -> np.ndarray:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    T[:3, 3] = t
    return T


def _cameras() -> Camera:
    K = torch.tensor([[[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]],
                      [[380.81, 0, 510.29], [0, 380.55, 514.35], [0, 0, 1]]], dtype=torch.float64)
    radtan = Camera.from_opencv(OPENCV5, K[0], torch.tensor([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
                                                            dtype=torch.float64), (752, 480))
    fisheye = Camera.from_opencv(FISHEYE, K[1], torch.tensor([0.0101, 0.0499, -0.05, 0.0150], dtype=torch.float64),
                                 (1024, 1024))
    return Camera.cat([radtan, fisheye])


def test_camchain_imucam_round_trip(tmp_path):
    cameras = _cameras()
    T = np.stack([_pose([0.1, 0.2, 1.0], 1.55, [-0.0216, -0.0647, 0.0098]),
                  _pose([0.3, -0.1, 1.0], 1.60, [0.0884, -0.0640, 0.0099])])
    text = camchain_imucam_yaml(cameras, torch.from_numpy(T), [5.63e-04, -1e-05], names=["left", "right"])
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(text)
    cam0, cam1 = read_camchain(str(path))
    for read, c in ((cam0, 0), (cam1, 1)):
        assert read.camera.models == (cameras.models[c],) and read.camera.image_sizes[0] == cameras.image_sizes[c]
        assert np.allclose(read.camera.params.numpy(), cameras[c].params.numpy(), rtol=1e-11, atol=0)
        assert np.allclose(read.T_cam_imu.numpy(), T[c], rtol=0, atol=1e-11)
    assert cam0.timeshift_cam_imu == 5.63e-04 and cam1.timeshift_cam_imu == -1e-05
    # T_cn_cnm1 is the chain of the two (x_1 = T x_0), and the layout is Kalibr's
    assert np.allclose(cam1.T_cn_cnm1.numpy(), T[1] @ np.linalg.inv(T[0]), rtol=0, atol=1e-11)
    assert cam0.T_cn_cnm1 is None
    chain = yaml.safe_load(text)
    assert list(chain) == ["cam0", "cam1"]
    assert list(chain["cam1"]) == ["camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution",
                                   "rostopic", "cam_overlaps", "T_cn_cnm1", "T_cam_imu", "timeshift_cam_imu"]
    assert chain["cam0"]["rostopic"] == "/left/image_raw" and chain["cam1"]["cam_overlaps"] == [0]
    assert chain["cam1"]["distortion_model"] == "equidistant" and chain["cam0"]["distortion_model"] == "radtan"
    assert all(isinstance(v, float) for row in chain["cam0"]["T_cam_imu"] for v in row)


def test_camchain_given_chain_and_a_single_matrix():
    cameras = _cameras()
    T = np.stack([_pose([0, 0, 1], 0.1, [0.0, 0.0, 0.0]), _pose([0, 1, 0], 0.2, [0.1, 0.0, 0.0])])
    given = _pose([1, 0, 0], 0.05, [-0.11, 0.0, 0.0])
    chain = yaml.safe_load(camchain_imucam_yaml(cameras, T, [0.0, 0.0], T_cn_cnm1=given[None]))
    assert np.allclose(chain["cam1"]["T_cn_cnm1"], given, atol=1e-12)
    one = yaml.safe_load(camchain_imucam_yaml(cameras[0], T[0], [0.002]))
    assert list(one) == ["cam0"] and one["cam0"]["cam_overlaps"] == [] and "T_cn_cnm1" not in one["cam0"]
    with pytest.raises(ValueError, match=r"T_cam_imu must be \(2, 4, 4\)"):
        camchain_imucam_yaml(cameras, T[0], [0.0, 0.0])
    with pytest.raises(ValueError, match="timeshift_cam_imu must hold 2 values"):
        camchain_imucam_yaml(cameras, T, [0.0])


def test_camchain_says_what_kalibr_cannot_hold():
    K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
    opencv5 = Camera.from_opencv(OPENCV5, K, torch.tensor([-0.2, 0.05, 0.0, 0.0, 0.01], dtype=torch.float64), (640, 480))
    text = camchain_imucam_yaml(opencv5, np.eye(4), [0.0])
    assert text.startswith("# camera cam0: Kalibr's radtan has no k3; k3 = 0.01 left out of the camchain\n")
    assert yaml.safe_load(text)["cam0"]["distortion_coeffs"] == [-0.2, 0.05, 0.0, 0.0]
    k1k2 = Camera.from_opencv(K1K2, K, torch.tensor([-0.2, 0.05], dtype=torch.float64), (640, 480))
    assert yaml.safe_load(camchain_imucam_yaml(k1k2, np.eye(4), [0.0]))["cam0"]["distortion_model"] == "radtan"
    rational = Camera.from_opencv(RATIONAL, K, torch.zeros(8, dtype=torch.float64), (640, 480))
    with pytest.raises(ValueError, match="Kalibr has no rational model"):
        camchain_imucam_yaml(rational, np.eye(4), [0.0])


def test_imu_yaml_round_trip(tmp_path):
    noise = ImuNoise(2.0e-3, 3.1e-5, 1.6968e-04, 1e-05, 400.0)
    text = imu_yaml(noise, rostopic="/vi/imu")
    path = tmp_path / "imu.yaml"
    path.write_text(text)
    assert read_imu_yaml(str(path)) == noise
    data = yaml.safe_load(text)  # as Kalibr reads it: every value a float, the topic given
    assert data["rostopic"] == "/vi/imu" and all(isinstance(data[k], float) for k in data if k != "rostopic")


def test_yaml_floats_read_as_floats():
    for value in (1e-05, 200.0, 0.0, -3.0, 0.1234567890123, 2.5e-12, 1e20):
        text = yaml_float(value)
        assert isinstance(yaml.safe_load(text), float) and float(text) == pytest.approx(value, rel=1e-11)
