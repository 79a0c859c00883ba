"""Kalibr's YAML files in: an IMU's ``imu.yaml`` (its four noise values and rate) and a ``camchain.yaml`` or
``camchain-imucam.yaml`` (each camera's model, intrinsics, resolution, and where given its pose in the chain, its pose
on the IMU and its time offset).

Kalibr's pinhole cameras with radtan distortion (OpenCV's ``k1, k2, p1, p2``: the ``opencv5`` model with ``k3 = 0``),
equidistant distortion (Kannala-Brandt ``k1 .. k4``: ``fisheye``) or none (``none``) are read; its other models
(``omni``, ``ds``, ``eucm``, the ``fov`` distortion) are refused in one line naming the model. The writers are in
:mod:`ccs_kornia.outputs.imu_exports` and :mod:`ccs_kornia.outputs.rig_exports`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import yaml

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import FISHEYE, OPENCV5, PINHOLE
from ccs_kornia.io.imu import ImuNoise
from ccs_kornia.runtime.errors import UserError

__all__ = ["KalibrCamera", "read_camchain", "read_imu_yaml"]

#: the noise fields of Kalibr's imu.yaml, in ImuNoise's order
IMU_FIELDS = ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
              "gyroscope_random_walk", "update_rate")
#: Kalibr's distortion models read, with their model here and coefficient count
_DISTORTIONS = {"radtan": (OPENCV5, 4), "equidistant": (FISHEYE, 4), "equi": (FISHEYE, 4), "none": (PINHOLE, 0)}


@dataclass
class KalibrCamera:
    """One camera of a Kalibr camchain.

    Args:
        name: its key in the file (``cam0``, ``cam1``, ...).
        camera: the camera (one; ``opencv5`` with ``k3 = 0`` for radtan, ``fisheye`` for equidistant, ``none``).
        T_cn_cnm1: :math:`(4, 4)` float64, the previous camera's frame to this one's (``x_n = T x_{n-1}``), or None.
        T_cam_imu: :math:`(4, 4)` float64, the IMU's frame to this camera's (``x_cam = T x_imu``), or None.
        timeshift_cam_imu: seconds, ``t_imu = t_cam + shift``, or None.
    """

    name: str
    camera: Camera
    T_cn_cnm1: torch.Tensor | None = None
    T_cam_imu: torch.Tensor | None = None
    timeshift_cam_imu: float | None = None


def _load(path: str, what: str) -> Any:
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise UserError(f"{path}: cannot be read as {what} ({getattr(err, 'strerror', None) or err})") from None
    if text.startswith("%YAML:"):  # OpenCV's FileStorage directive (OpenVINS' and others' copies): not YAML 1.1
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        where = getattr(err, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise UserError(f"{path}: not a YAML file{line} ({getattr(err, 'problem', None) or 'unreadable'}); "
                        f"expected {what}") from None


def _number(path: str, key: str, value: Any) -> float:
    """A number of the file; also one YAML 1.1 reads as text (``4e-05``, without a decimal point)."""
    try:
        number = float(value) if not isinstance(value, bool) and isinstance(value, (int, float, str)) else math.nan
    except ValueError:
        number = math.nan
    if not math.isfinite(number):
        raise UserError(f"{path}: {key} must be a finite number, got {value!r}")
    return number


def read_imu_yaml(path: str) -> ImuNoise:
    """Kalibr's ``imu.yaml``: the four noise densities and the update rate (``rostopic`` and other keys ignored; the
    values may also sit under one key, as ``imu0:``).

    Args:
        path: the YAML file.

    Returns:
        the noise values.

    Raises:
        UserError: one line: no such file, not YAML, a field missing, a value that is not a positive number.

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "imu.yaml")
        >>> _ = open(path, "w").write("#Accelerometers\\naccelerometer_noise_density: 1.86e-03  #Noise density\\n"
        ...     "accelerometer_random_walk: 4.33e-04\\ngyroscope_noise_density: 1.87e-04\\n"
        ...     "gyroscope_random_walk: 2.66e-05\\nrostopic: /imu0\\nupdate_rate: 200.0\\n")
        >>> read_imu_yaml(path) == ImuNoise.euroc()
        True
    """
    data = _load(path, "Kalibr's imu.yaml")
    if isinstance(data, dict) and not set(IMU_FIELDS) & set(data):
        nested = [v for v in data.values() if isinstance(v, dict) and set(IMU_FIELDS) & set(v)]
        if len(nested) == 1:
            data = nested[0]
    if not isinstance(data, dict):
        raise UserError(f"{path}: not Kalibr's imu.yaml (expected {', '.join(IMU_FIELDS)})")
    missing = [k for k in IMU_FIELDS if k not in data]
    if missing:
        raise UserError(f"{path}: not Kalibr's imu.yaml: {', '.join(missing)} missing")
    values = [_number(path, k, data[k]) for k in IMU_FIELDS]
    bad = [k for k, v in zip(IMU_FIELDS, values) if not v > 0]
    if bad:
        raise UserError(f"{path}: {', '.join(bad)} must be positive")
    return ImuNoise(*values)


def _matrix(path: str, name: str, key: str, value: Any) -> torch.Tensor:
    """A 4x4 rigid transform of the file, checked: finite, last row ``0 0 0 1``, a rotation (to 1e-3)."""
    try:
        T = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise UserError(f"{path}: {name}.{key} must be a 4x4 matrix of numbers")
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(R.T @ R, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        raise UserError(f"{path}: {name}.{key} is not a rigid transform (a rotation and a translation, last row "
                        "0 0 0 1)")
    return torch.from_numpy(T)


def _camera(path: str, name: str, entry: Any) -> KalibrCamera:
    if not isinstance(entry, dict):
        raise UserError(f"{path}: {name} is not a camera (expected camera_model, intrinsics, distortion_model, ...)")
    missing = [k for k in ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution")
               if k not in entry]
    if missing:
        raise UserError(f"{path}: {name}: {', '.join(missing)} missing")
    projection, distortion = str(entry["camera_model"]), str(entry["distortion_model"])
    if projection != "pinhole" or distortion not in _DISTORTIONS:
        raise UserError(f"{path}: {name} is a {projection}-{distortion} camera, which is not supported (Kalibr's "
                        "pinhole-radtan, pinhole-equidistant and pinhole-none are)")
    model, count = _DISTORTIONS[distortion]
    intrinsics = entry["intrinsics"]
    if not isinstance(intrinsics, list) or len(intrinsics) != 4:
        raise UserError(f"{path}: {name}.intrinsics must be [fu, fv, pu, pv] for a pinhole camera")
    fu, fv, pu, pv = (_number(path, f"{name}.intrinsics", v) for v in intrinsics)
    if not (fu > 0 and fv > 0):
        raise UserError(f"{path}: {name}: the focal lengths fu {fu:g}, fv {fv:g} must be positive")
    coeffs = entry["distortion_coeffs"] or []
    if not isinstance(coeffs, list) or len(coeffs) != count:
        raise UserError(f"{path}: {name}.distortion_coeffs must hold {count} numbers for {distortion} distortion")
    dist = [_number(path, f"{name}.distortion_coeffs", v) for v in coeffs]
    size = entry["resolution"]
    if (not isinstance(size, list) or len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool)
                                                                   and v > 0 for v in size)):
        raise UserError(f"{path}: {name}.resolution must be [width, height] in pixels")
    K = torch.tensor([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]], dtype=torch.float64)
    camera = Camera.from_opencv(model, K, torch.tensor(dist, dtype=torch.float64) if dist else None,
                                (int(size[0]), int(size[1])))
    transforms = {k: _matrix(path, name, k, entry[k]) if entry.get(k) is not None else None
                  for k in ("T_cn_cnm1", "T_cam_imu")}
    shift = entry.get("timeshift_cam_imu")
    return KalibrCamera(name, camera, transforms["T_cn_cnm1"], transforms["T_cam_imu"],
                        None if shift is None else _number(path, f"{name}.timeshift_cam_imu", shift))


def read_camchain(path: str) -> list[KalibrCamera]:
    """Kalibr's ``camchain.yaml`` or ``camchain-imucam.yaml``: its cameras ``cam0, cam1, ...`` in order.

    Args:
        path: the YAML file.

    Returns:
        one :class:`KalibrCamera` per ``camN`` key, ``cam0`` first.

    Raises:
        UserError: one line: no such file, not YAML, no ``cam0``, a camera of a model not supported (named), a field
            missing or malformed (named), a transform that is not rigid.

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "camchain.yaml")
        >>> _ = open(path, "w").write("cam0:\\n  camera_model: pinhole\\n  intrinsics: [458.654, 457.296, 367.215, "
        ...     "248.375]\\n  distortion_model: radtan\\n  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, "
        ...     "1.76187114e-05]\\n  resolution: [752, 480]\\n  rostopic: /cam0/image_raw\\n")
        >>> (cam,) = read_camchain(path)
        >>> cam.name, cam.camera.model.name, cam.camera.image_size, cam.T_cam_imu
        ('cam0', 'opencv5', (752, 480), None)
        >>> cam.camera.K[0].tolist()[0], cam.camera.dist[0].tolist()[-1]
        ([458.654, 0.0, 367.215], 0.0)
    """
    data = _load(path, "Kalibr's camchain.yaml")
    if not isinstance(data, dict) or "cam0" not in data:
        raise UserError(f"{path}: not Kalibr's camchain.yaml (no cam0)")
    cameras = []
    while f"cam{len(cameras)}" in data:
        name = f"cam{len(cameras)}"
        cameras.append(_camera(path, name, data[name]))
    return cameras
