"""The calibration file ``calibrate`` writes (or one camera of ``calibrate-rig``'s), read back and checked
(``undistort --calibration``, ``calibrate-rig --fix-intrinsics``).

A file is refused with one line saying what is wrong: a failed calibration's per-image record (``.failed.json``), a
hand-written ``{"K": ...}`` without distortion or image size, a K that is not a camera matrix, an unknown distortion
model or a coefficient count that does not match it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import CAMERA_MODELS, camera_model
from ccs_kornia.geometry.models.splined import SPLINE_NAME
from ccs_kornia.io.cameramodel import read_cameramodel

__all__ = ["CALIBRATION_COEFFS", "CalibrationFile", "RigFileError", "camera_from_record", "camera_record_fields",
           "read_calibration"]


class RigFileError(ValueError):
    """A ``rig.json`` given where one camera's calibration is read, without saying which of its cameras."""


def _coefficient_counts() -> dict[str, tuple[int, ...]]:
    # the models as the solver writes them (``none``: five zeros, or no coefficients at all)
    return {name: (m.num_coeffs,) if m.num_coeffs else (0, 5) for name, m in CAMERA_MODELS.items()}


#: distortion coefficient counts a calibration file may hold, per model
CALIBRATION_COEFFS: dict[str, tuple[int, ...]] = _coefficient_counts()


@dataclass
class CalibrationFile:
    """One camera's calibration as a file holds it: the camera (with its image size) and the calibration's views as
    the file records them (empty when it has none)."""

    camera: Camera
    views: list = field(default_factory=list)
    #: the calibration's figures as the file records them (``diagnostics``: its projection uncertainty over the image
    #: among them), empty when it has none
    diagnostics: dict = field(default_factory=dict)


def camera_record_fields(camera: Camera) -> dict[str, Any]:
    """A camera (one) as the JSON files write it: ``image_size``, ``K`` and ``distortion`` (``model``, ``coeffs`` in
    OpenCV's layout); the inverse of :func:`camera_from_record`.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2
        >>> cam = Camera(K1K2, torch.tensor([500., 500, 320, 240, -0.1, 0.01], dtype=torch.float64), (640, 480))
        >>> fields = camera_record_fields(cam)
        >>> fields["distortion"]["model"], len(fields["distortion"]["coeffs"]), fields["image_size"]
        ('k1k2', 5, [640, 480])
    """
    if len(camera) != 1:
        raise ValueError(f"camera_record_fields takes one camera, got {len(camera)}.")
    K = camera.K[0].double().cpu()
    size = camera.image_size
    return {"image_size": None if size is None else [int(size[0]), int(size[1])],
            "K": [[float(v) for v in row] for row in K.tolist()],
            "distortion": {"model": str(camera.model), "coeffs": [float(v) for v in camera.coeffs(0).double().tolist()]}}


def camera_from_record(data: dict[str, Any], need_size: bool = True) -> Camera:
    """The camera of a calibration record (``K``, ``distortion``, ``image_size``: what ``calibrate`` writes, and each
    camera of ``calibrate-rig``'s ``cameras``), checked: where files' model names become models.

    Raises:
        ValueError: one line saying what is wrong (a K that is not a camera matrix, an unknown distortion model, a
            coefficient count that does not match it, no image size where ``need_size``).

    Example:
        >>> cam = camera_from_record({"K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]], "image_size": [640, 480],
        ...                           "distortion": {"model": "fisheye", "coeffs": [0.01, 0, 0, 0]}})
        >>> cam.model, cam.image_size
        (KannalaBrandtModel('fisheye'), (640, 480))
    """
    for key in ("K", "distortion", *(("image_size",) if need_size else ())):
        if data.get(key) is None:
            raise ValueError(f"not a calibration: {json.dumps(key)} is missing")
    try:
        K = np.array(data["K"], dtype=np.float64)
    except (TypeError, ValueError):
        K = np.zeros(0)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise ValueError("not a calibration: K must be a 3x3 matrix of finite numbers")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"not a calibration: the focal lengths fx {K[0, 0]:g}, fy {K[1, 1]:g} must be positive")
    if not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise ValueError("not a calibration: K's last row must be [0, 0, 1]")
    dist = data["distortion"]
    name = dist.get("model") if isinstance(dist, dict) else None
    if isinstance(name, str) and name.startswith(SPLINE_NAME):
        return _splined_from_record(name, K, dist, data.get("image_size"), need_size)
    if name not in CALIBRATION_COEFFS:
        raise ValueError(f"not a calibration: unknown distortion model {name!r} (expected one of "
                         f"{', '.join(CALIBRATION_COEFFS)})")
    try:
        coeffs = np.array(dist.get("coeffs") or [], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        coeffs = np.array([np.nan])
    if coeffs.size not in CALIBRATION_COEFFS[name] or not np.isfinite(coeffs).all():
        counts = " or ".join(str(n) for n in CALIBRATION_COEFFS[name])
        raise ValueError(f"not a calibration: the {name} model has {counts} finite distortion coefficients, "
                         f"the file gives {coeffs.size}")
    size = data.get("image_size")
    if size is not None or need_size:
        if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
            raise ValueError(f"not a calibration: image_size must be [width, height] in pixels, got {size!r}")
    model = CAMERA_MODELS[name]
    try:
        return Camera.from_opencv(model, torch.from_numpy(K), torch.from_numpy(coeffs),
                                  None if size is None else tuple(size))
    except ValueError as err:  # e.g. k1k2 with tangential terms
        raise ValueError(f"not a calibration: {err}") from None


def _splined_from_record(name: str, K: np.ndarray, dist: dict, size: Any, need_size: bool) -> Camera:
    """A splined camera's record: its model's name with the grid, the control points' values as ``coeffs``."""
    try:
        model = camera_model(name)
    except ValueError as err:
        raise ValueError(f"not a calibration: {err}") from None
    try:
        coeffs = np.array(dist.get("coeffs") or [], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        coeffs = np.array([np.nan])
    if coeffs.size != model.num_coeffs or not np.isfinite(coeffs).all():
        raise ValueError(f"not a calibration: the {name} model has {model.num_coeffs} finite coefficients, the file "
                         f"gives {coeffs.size}")
    if size is not None or need_size:
        if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
            raise ValueError(f"not a calibration: image_size must be [width, height] in pixels, got {size!r}")
    return Camera.from_opencv(model, torch.from_numpy(K), torch.from_numpy(coeffs), None if size is None else tuple(size))


def _rig_camera(data: dict[str, Any], camera: str) -> dict[str, Any]:
    """Camera ``camera`` (its name, or its index) of a ``rig.json``: written as ``calibrate`` writes one."""
    cameras = [c for c in data["cameras"] if isinstance(c, dict)]
    names = [str(c.get("name")) for c in cameras]
    if camera in names:
        return cameras[names.index(camera)]
    if camera.isdigit() and int(camera) < len(cameras):
        return cameras[int(camera)]
    raise ValueError(f"--camera {camera}: no such camera in the rig (its cameras: {', '.join(names)}, or their "
                     f"indices 0..{len(cameras) - 1})")


def read_calibration(path: str | os.PathLike, camera: str | None = None) -> CalibrationFile:
    """Read and check a calibration JSON written by ``calibrate``, one camera of a ``rig.json`` written by
    ``calibrate-rig``, or an mrcal ``.cameramodel`` file (:mod:`~ccs_kornia.io.cameramodel`).

    Args:
        path: the file.
        camera: the camera of a rig file to read (its name or index); a rig file without it is refused, saying what
            to do instead.

    Returns:
        :class:`CalibrationFile`: the camera (float64, with its image size) and the calibration's views as the file
        records them (empty when it has none).

    Raises:
        ValueError: one line saying what is wrong (a file of a failed calibration says so); :class:`RigFileError`
            for a rig file without ``camera``.

    Example:
        >>> import tempfile, os
        >>> from ccs_kornia.io.files import write_json
        >>> path = os.path.join(tempfile.mkdtemp(), "c.json")
        >>> write_json(path, {"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]})
        >>> read_calibration(path)
        Traceback (most recent call last):
        ...
        ValueError: not a calibration: "distortion" is missing
    """
    if str(path).endswith(".cameramodel"):  # mrcal's format: the camera alone
        if camera is not None:
            raise ValueError(f"--camera {camera}: an mrcal .cameramodel file holds one camera (drop --camera)")
        return CalibrationFile(read_cameramodel(path)[0])
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except FileNotFoundError:
        raise ValueError("no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"not a readable JSON file ({err})") from None
    if not isinstance(data, dict):
        raise ValueError("not a calibration: the file holds no JSON object")
    if isinstance(data.get("cameras"), list) and "extrinsics" in data:
        if camera is None:
            names = ", ".join(str(c.get("name")) for c in data["cameras"] if isinstance(c, dict))
            raise RigFileError(f"a rig calibration written by calibrate-rig (cameras {names}), not one camera's")
        data = _rig_camera(data, camera)
    elif camera is not None:
        raise ValueError(f"--camera {camera}: the file is one camera's calibration, not a rig's (drop --camera)")
    if data.get("success") is False:
        error = data.get("error") or "no camera was computed"
        raise ValueError(f"this is a failed calibration: {error}")
    views = data.get("views") if isinstance(data.get("views"), list) else []
    diagnostics = data.get("diagnostics") if isinstance(data.get("diagnostics"), dict) else {}
    return CalibrationFile(camera_from_record(data), views, diagnostics)
