"""``ccs_kornia undistort``: images undistorted with a calibration into pinhole views along the optical axis.

The view's camera comes from the lens's valid field (where the model is monotonic and the calibration's corners
reached, read from the JSON's views when it has them): ``--balance 0`` the largest view without black borders,
``1`` the whole valid field, ``--fov`` an explicit horizontal field of view (see ``docs/undistortion.md``). The
images are then resampled as ``cv2.undistort`` / ``cv2.fisheye.undistortImage`` with that ``newCameraMatrix``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import Any

import torch
from tqdm import tqdm

from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._output_paths import check_outputs, make_dir
from ccs_kornia.commands._printing import info, warn
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.io.images import read_image, write_image
from ccs_kornia.modules.undistort.undistort_image import undistort_image
from ccs_kornia.modules.undistort.valid_field import valid_radius
from ccs_kornia.modules.undistort.view_camera import horizontal_fov, view_camera_matrix
from ccs_kornia.outputs.calibration_file import (
    CalibrationFile,
    RigFileError,
    read_calibration,
)
from ccs_kornia.runtime.errors import UserError

__all__ = ["run"]


def _read_calibration(path: str, camera: str | None = None) -> CalibrationFile:
    try:
        return read_calibration(path, camera)
    except RigFileError as err:
        raise UserError(f"--calibration {path}: {err}: rectify its stereo pairs with 'rectify', or give one of its "
                        "cameras with --camera NAME") from None
    except ValueError as err:
        raise UserError(f"--calibration {path}: {err}") from None


def _calibrated_corners(views: list) -> Any:
    """The corners of the calibration's used views, :math:`(1, N, 2)` (hidden ones NaN), or ``None`` without any.

    They bound the valid field (beyond them the model is extrapolated); a calibration without views is framed by
    the monotonic range of its model within the image alone.
    """
    try:
        rows = [[float("nan") if c is None else float(c) for c in corner[:2]]
                for view in views if isinstance(view, dict) and view.get("used") and view.get("corners")
                for corner in view["corners"]]
        points = torch.tensor(rows, dtype=torch.float64).reshape(1, -1, 2)
    except (ValueError, TypeError, AttributeError, IndexError, RuntimeError):
        return None
    return points if bool(points.isfinite().all(-1).any()) else None


def _view_camera(camera: Camera, size: tuple[int, int], field: torch.Tensor, args: argparse.Namespace) -> torch.Tensor:
    """The undistorted view's camera for images of ``size`` (``--balance`` or ``--fov``), with a warning when
    ``--fov`` is clamped to the valid field and one line saying how the view is framed."""
    balance, fov_asked = getattr(args, "balance", 0.0), getattr(args, "fov", None)
    try:
        new_K = view_camera_matrix(camera, size, balance, fov_asked, field)
    except ValueError as err:
        raise UserError(f"--calibration {args.calibration}: cannot frame an undistorted view: {err}") from None
    fov = float(horizontal_fov(new_K, size)[0])
    angle = math.degrees(math.atan(float(field[0])))
    if fov_asked is not None and fov < fov_asked - 0.05:
        warn("undistort", f"--fov {fov_asked:g} clamped to {fov:.1f} degrees, the valid field of the lens model "
                          f"(monotonic and calibrated up to {angle:.1f} degrees from the axis)")
    how = f"--fov {fov_asked:g}" if fov_asked is not None else f"--balance {balance:g}"
    info(f"undistort: {size[0]}x{size[1]} view ({how}): horizontal field of view {fov:.1f} degrees, "
         f"f = {float(new_K[0, 0, 0]):.1f} px, valid field up to {angle:.1f} degrees from the axis")
    return new_K


def run(args: argparse.Namespace) -> int:
    calibration = _read_calibration(args.calibration, getattr(args, "camera", None))
    device = resolve_device(args.device)
    files = inputs("undistort", args.images)
    check_outputs(dirs=[("--out-dir", args.out_dir)])  # created once there is an image to write
    camera, calib_size = calibration.camera.to(device), calibration.camera.image_size
    corners = _calibrated_corners(calibration.views)
    corners = None if corners is None else corners.to(device)
    field = valid_radius(camera, corners)  # on the normalized plane: the tangent of the angle from the axis
    written, used_names, new_K = 0, set(), {}
    for path in tqdm(files, unit="img", desc="undistort", file=sys.stderr, disable=None, leave=False):
        image, reason, depth = read_image(path, gray=False)
        if image is None:
            warn("undistort", f"skipped {path}: {reason}")
            continue
        h, w = image.shape[:2]
        if calib_size is not None and (w, h) != calib_size:
            warn("undistort", f"skipped {path}: image size {w}x{h} differs from the calibration's {calib_size[0]}x{calib_size[1]}")
            continue
        stem, ext = os.path.splitext(os.path.basename(path))
        if ext.lower() not in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"):
            ext = ".png"
        name, k = stem + ext, 1
        while name in used_names:  # same file name from different input folders
            name, k = f"{stem}_{k}{ext}", k + 1
        used_names.add(name)
        target = os.path.join(args.out_dir, name)
        if os.path.exists(target) and os.path.samefile(target, path):
            warn("undistort", f"skipped {path}: writing to --out-dir would overwrite the input")
            continue
        tensor = torch.from_numpy(image).to(device)
        tensor = tensor[None, None] if tensor.dim() == 2 else tensor.permute(2, 0, 1)[None]
        size = (w, h)
        if size not in new_K:
            new_K[size] = _view_camera(camera, size, field, args)
        out = undistort_image(tensor.double(), camera, new_K[size], field)[0]
        if not written:
            make_dir("--out-dir", args.out_dir)
        if not write_image(target, out, bit_depth=16 if depth > 8 and ext.lower() in (".png", ".tif", ".tiff") else 8):
            warn("undistort", f"could not write {target}")
            continue
        written += 1
    if written == 0:
        raise UserError(f"no image undistorted (all {len(files)} inputs were skipped)")
    print(f"undistorted {written} of {len(files)} images into {args.out_dir}")
    return 0
