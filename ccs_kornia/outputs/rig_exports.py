"""A ``rig.json`` in the formats other tools load: OpenCV's stereo FileStorage YAML, ROS stereo ``camera_info``
files, Kalibr's camchain; and the rectification of one pair they share.

Every function here builds text (or checks) from the record; the command writes the files, all at the end, so a
run that fails writes none. Translations stay in the unit of ``--square`` (give it in metres for ROS and Kalibr).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import CAMERA_MODELS, FISHEYE, OPENCV5, RATIONAL
from ccs_kornia.geometry.poses import pair_pose
from ccs_kornia.io.files import atomic_path
from ccs_kornia.outputs.calibration_file import camera_from_record
from ccs_kornia.outputs.camera_exports import ros_camera_info
from ccs_kornia.outputs.rig_records import record_extrinsics, rig_cameras
from ccs_kornia.runtime.errors import UserError

__all__ = [
    "rectification",
    "KALIBR_DISTORTION",
    "write_opencv_stereo_yaml",
    "ros_stereo_files",
    "kalibr_problem",
    "kalibr_camchain",
    "kalibr_camera_lines",
    "kalibr_matrix_lines",
    "yaml_float",
]


#: Kalibr's distortion model of each camera model it holds (its pinhole cameras take radtan: k1, k2, p1, p2, or
#: equidistant: fisheye k1..k4; it has no rational model)
KALIBR_DISTORTION = {m: ("equidistant" if m == FISHEYE else "radtan") for m in CAMERA_MODELS.values() if m != RATIONAL}


def rectification(data: dict[str, Any], i: int = 0, j: int = 1, alpha: float = 0.0) -> dict[str, Any]:
    """The stereo rectification of cameras ``i``, ``j`` of a ``rig.json``
    (:func:`~ccs_kornia.modules.rig.stereo.stereo_rectify` at camera ``i``'s image size) plus ``R``, ``T``
    (``x_j = R x_i + T``), ``image_size``."""
    from ccs_kornia.modules.rig import stereo_rectify

    cams = rig_cameras(data)
    R, T = pair_pose(*record_extrinsics(data["extrinsics"]), i, j)
    size = tuple(int(v) for v in data["cameras"][i]["image_size"])
    rect = dict(stereo_rectify(cams[i], cams[j], size, R, T, alpha=alpha))
    rect.update(R=R.numpy(), T=T.numpy(), image_size=size)
    return rect


def _pair(data: dict[str, Any], i: int, j: int) -> dict[str, Any]:
    """The record's pair ``(i, j)``; the record holds ``i < j``, the other order has ``E`` and ``F`` transposed
    (``x_i^T E_ji x_j = 0``)."""
    for pair in data["pairs"]:
        if pair["cameras"] == [i, j]:
            return pair
        if pair["cameras"] == [j, i]:
            return {**pair, "E": np.asarray(pair["E"]).T.tolist(), "F": np.asarray(pair["F"]).T.tolist()}
    raise KeyError((i, j))


def write_opencv_stereo_yaml(path: str, data: dict[str, Any], rect: dict[str, Any], i: int = 0, j: int = 1) -> None:
    """The pair ``i``, ``j`` as an OpenCV FileStorage YAML: ``K1 D1 K2 D2 R T E F R1 R2 P1 P2 Q`` (the names of
    ``cv2.stereoCalibrate`` / ``cv2.stereoRectify``), image sizes, models, RMS; written to a temporary file renamed
    over ``path``."""
    import cv2

    cams = data["cameras"]
    pair = _pair(data, i, j)
    with atomic_path(path, mode=0o644) as tmp:
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
        if not fs.isOpened():
            raise UserError(f"--opencv-yaml {path}: cannot open for writing")
        try:
            for k, c in (("1", i), ("2", j)):
                fs.write(f"image_width{k}", int(cams[c]["image_size"][0]))
                fs.write(f"image_height{k}", int(cams[c]["image_size"][1]))
            for k, c in (("1", i), ("2", j)):
                camera = camera_from_record(cams[c])
                fs.write(f"K{k}", np.array(cams[c]["K"], dtype=np.float64))
                fs.write(f"D{k}", camera.model.opencv_coeffs(camera.coeffs(0).numpy()).reshape(1, -1))
                fs.write(f"distortion_model{k}", camera.model.opencv_family)
            fs.write("R", np.asarray(rect["R"], dtype=np.float64))
            fs.write("T", np.asarray(rect["T"], dtype=np.float64).reshape(3, 1))
            fs.write("E", np.array(pair["E"], dtype=np.float64))
            fs.write("F", np.array(pair["F"], dtype=np.float64))
            for key in ("R1", "R2", "P1", "P2", "Q"):
                fs.write(key, np.asarray(rect[key], dtype=np.float64))
            fs.write("rectified_width", int(rect["image_size"][0]))
            fs.write("rectified_height", int(rect["image_size"][1]))
            fs.write("rms", float(data["rms"]))
            fs.write("convention", "x2 = R x1 + T (camera 1 to camera 2), as cv2.stereoCalibrate")
        finally:
            fs.release()


def ros_stereo_files(data: dict[str, Any], rect: dict[str, Any], names: tuple[str, str] = ("left", "right"),
                     i: int = 0, j: int = 1) -> dict[str, str]:
    """``{file name: text}`` of the pair's two ROS ``camera_info`` YAML files (``stereo_image_proc``): each camera's
    matrix and coefficients, its rectification (``R1``/``R2``) and projection (``P1``/``P2``; the second has
    ``P[0,3] = -fx' * baseline`` for a horizontal pair)."""
    out = {}
    for name, c, R, P in ((names[0], i, rect["R1"], rect["P1"]), (names[1], j, rect["R2"], rect["P2"])):
        cam = dict(data["cameras"][c])
        camera = camera_from_record(cam)
        cam["distortion"] = {"model": cam["distortion"]["model"],
                             "coeffs": camera.model.opencv_coeffs(camera.coeffs(0).numpy()).tolist()}
        out[f"{name}.yaml"] = ros_camera_info(cam, name, rectification=np.asarray(R).tolist(),
                                              projection=np.asarray(P).tolist())
    return out


def kalibr_problem(data: dict[str, Any]) -> str:
    """Why the rig cannot be written as a Kalibr camchain (``""`` when it can): Kalibr's pinhole cameras take radtan
    (k1, k2, p1, p2) or equidistant (fisheye k1..k4) distortion only."""
    bad = [f"{cam['name']} ({cam['distortion']['model']})" for cam in data["cameras"]
           if camera_from_record(cam).model not in KALIBR_DISTORTION]
    if bad:
        return (f"--kalibr-yaml: Kalibr has no rational (k1..k6) model, used by camera {', '.join(bad)}; "
                "calibrate with --model opencv5, k1k2 or fisheye for a Kalibr camchain")
    return ""


def kalibr_matrix_lines(key: str, R, T) -> list[str]:
    """A 4x4 rigid transform ``[R T; 0 0 0 1]`` (``R`` 3x3, ``T`` 3) as Kalibr's YAML lists it under ``key``, indented
    as a camera's field."""
    lines = [f"  {key}:"]
    for r in range(3):
        lines.append(f"  - {_kalibr_row([*np.asarray(R[r], dtype=np.float64).tolist(), float(T[r])])}")
    lines.append("  - [0.0, 0.0, 0.0, 1.0]")
    return lines


def yaml_float(value: float) -> str:
    """A float as YAML 1.1 reads one (PyYAML, Kalibr): 12 significant digits, always with a decimal point (``1e-05``
    would be read as text, ``200`` as an integer).

    Example:
        >>> yaml_float(1e-05), yaml_float(200.0), yaml_float(0.0031)
        ('1.0e-05', '200.0', '0.0031')
    """
    text = f"{float(value):.12g}"
    if "." in text or "n" in text:  # a decimal point already, or nan / inf
        return text
    mantissa, _, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if exponent else f"{mantissa}.0"


def _kalibr_row(values) -> str:
    return "[" + ", ".join(yaml_float(v) for v in values) + "]"


def kalibr_camera_lines(index: int, name: str, camera: Camera, cameras: int) -> tuple[list[str], list[str]]:
    """Camera ``index`` of ``cameras`` as Kalibr's camchain lists it (``camN:``, ``camera_model``, ``intrinsics``,
    ``distortion_model``, ``distortion_coeffs``, ``resolution``, ``rostopic: /NAME/image_raw``, ``cam_overlaps``: every
    other camera), and notes on what the format could not hold (opencv5's k3).

    Args:
        index: its place in the chain (``camN``).
        name: its name (the rostopic's and the notes').
        camera: the camera (one, of a model in :data:`KALIBR_DISTORTION`, with its image size).
        cameras: how many cameras the chain has.
    """
    model = camera.models[0]
    if model not in KALIBR_DISTORTION:
        raise ValueError(f"Kalibr has no {model.name} model (camera {name}): its pinhole cameras take radtan (k1, k2, "
                         "p1, p2) or equidistant (k1..k4) distortion")
    K = camera.K[0].tolist()
    coeffs = camera.coeffs(0).tolist()
    notes = []
    if model == OPENCV5 and len(coeffs) > 4 and coeffs[4] != 0.0:
        notes.append(f"camera {name}: Kalibr's radtan has no k3; k3 = {coeffs[4]:.6g} left out of the camchain")
    width, height = camera.image_sizes[0]
    lines = [f"cam{index}:", "  camera_model: pinhole", f"  intrinsics: {_kalibr_row([K[0][0], K[1][1], K[0][2], K[1][2]])}",
             f"  distortion_model: {KALIBR_DISTORTION[model]}",
             f"  distortion_coeffs: {_kalibr_row((coeffs + [0.0] * 4)[:4])}",
             f"  resolution: [{int(width)}, {int(height)}]", f"  rostopic: /{name}/image_raw",
             f"  cam_overlaps: [{', '.join(str(k) for k in range(cameras) if k != index)}]"]
    return lines, notes


def kalibr_camchain(data: dict[str, Any]) -> tuple[str, list[str]]:
    """The rig as a Kalibr camchain YAML, and notes on what the format could not hold (opencv5's k3).

    ``T_cn_cnm1`` of camera ``n`` maps camera ``n-1``'s frame to camera ``n``'s (4x4).
    """
    text, notes = [], []
    for c, cam in enumerate(data["cameras"]):
        lines, said = kalibr_camera_lines(c, cam["name"], camera_from_record(cam), len(data["cameras"]))
        notes.extend(said)
        if c > 0:
            R, T = pair_pose(*record_extrinsics(data["extrinsics"]), c - 1, c)
            lines.extend(kalibr_matrix_lines("T_cn_cnm1", R, T))
        text.extend(lines)
    return "\n".join(text) + "\n", notes
