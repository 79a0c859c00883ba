"""``ccs_kornia undistort``: images undistorted with a calibration (as ``cv2.undistort``; a fisheye calibration as
``cv2.fisheye.undistortImage`` with ``estimateNewCameraMatrixForUndistortRectify``'s balance)."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from ccs_kornia.commands._common import UserError, inputs, make_dir, resolve_device, warn

__all__ = ["run"]


def _read_calibration(path: str) -> tuple[Any, Any, tuple[int, int] | None, bool]:
    import torch

    from ccs_kornia.calibration_file import read_calibration

    try:
        calib = read_calibration(path)
    except ValueError as err:
        raise UserError(f"--calibration {path}: {err}") from None
    K = torch.from_numpy(calib["K"])
    dist = torch.from_numpy(calib["coeffs"])
    return K, dist, calib["image_size"], calib["model"] == "fisheye"


def run(args: argparse.Namespace) -> int:
    import torch
    from kornia.geometry.calibration import undistort_image
    from tqdm import tqdm

    from ccs_kornia.io import read_image, write_image

    from ccs_kornia.modules.correction.fisheye_warp import fisheye_new_camera_matrix, fisheye_undistort_image

    K, dist, calib_size, fisheye = _read_calibration(args.calibration)
    device = resolve_device(args.device)
    files = inputs("undistort", args.images)
    make_dir("--out-dir", args.out_dir)
    K, dist = K.to(device), dist.to(device)
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
        if fisheye:
            size = (w, h)
            if size not in new_K:
                new_K[size] = fisheye_new_camera_matrix(K[None], dist[None], size, args.balance)
            out = fisheye_undistort_image(tensor.double(), K[None], dist[None], new_K[size])[0]
        else:
            out = undistort_image(tensor.double(), K[None], dist[None])[0]
        if not write_image(target, out, bit_depth=16 if depth > 8 and ext.lower() in (".png", ".tif", ".tiff") else 8):
            warn("undistort", f"could not write {target}")
            continue
        written += 1
    if written == 0:
        raise UserError(f"no image undistorted (all {len(files)} inputs were skipped)")
    print(f"undistorted {written} of {len(files)} images into {args.out_dir}")
    return 0
