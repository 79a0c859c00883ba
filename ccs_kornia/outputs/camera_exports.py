"""One camera's calibration in the formats other tools load: OpenCV's FileStorage YAML and ROS ``camera_info``."""

from __future__ import annotations

import time
from typing import Any

import cv2
import numpy as np

from ccs_kornia.geometry.models.factory import FISHEYE, RATIONAL
from ccs_kornia.io.files import atomic_path
from ccs_kornia.outputs.calibration_file import camera_from_record
from ccs_kornia.runtime.errors import UserError

__all__ = ["ROS_DISTORTION_MODELS", "opencv_record", "ros_camera_info", "write_opencv_yaml"]


def opencv_record(data: dict[str, Any]) -> dict[str, Any]:
    """The calibration record as OpenCV's functions take it: for a camera no OpenCV model holds (a splined one), its
    closest OpenCV camera (``opencv_equivalent``) in place of its own."""
    equivalent = data.get("opencv_equivalent")
    return data if not equivalent else {**data, "K": equivalent["K"], "distortion": equivalent["distortion"]}


def write_opencv_yaml(path: str, data: dict[str, Any]) -> None:
    """A calibration as OpenCV's FileStorage YAML (the names of OpenCV's calibration sample), written atomically (a
    splined camera as its closest OpenCV camera, :func:`opencv_record`)."""
    data = opencv_record(data)
    with atomic_path(path, mode=0o644) as tmp:
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
        if not fs.isOpened():
            raise UserError(f"--opencv-yaml {path}: cannot open for writing")
        try:
            fs.write("calibration_time", time.strftime("%Y-%m-%d %H:%M:%S"))
            fs.write("nr_of_frames", int(data["num_views"]["used"]))
            fs.write("image_width", int(data["image_size"][0]))
            fs.write("image_height", int(data["image_size"][1]))
            fs.write("board_width", int(data["board"][0]))
            fs.write("board_height", int(data["board"][1]))
            fs.write("square_size", float(data["square"]))
            fs.write("camera_matrix", np.array(data["K"], dtype=np.float64))
            camera = camera_from_record(data)
            fs.write("distortion_coefficients", camera.model.opencv_coeffs(camera.coeffs(0).numpy()).reshape(-1, 1))
            # which projection the coefficients belong to: cv2.fisheye's k1..k4 or cv2's polynomial model
            fs.write("distortion_model", camera.model.opencv_family)
            fs.write("avg_reprojection_error", float(data["rms"]))
        finally:
            fs.release()


#: ROS camera_info names of the models (image_pipeline's camera_calibration writes ``equidistant`` for fisheye); the
#: others are ``plumb_bob``
ROS_DISTORTION_MODELS = {FISHEYE: "equidistant", RATIONAL: "rational_polynomial"}


def ros_camera_info(data: dict[str, Any], camera_name: str = "camera", rectification: Any = None,
                    projection: Any = None) -> str:
    """The calibration as a ROS ``camera_info`` YAML (``camera_calibration_parsers`` format). Monocular by default:
    identity rectification, projection ``[K | 0]``; a stereo camera passes its ``rectification`` (3x3, ``R1``/``R2``
    of the rectification) and ``projection`` (3x4, ``P1``/``P2``). A splined camera is written as its closest OpenCV
    camera (:func:`opencv_record`)."""
    data = opencv_record(data)
    K = [float(v) for row in data["K"] for v in row]
    camera = camera_from_record(data, need_size=False)
    coeffs = camera.model.opencv_coeffs(camera.coeffs(0).numpy()).tolist()
    model = ROS_DISTORTION_MODELS.get(camera.model, "plumb_bob")
    P = [K[0], K[1], K[2], 0.0, K[3], K[4], K[5], 0.0, K[6], K[7], K[8], 0.0]
    if projection is not None:
        P = [float(v) for row in projection for v in row]
    R = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    if rectification is not None:
        R = [float(v) for row in rectification for v in row]

    def matrix(rows: int, cols: int, values: list[float]) -> str:
        return f"  rows: {rows}\n  cols: {cols}\n  data: [{', '.join(f'{v:.9g}' for v in values)}]\n"

    return (f"image_width: {int(data['image_size'][0])}\nimage_height: {int(data['image_size'][1])}\n"
            f"camera_name: {camera_name}\ncamera_matrix:\n{matrix(3, 3, K)}distortion_model: {model}\n"
            f"distortion_coefficients:\n{matrix(1, len(coeffs), coeffs)}"
            f"rectification_matrix:\n{matrix(3, 3, R)}"
            f"projection_matrix:\n{matrix(3, 4, P)}")
