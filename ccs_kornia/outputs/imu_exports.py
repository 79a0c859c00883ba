"""Kalibr's YAML files out: an IMU's ``imu.yaml``, the cameras with their pose on the IMU and time offset
(``camchain-imucam.yaml``) and the IMU as Kalibr's calibration writes it (``imu-*.yaml``: its noise, its model and, for
``scale-misalignment``, its matrices); and the cameras' poses on the IMU as a ROS launch file (:func:`imu_ros_static_transform`).

The cameras' fields are the camchain's (:func:`~ccs_kornia.outputs.rig_exports.kalibr_camera_lines`), with
``T_cam_imu`` and ``timeshift_cam_imu`` after them; :func:`ccs_kornia.io.kalibr.read_camchain` and
:func:`ccs_kornia.io.kalibr.read_imu_yaml` read both back. The functions build text; the command writes the files.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics, ImuModel
from ccs_kornia.io.imu import ImuNoise
from ccs_kornia.outputs.rig_exports import (
    kalibr_camera_lines,
    kalibr_matrix_lines,
    yaml_float,
)
from ccs_kornia.outputs.ros_tf import StaticTransform, pose_tq, static_transform_launch

__all__ = ["camchain_imucam_yaml", "imu_ros_static_transform", "imu_yaml", "kalibr_imu_result_yaml", "to_kalibr_imu_frame"]


def _transforms(value, count: int, what: str) -> np.ndarray:
    T = np.asarray(value.detach().cpu().double() if isinstance(value, torch.Tensor) else value, dtype=np.float64)
    if T.shape == (4, 4) and count == 1:
        T = T[None]
    if T.shape != (count, 4, 4):
        raise ValueError(f"{what} must be ({count}, 4, 4), got {tuple(T.shape)}")
    return T


def camchain_imucam_yaml(cameras: Camera, T_cam_imu, timeshift_cam_imu: Sequence[float],
                         T_cn_cnm1=None, names: Sequence[str] | None = None) -> str:
    """The cameras on an IMU in Kalibr's ``camchain-imucam.yaml`` layout.

    Per camera ``camN``: ``camera_model``, ``intrinsics``, ``distortion_model``, ``distortion_coeffs``, ``resolution``,
    ``rostopic``, ``cam_overlaps``, then ``T_cn_cnm1`` (cameras after the first), ``T_cam_imu`` and
    ``timeshift_cam_imu``. What Kalibr's format cannot hold (opencv5's k3) is said in a comment at the top.

    Args:
        cameras: the C cameras (pinhole with opencv5, k1k2, none or fisheye lenses, image sizes known).
        T_cam_imu: :math:`(C, 4, 4)` the IMU's frame to each camera's (``x_cam = T x_imu``).
        timeshift_cam_imu: C time offsets (s; ``t_imu = t_cam + shift``).
        T_cn_cnm1: :math:`(C - 1, 4, 4)` each camera after the first from the one before it (``x_n = T x_{n-1}``);
            default: from ``T_cam_imu`` (``T_cn_imu T_cnm1_imu^-1``).
        names: the cameras' names for the rostopics (default ``cam0``, ``cam1``, ...).

    Returns:
        the YAML text.

    Raises:
        ValueError: a model Kalibr does not have (rational), shapes that do not match the cameras.

    Example:
        >>> import yaml
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> K = torch.tensor([[450.0, 0, 320], [0, 450, 240], [0, 0, 1]], dtype=torch.float64)
        >>> cam = Camera.from_opencv(FISHEYE, K, torch.tensor([0.01, -0.002, 0.0, 0.0]), (640, 480))
        >>> T = torch.eye(4, dtype=torch.float64)
        >>> T[:3, 3] = torch.tensor([0.05, 0.0, -0.01], dtype=torch.float64)
        >>> chain = yaml.safe_load(camchain_imucam_yaml(cam, T[None], [0.0031]))
        >>> chain["cam0"]["distortion_model"], chain["cam0"]["T_cam_imu"][0], chain["cam0"]["timeshift_cam_imu"]
        ('equidistant', [1.0, 0.0, 0.0, 0.05], 0.0031)
    """
    count = len(cameras)
    T_ci = _transforms(T_cam_imu, count, "T_cam_imu")
    shifts = [float(s) for s in (timeshift_cam_imu.tolist() if isinstance(timeshift_cam_imu, torch.Tensor)
                                 else timeshift_cam_imu)]
    if len(shifts) != count:
        raise ValueError(f"timeshift_cam_imu must hold {count} values, got {len(shifts)}")
    if T_cn_cnm1 is None:
        chain = np.stack([T_ci[c] @ np.linalg.inv(T_ci[c - 1]) for c in range(1, count)]) if count > 1 else None
    else:
        chain = _transforms(T_cn_cnm1, count - 1, "T_cn_cnm1") if count > 1 else None
    names = list(names) if names is not None else [f"cam{c}" for c in range(count)]
    if len(names) != count:
        raise ValueError(f"names must hold {count} names, got {len(names)}")
    text, notes = [], []
    for c in range(count):
        lines, said = kalibr_camera_lines(c, names[c], cameras[c], count)
        notes.extend(said)
        if c > 0 and chain is not None:
            lines.extend(kalibr_matrix_lines("T_cn_cnm1", chain[c - 1][:3, :3], chain[c - 1][:3, 3]))
        lines.extend(kalibr_matrix_lines("T_cam_imu", T_ci[c][:3, :3], T_ci[c][:3, 3]))
        lines.append(f"  timeshift_cam_imu: {yaml_float(shifts[c])}")
        text.extend(lines)
    return "".join(f"# {note}\n" for note in notes) + "\n".join(text) + "\n"


def imu_yaml(noise: ImuNoise, rostopic: str = "/imu0") -> str:
    """An IMU's noise in Kalibr's ``imu.yaml`` layout (with its comments).

    Args:
        noise: the four densities and the rate.
        rostopic: the IMU's topic (Kalibr reads it; files here ignore it).

    Returns:
        the YAML text.

    Example:
        >>> print(imu_yaml(ImuNoise.euroc()), end="")
        #Accelerometers
        accelerometer_noise_density: 0.00186   #Noise density (continuous-time), m/s^2/sqrt(Hz)
        accelerometer_random_walk: 0.000433   #Bias random walk, m/s^3/sqrt(Hz)
        <BLANKLINE>
        #Gyroscopes
        gyroscope_noise_density: 0.000187   #Noise density (continuous-time), rad/s/sqrt(Hz)
        gyroscope_random_walk: 2.66e-05   #Bias random walk, rad/s^2/sqrt(Hz)
        <BLANKLINE>
        rostopic: /imu0   #the IMU ROS topic
        update_rate: 200.0   #Hz (for discretization of the values above)
    """
    number = yaml_float
    return (
        "#Accelerometers\n"
        f"accelerometer_noise_density: {number(noise.accelerometer_noise_density)}   "
        "#Noise density (continuous-time), m/s^2/sqrt(Hz)\n"
        f"accelerometer_random_walk: {number(noise.accelerometer_random_walk)}   #Bias random walk, m/s^3/sqrt(Hz)\n"
        "\n"
        "#Gyroscopes\n"
        f"gyroscope_noise_density: {number(noise.gyroscope_noise_density)}   "
        "#Noise density (continuous-time), rad/s/sqrt(Hz)\n"
        f"gyroscope_random_walk: {number(noise.gyroscope_random_walk)}   #Bias random walk, rad/s^2/sqrt(Hz)\n"
        "\n"
        f"rostopic: {rostopic}   #the IMU ROS topic\n"
        f"update_rate: {number(noise.update_rate)}   #Hz (for discretization of the values above)\n"
    )


def to_kalibr_imu_frame(T_cam_imu, intrinsics: ImuIntrinsics | None):
    """``T_cam_imu`` :math:`(C, 4, 4)` on Kalibr's IMU frame: unchanged for an ideal IMU (``None``); for estimated
    intrinsics, times the rotation from Kalibr's frame to this one (:meth:`ImuIntrinsics.to_kalibr`), so that the
    camchain and :func:`kalibr_imu_result_yaml` hold one IMU frame."""
    if intrinsics is None:
        return T_cam_imu
    T = torch.as_tensor(T_cam_imu, dtype=torch.float64).clone()
    R = intrinsics.to_kalibr().R_kalibr_imu.to(T)
    T[..., :3, :3] = T[..., :3, :3] @ R.T
    return T


def _yaml_matrix(name: str, M, indent: str) -> list[str]:
    rows = np.asarray(M.detach().cpu() if isinstance(M, torch.Tensor) else M, dtype=np.float64)
    return [f"{indent}{name}:"] + [f"{indent}- [{', '.join(yaml_float(float(v)) for v in row)}]" for row in rows]


def kalibr_imu_result_yaml(noise: ImuNoise, model: ImuModel = ImuModel.CALIBRATED,
                           intrinsics: ImuIntrinsics | None = None, rostopic: str = "/imu0",
                           comment: str | None = None) -> str:
    """The IMU as Kalibr's camera-IMU calibration writes it (``imu-<bag>.yaml``): under ``imu0``, ``T_i_b`` (the
    identity: one IMU), the noise, ``model``, ``rostopic``, ``time_offset`` and ``update_rate``; for
    ``scale-misalignment`` also ``accelerometers: M`` and ``gyroscopes: A, C_gyro_i, M`` in Kalibr's convention
    (:class:`~ccs_kornia.geometry.imu_intrinsics.KalibrImuMatrices`; pair it with a camchain written through
    :func:`to_kalibr_imu_frame`). :func:`ccs_kornia.io.kalibr.read_imu_yaml` reads its noise back.

    Args:
        noise: the four densities and the rate.
        model: the IMU model fitted.
        intrinsics: the estimated intrinsics (required for ``scale-misalignment``, else ignored).
        rostopic: the IMU's topic.
        comment: a line written as a comment at the top (e.g. where the noise values come from).

    Returns:
        the YAML text.

    Raises:
        ValueError: ``scale-misalignment`` without intrinsics.

    Example:
        >>> import yaml
        >>> from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics
        >>> text = kalibr_imu_result_yaml(ImuNoise.euroc(), ImuModel.SCALE_MISALIGNMENT, ImuIntrinsics.identity())
        >>> imu0 = yaml.safe_load(text)["imu0"]
        >>> imu0["model"], imu0["accelerometers"]["M"][0], imu0["update_rate"]
        ('scale-misalignment', [1.0, 0.0, 0.0], 200.0)
    """
    if model is ImuModel.SCALE_MISALIGNMENT and intrinsics is None:
        raise ValueError("the scale-misalignment model needs the IMU's intrinsics")
    lines = [f"# {comment}"] if comment else []
    lines += ["imu0:"] + _yaml_matrix("T_i_b", np.eye(4), "  ")
    for key, value in (("accelerometer_noise_density", noise.accelerometer_noise_density),
                       ("accelerometer_random_walk", noise.accelerometer_random_walk),
                       ("gyroscope_noise_density", noise.gyroscope_noise_density),
                       ("gyroscope_random_walk", noise.gyroscope_random_walk)):
        lines.append(f"  {key}: {yaml_float(float(value))}")
    lines += [f"  model: {model.value}", f"  rostopic: {rostopic}", "  time_offset: 0.0",
              f"  update_rate: {yaml_float(float(noise.update_rate))}"]
    if model is ImuModel.SCALE_MISALIGNMENT:
        k = intrinsics.to_kalibr()
        lines += ["  accelerometers:"] + _yaml_matrix("M", k.accel_M, "    ")
        lines += ["  gyroscopes:"] + _yaml_matrix("A", k.gyro_A, "    ") + _yaml_matrix("C_gyro_i", k.gyro_C, "    ")
        lines += _yaml_matrix("M", k.gyro_M, "    ")
    return "\n".join(lines) + "\n"


def imu_ros_static_transform(T_cam_imu, imu_frame: str, camera_frames: Sequence[str]) -> str:
    """The launch file of ``calibrate-imu --ros-tf``: each camera's optical frame in the IMU's frame
    (``T_imu_cam = T_cam_imu^-1``), one ``static_transform_publisher`` per camera.

    Args:
        T_cam_imu: :math:`(C, 4, 4)` the IMU's frame to each camera's.
        imu_frame: the parent frame's name. camera_frames: C child frames' names.

    Example:
        >>> T = torch.eye(4, dtype=torch.float64)[None].clone()
        >>> T[0, 0, 3] = -0.05  # the camera 5 cm along the IMU's x axis
        >>> 'args="0.05 0 0 0 0 0 1 imu cam0_optical_frame"' in imu_ros_static_transform(T, "imu", ["cam0_optical_frame"])
        True
    """
    T = torch.as_tensor(_transforms(T_cam_imu, len(camera_frames), "T_cam_imu"))
    tfs = []
    for c, child in enumerate(camera_frames):
        tq = pose_tq(torch.linalg.inv(T[c]))
        tfs.append(StaticTransform(tq["t"], tq["q"], imu_frame, child, f"imu_camera{c}_broadcaster"))
    return static_transform_launch(tfs, f"camera-IMU calibration: each camera's optical frame in {imu_frame}")
