"""Kalibr's YAML files in (``io/kalibr.py``): imu.yaml, camchain.yaml and camchain-imucam.yaml as Kalibr writes them,
and the refusals."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ccs_kornia.geometry.models import FISHEYE, OPENCV5, PINHOLE
from ccs_kornia.io.imu import ImuNoise
from ccs_kornia.io.kalibr import read_camchain, read_imu_yaml
from ccs_kornia.runtime.errors import UserError

#: Kalibr's example imu.yaml (its wiki's, for the ADIS16448), comments and alignment as given
KALIBR_IMU = """#Accelerometers
accelerometer_noise_density: 1.86e-03   #Noise density (continuous-time)
accelerometer_random_walk:   4.33e-04   #Bias random walk

#Gyroscopes
gyroscope_noise_density:     1.87e-04   #Noise density (continuous-time)
gyroscope_random_walk:       2.66e-05   #Bias random walk

rostopic:                    /imu0      #the IMU ROS topic
update_rate:                 200.0      #Hz (for discretization of the values above)
"""

#: a camchain-imucam.yaml in Kalibr's layout (keys sorted as its yaml dump writes them, a comment line), EuRoC's two
#: cameras (cam1's T_cam_imu is T_cn_cnm1 times cam0's, to 12 digits)
KALIBR_CAMCHAIN_IMUCAM = """# results of kalibr_calibrate_imu_camera
cam0:
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
  timeshift_cam_imu: 5.63e-04
cam1:
  T_cam_imu:
  - [0.0171668543284, -0.999842168941, 0.00457562200141, -0.13185974288]
  - [0.999057739589, 0.0173354712985, 0.0397883701634, -0.0640828965674]
  - [-0.0398614109323, 0.00388826941893, 0.99919765276, 0.00987482657331]
  - [0.0, 0.0, 0.0, 1.0]
  T_cn_cnm1:
  - [0.999997256477, 0.00231206719764, 0.000376008102261, -0.110073808127]
  - [-0.00231713572814, 0.999898048506, 0.0140898358801, 0.000399121547014]
  - [-0.000343393120525, -0.0140906685317, 0.999900662638, -0.000853702503356]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]
  distortion_model: radtan
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
  timeshift_cam_imu: -0.0001
"""


def _file(tmp_path, text: str, name: str = "file.yaml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_kalibr_imu_yaml(tmp_path):
    assert read_imu_yaml(_file(tmp_path, KALIBR_IMU)) == ImuNoise.euroc()


def test_imu_yaml_under_one_key_with_opencv_directive_and_exponents_without_a_point(tmp_path):
    text = ("%YAML:1.0\nimu0:\n  accelerometer_noise_density: 2e-3\n  accelerometer_random_walk: 3e-3\n"
            "  gyroscope_noise_density: 1.6968e-04\n  gyroscope_random_walk: 1.9393e-05\n  update_rate: 200\n")
    noise = read_imu_yaml(_file(tmp_path, text))
    assert noise == ImuNoise(2e-3, 3e-3, 1.6968e-04, 1.9393e-05, 200.0)


@pytest.mark.parametrize("text,message", [
    ("accelerometer_noise_density: 1.0e-3\n",
     "accelerometer_random_walk, gyroscope_noise_density, gyroscope_random_walk, update_rate missing"),
    (KALIBR_IMU.replace("200.0", "fast"), r"update_rate must be a finite number, got 'fast'"),
    (KALIBR_IMU.replace("2.66e-05", "-2.66e-05"), "gyroscope_random_walk must be positive"),
    ("- 1\n- 2\n", "not Kalibr's imu.yaml"),
    ("a: [1, 2\n", "not a YAML file at line 2"),
])
def test_imu_yaml_refusals(tmp_path, text, message):
    with pytest.raises(UserError, match=message):
        read_imu_yaml(_file(tmp_path, text))
    with pytest.raises(UserError, match="no such file"):
        read_imu_yaml(str(tmp_path / "missing.yaml"))


def test_kalibr_camchain_imucam(tmp_path):
    cams = read_camchain(_file(tmp_path, KALIBR_CAMCHAIN_IMUCAM))
    assert [c.name for c in cams] == ["cam0", "cam1"]
    cam0, cam1 = cams
    assert cam0.camera.models == (OPENCV5,) and cam0.camera.image_size == (752, 480)
    assert cam0.camera.K[0].tolist() == [[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]]
    assert cam0.camera.dist[0].tolist() == [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
    assert cam0.T_cn_cnm1 is None and cam0.timeshift_cam_imu == 5.63e-04
    assert cam0.T_cam_imu.dtype == torch.float64 and cam0.T_cam_imu[0, 3].item() == -0.0216401454975
    assert cam1.T_cn_cnm1[0, 3].item() == -0.110073808127 and cam1.timeshift_cam_imu == -0.0001
    # the three transforms are read as the one chain they are
    chained = cam1.T_cn_cnm1.numpy() @ cam0.T_cam_imu.numpy()
    assert np.allclose(chained, cam1.T_cam_imu.numpy(), rtol=0, atol=1e-11)


def test_camchain_of_fisheye_and_undistorted_cameras(tmp_path):
    text = ("cam0:\n  camera_model: pinhole\n  intrinsics: [380.8, 380.5, 510.3, 514.3]\n"
            "  distortion_model: equidistant\n  distortion_coeffs: [0.0101, 0.0499, -0.0500, 0.0150]\n"
            "  resolution: [1024, 1024]\n  rostopic: /cam0/image_raw\n"
            "cam1:\n  camera_model: pinhole\n  intrinsics: [500, 500, 320, 240]\n  distortion_model: none\n"
            "  distortion_coeffs: []\n  resolution: [640, 480]\n")
    cam0, cam1 = read_camchain(_file(tmp_path, text))
    assert cam0.camera.models == (FISHEYE,) and cam0.camera.coeffs(0).tolist() == [0.0101, 0.0499, -0.05, 0.015]
    assert cam1.camera.models == (PINHOLE,) and cam1.camera.image_size == (640, 480)
    assert cam0.T_cam_imu is None and cam0.timeshift_cam_imu is None and cam1.T_cn_cnm1 is None


@pytest.mark.parametrize("projection,distortion", [("omni", "radtan"), ("ds", "none"), ("eucm", "none"),
                                                   ("pinhole", "fov")])
def test_unsupported_models_are_named(tmp_path, projection, distortion):
    text = (f"cam0:\n  camera_model: {projection}\n  intrinsics: [0.8, 400, 400, 320, 240]\n"
            f"  distortion_model: {distortion}\n  distortion_coeffs: [0.9]\n  resolution: [640, 480]\n")
    with pytest.raises(UserError, match=f"cam0 is a {projection}-{distortion} camera, which is not supported") as err:
        read_camchain(_file(tmp_path, text))
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("edit,message", [
    (lambda t: t.replace("intrinsics: [458.654, 457.296, 367.215, 248.375]", "intrinsics: [458.654, 457.296]"),
     r"cam0.intrinsics must be \[fu, fv, pu, pv\]"),
    (lambda t: t.replace("[-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]", "[-0.28]"),
     "cam0.distortion_coeffs must hold 4 numbers for radtan distortion"),
    (lambda t: t.replace("resolution: [752, 480]\n  rostopic: /cam1", "resolution: [752]\n  rostopic: /cam1"),
     r"cam1.resolution must be \[width, height\]"),
    (lambda t: t.replace("- [0.0148655429818, -0.999880929698", "- [0.5, -0.999880929698"),
     "cam0.T_cam_imu is not a rigid transform"),
    (lambda t: t.replace("  camera_model: pinhole\n  distortion_coeffs: [-0.28340811", "  distortion_coeffs: "
                         "[-0.28340811"), "cam0: camera_model missing"),
    (lambda t: t.replace("cam0:", "camA:"), r"not Kalibr's camchain.yaml \(no cam0\)"),
    (lambda t: t.replace("timeshift_cam_imu: -0.0001", "timeshift_cam_imu: soon"),
     "cam1.timeshift_cam_imu must be a finite number"),
])
def test_camchain_refusals(tmp_path, edit, message):
    text = edit(KALIBR_CAMCHAIN_IMUCAM)
    assert text != KALIBR_CAMCHAIN_IMUCAM
    with pytest.raises(UserError, match=message):
        read_camchain(_file(tmp_path, text))
