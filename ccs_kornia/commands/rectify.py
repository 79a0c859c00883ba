"""``ccs_kornia rectify``: stereo pairs rectified with a ``rig.json`` (``cv2.stereoRectify`` /
``cv2.fisheye.stereoRectify`` through :func:`~ccs_kornia.modules.rig.stereo.stereo_rectify`, then
``initUndistortRectifyMap`` and ``remap``): the rows of the two images of a pair are the same epipolar lines."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._output_paths import check_outputs, make_dir
from ccs_kornia.commands._printing import warn
from ccs_kornia.commands._stereo_pair import parse_pair
from ccs_kornia.io.images import read_image, write_image
from ccs_kornia.outputs.rig_exports import rectification
from ccs_kornia.outputs.rig_records import rectify_maps
from ccs_kornia.pipeline.frame_matching import match_frames
from ccs_kornia.runtime.errors import UserError

__all__ = ["read_rig", "run"]


def read_rig(path: str) -> dict[str, Any]:
    """A ``rig.json`` written by ``calibrate-rig`` (one clear error line when it is not one)."""
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except FileNotFoundError:
        raise UserError(f"--calibration {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserError(f"--calibration {path}: not a readable JSON file ({err})") from None
    if not isinstance(data, dict) or "extrinsics" not in data or "cameras" not in data:
        raise UserError(f"--calibration {path}: not a rig calibration written by calibrate-rig (no cameras and "
                        "extrinsics; a single camera's calibration is undistorted with 'undistort')")
    return data


def _stem(path: str) -> str:
    """A file's name without its numbers (``left07.jpg`` -> ``left.jpg``): what a camera's files share."""
    return re.sub(r"\d+", "", os.path.basename(path)).lower()


def _camera_of(files: list[str], data: dict[str, Any]) -> tuple[int | None, str]:
    """Which camera of the rig ``files`` belong to, as far as ``rig.json``'s record of each camera's files tells, and
    how that is known (``(None, "")`` when it does not tell): the same files, else files of the same names (a copy),
    else names alike but for their numbers (``left``, ``right``)."""
    recorded = [[v["path"] for v in cam.get("views") or [] if isinstance(v, dict) and v.get("path")]
                for cam in data["cameras"]]
    for how, key in (("the calibration's own files", os.path.realpath), ("files of the calibration's names",
                                                                          os.path.basename),
                     ("file names like the calibration's", _stem)):
        given = {key(f) for f in files}
        scores = [len(given & {key(f) for f in cam}) for cam in recorded]
        best = max(scores, default=0)
        if best and scores.count(best) == 1:
            return scores.index(best), how
        if best:  # these names are shared by several cameras: a weaker clue cannot separate them either
            return None, ""
    return None, ""


def _check_order(files: list[list[str]], folders: tuple[str, str], pair: tuple[int, int], data: dict[str, Any]) -> None:
    """Refuse folders that hold the other camera's images than ``--pair`` puts there (each image would be rectified
    with the other camera's model: the rows land pixels apart, worse than no rectification)."""
    names = [cam.get("name") or f"cam{c}" for c, cam in enumerate(data["cameras"])]
    seen = [_camera_of(f, data) for f in files]
    if all(c == p or c is None for (c, _), p in zip(seen, pair)):
        return
    (first, how), (second, _) = seen
    if (first, second) == (pair[1], pair[0]):
        raise UserError(f"{folders[0]} holds camera {names[first]}'s images and {folders[1]} camera "
                        f"{names[second]}'s ({how}), but --pair {pair[0]},{pair[1]} puts camera {names[pair[0]]} "
                        f"first: swap the two folders")
    k = 0 if first not in (None, pair[0]) else 1
    c, why = seen[k]
    raise UserError(f"{folders[k]} holds camera {names[c]}'s images ({why}), but --pair {pair[0]},{pair[1]} puts "
                    f"camera {names[pair[k]]} there: give the folders in the order of --pair, or another --pair")


def run(args: argparse.Namespace) -> int:
    data = read_rig(args.calibration)
    i, j = parse_pair(args.pair, len(data["cameras"]))
    files = [inputs("rectify", [args.left]), inputs("rectify", [args.right])]
    _check_order(files, (args.left, args.right), (i, j), data)
    frames = match_frames(files)
    pairs = [(files[0][a], files[1][b]) for a, b in zip(*frames.index) if a is not None and b is not None]
    if not pairs:
        raise UserError(f"no image of {args.left} pairs with one of {args.right} (frames match by the last number in "
                        "the file names, else by sorted order)")
    check_outputs(dirs=[("--out-dir", args.out_dir)])  # created once there is a pair to write
    rect = rectification(data, i, j, alpha=args.alpha)
    maps = rectify_maps(data, rect, i, j)
    sizes = [tuple(int(v) for v in data["cameras"][c]["image_size"]) for c in (i, j)]
    written = 0
    for left, right in tqdm(pairs, unit="pair", desc="rectify", file=sys.stderr, disable=None, leave=False):
        images = [read_image(p, gray=False) for p in (left, right)]
        bad = [(p, why) for p, (im, why, _) in zip((left, right), images) if im is None]
        bad += [(p, f"image size {im.shape[1]}x{im.shape[0]} differs from the calibration's {s[0]}x{s[1]}")
                for p, (im, _, _), s in zip((left, right), images, sizes) if im is not None and
                (im.shape[1], im.shape[0]) != s]
        if bad:
            for p, why in bad:
                warn("rectify", f"skipped the pair of {p}: {why}")
            continue
        if not written:
            make_dir("--out-dir", args.out_dir)
        for path, (image, _, _), (mx, my) in zip((left, right), images, maps):
            out = cv2.remap(np.ascontiguousarray(image), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            stem, ext = os.path.splitext(os.path.basename(path))
            target = os.path.join(args.out_dir, f"{stem}_rect{ext if ext.lower() in ('.png', '.jpg', '.jpeg') else '.png'}")
            if not write_image(target, out):
                raise UserError(f"--out-dir {args.out_dir}: could not write {target}")
        written += 1
    if written == 0:
        raise UserError(f"no pair rectified (all {len(pairs)} pairs were skipped)")
    print(f"rectified {written} of {len(pairs)} pairs into {args.out_dir} (cameras {i} and {j}; rows of a pair are "
          "epipolar lines)")
    return 0
