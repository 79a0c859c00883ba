"""The calibration file ``calibrate`` writes (or one camera of ``calibrate-rig``'s), read back and checked
(``undistort --calibration``, ``calibrate-rig --fix-intrinsics``).

A file is refused with one line saying what is wrong: a failed calibration's per-image record (``.failed.json``), a
hand-written ``{"K": ...}`` without distortion or image size, a K that is not a camera matrix, an unknown distortion
model or a coefficient count that does not match it.
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from ccs_kornia.geometry.models.factory import camera_model
from ccs_kornia.geometry.models.fisheye import KannalaBrandtModel
from ccs_kornia.geometry.models.opencv import OPENCV_VARIANTS

__all__ = ["CALIBRATION_COEFFS", "RigFileError", "read_calibration"]


class RigFileError(ValueError):
    """A ``rig.json`` given where one camera's calibration is read, without saying which of its cameras."""


def _coefficient_counts() -> dict[str, tuple[int, ...]]:
    # the models as the solver writes them (``none``: five zeros, or no coefficients at all)
    counts = {name: camera_model(name).num_coeffs for name in (*OPENCV_VARIANTS, KannalaBrandtModel.name)}
    return {name: (n,) if n else (0, 5) for name, n in counts.items()}


#: distortion coefficient counts a calibration file may hold, per model
CALIBRATION_COEFFS: dict[str, tuple[int, ...]] = _coefficient_counts()


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


def read_calibration(path: str | os.PathLike, camera: str | None = None) -> dict[str, Any]:
    """Read and check a calibration JSON written by ``calibrate``, or one camera of a ``rig.json`` written by
    ``calibrate-rig``.

    Args:
        path: the file.
        camera: the camera of a rig file to read (its name or index); a rig file without it is refused, saying what
            to do instead.

    Returns:
        ``{"K": 3x3 float64 array, "coeffs": float64 array, "model": str, "image_size": (w, h), "views": list}``;
        ``coeffs`` holds five zeros for a calibration without distortion; ``views``: the calibration's views as the
        file records them (empty when it has none).

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
    for key in ("K", "distortion", "image_size"):
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
    model = dist.get("model") if isinstance(dist, dict) else None
    if model not in CALIBRATION_COEFFS:
        raise ValueError(f"not a calibration: unknown distortion model {model!r} (expected one of "
                         f"{', '.join(CALIBRATION_COEFFS)})")
    try:
        coeffs = np.array(dist.get("coeffs") or [], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        coeffs = np.array([np.nan])
    if coeffs.size not in CALIBRATION_COEFFS[model] or not np.isfinite(coeffs).all():
        counts = " or ".join(str(n) for n in CALIBRATION_COEFFS[model])
        raise ValueError(f"not a calibration: the {model} model has {counts} finite distortion coefficients, "
                         f"the file gives {coeffs.size}")
    size = data["image_size"]
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise ValueError(f"not a calibration: image_size must be [width, height] in pixels, got {size!r}")
    views = data.get("views") if isinstance(data.get("views"), list) else []
    return {"K": K, "coeffs": camera_model(model).opencv_coeffs(coeffs), "model": model, "image_size": tuple(size),
            "views": views}
