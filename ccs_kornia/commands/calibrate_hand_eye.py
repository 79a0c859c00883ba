"""``ccs_kornia calibrate-hand-eye``: where the camera sits on a robot, from board images and the robot's pose of
each image (docs/hand_eye.md); writes ``handeye.json`` and, on request, a ROS static transform, easy_handeye's YAML
and a report.

Images and poses are paired by file name, never by order: an image without a pose, a pose without an image and an
image without a board are each reported and left out. Degenerate or disagreeing data (too few poses, tiny rotations,
one axis, the robot and the camera disagreeing) is refused with one line naming the poses (exit status 2). Every
output is written at the end, once the calibration is computed.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from ccs_kornia.commands._boards import board_records, require_circle_origin
from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._messages import not_found_message
from ccs_kornia.commands._output_paths import (
    check_outputs,
    make_dir,
)
from ccs_kornia.commands._printing import info, warn
from ccs_kornia.commands._run import calibrate_files, run_files
from ccs_kornia.io.files import write_json, write_text_atomic
from ccs_kornia.io.robot_poses import match_poses, read_robot_poses
from ccs_kornia.modules.detection.boards import grid_object_points
from ccs_kornia.modules.detection.circles.centre_bias import correct_centres
from ccs_kornia.modules.detection.markers.apriltag import (
    AprilTagDetector,
    AprilTagTarget,
)
from ccs_kornia.modules.hand_eye import HandEyeSetup, calibrate_hand_eye
from ccs_kornia.outputs.calibration_file import camera_from_record, read_calibration
from ccs_kornia.outputs.hand_eye_exports import (
    moveit_calibration_yaml,
    ros_static_transform,
)
from ccs_kornia.outputs.hand_eye_records import hand_eye_record
from ccs_kornia.outputs.report.hand_eye import write_hand_eye_report
from ccs_kornia.runtime.errors import UserError

__all__ = ["COMMAND", "parse_frames", "parse_robot_noise", "run", "summary_lines"]

COMMAND = "calibrate-hand-eye"


def parse_robot_noise(text: str) -> tuple[float, float] | str | None:
    """``--robot-noise``: ``auto`` (estimated), ``none`` (poses exact) or ``DEG,MM`` (the poses' 1-sigma), as the solver
    takes it (radians, metres).

    Example:
        >>> parse_robot_noise("auto"), parse_robot_noise("none"), [round(v, 6) for v in parse_robot_noise("0.1,0.5")]
        ('auto', None, [0.001745, 0.0005])
    """
    if text in ("auto", "none"):
        return None if text == "none" else text
    try:
        deg, mm = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--robot-noise {text}: expected auto, none or DEG,MM (e.g. 0.05,0.2)") from None
    if not (deg > 0 and mm > 0):
        raise UserError(f"--robot-noise {text}: both sigmas must be positive")

    return math.radians(deg), mm / 1000.0


def parse_frames(text: str) -> tuple[str, str, str]:
    """``--ros-frames BASE,FLANGE,CAMERA``.

    Example:
        >>> parse_frames("panda_link0,panda_link8,camera_color_optical_frame")[1]
        'panda_link8'
    """
    names = [n.strip() for n in text.split(",")]
    if len(names) != 3 or not all(names) or any(" " in n for n in names):
        raise UserError(f"--ros-frames {text}: expected three frame names BASE,FLANGE,CAMERA")
    return names[0], names[1], names[2]


def _distortion(camera) -> dict[str, Any]:
    """A camera's distortion as the hand-eye record gives it: the model's name and OpenCV's full coefficients."""
    return {"model": str(camera.model), "coeffs": camera.model.opencv_coeffs(camera.coeffs(0).numpy()).tolist()}


def _camera(args, image_size_hint=None) -> tuple[Any, dict[str, Any]] | None:
    """The camera of ``--calibration`` and its record, or None."""
    if not args.calibration:
        return None

    try:
        cal = read_calibration(args.calibration)
    except ValueError as err:
        raise UserError(f"--calibration {args.calibration}: {err}") from None
    camera = cal.camera
    record = {"source": args.calibration, "image_size": list(camera.image_size), "K": camera.K[0].tolist(),
              "distortion": _distortion(camera)}
    with open(args.calibration, encoding="utf-8") as handle:
        full = json.load(handle)
    for key in ("rms", "std"):
        if key in full:
            record[key] = full[key]
    return camera, record


def _detect_tag(files: list[str], args, device, camera):
    """The tag's corners through the pipeline, the camera's lens straightening its sides (no correction network, no
    corner weights: the hand-eye fit takes neither): corners (V, 4, 2), found (V,), present (V,), reasons, image size
    (the first readable image's: an image of another size is left out)."""
    detector = AprilTagDetector(args.tag_target, camera)
    pipeline = make_pipeline(args, detector=detector, distortion_correction=False, weigh_corners=False)
    out, _ = run_files(COMMAND, pipeline, [files], detector.target.board_size, args.tag_size, device, calibrate=False)
    one = out.select(0)
    corners, found, present, reasons = _views(one, len(files))
    sizes = [tuple(int(x) for x in s) for s in one.view_sizes.cpu().tolist()]
    size = next((sizes[v] for v in range(len(files)) if present[v]), None)
    for v in range(len(files)):
        if present[v] and sizes[v] != size:
            found[v] = False
            reasons[v] = f"image size {sizes[v][0]}x{sizes[v][1]} differs from the first image's {size[0]}x{size[1]}"
    return corners, found, present, reasons, size


def _detect_board(files: list[str], args, device, camera):
    """A board's corners through the pipeline (and the camera calibrated from the same images when none is given);
    a circle grid's centres corrected for the given ``camera`` (the calibration corrects them itself)."""
    # the camera from the same images on a flat board: the hand-eye fit judges the board's sag itself
    pipeline = make_pipeline(args, model=args.model, board_flatness=False)
    camera_record = None
    if camera is not None:
        out, _ = run_files(COMMAND, pipeline, [files], args.board, args.square, device, calibrate=False)
        one = out.select(0)
        grid = getattr(args, "circle_board", None)
        if grid is not None:
            det = one.detections
            fixed = correct_centres(det.corners, det.valid, camera, grid.object_points(), grid.dot_diameters() / 2)
            one = replace(one, detections=replace(det, corners=fixed.to(det.corners)))
    else:
        try:
            camera_record, one = calibrate_files(COMMAND, files, args.board, args.square, pipeline, device, args.model,
                                                 args.detector)
        except UserError as err:
            raise type(err)(f"the camera could not be calibrated from the images ({err}); give --calibration") \
                from None
    corners, found, present, reasons = _views(one, len(files))
    size = tuple(int(x) for x in one.image_size)
    return corners, found, present, reasons, size, camera_record


def _views(one, count: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, list[str]]:
    """A camera's views from its pipeline result: corners (V, N, 2), found (V,), present (V,) and each view's reason."""
    det = one.detections
    present = one.present.bool().cpu()
    found = det.found.bool().cpu() & present
    reasons = [(det.reasons[v] if det.reasons else "") or ("board found" if bool(found[v]) else "board not found")
               for v in range(count)]
    return det.corners.double().cpu(), found, present, reasons


def _size_hint(result, args: argparse.Namespace) -> str:
    """Where the board's size disagrees with the robot's translations, the option and value that say the size the
    robot sees; else an empty string."""
    found = next((i for i in result.issues[0] if i.get("check") == "board_scale"), None)
    if found is None:
        return ""
    s = float(found["scale"])
    if getattr(args, "circle_board", None) is not None:
        return f": measure the dots' spacing, or give --spacing {args.spacing * s:.5g} (given {args.spacing:g})"
    if getattr(args, "apriltag", None) is not None:
        return f": measure the tag, or give --tag-size {args.tag_size * s:.5g} (given {args.tag_size:g})"
    if getattr(args, "aprilgrid_board", None) is not None:
        return f": measure the tags, or give a tagSize of {args.aprilgrid_board.tag_size * s:.5g} in the target YAML"
    if getattr(args, "charuco_board", None) is not None:
        return (f": measure the squares, or give --square {args.square * s:.5g} --marker {args.marker * s:.5g} "
                f"(given {args.square:g}, {args.marker:g})")
    return f": measure the squares, or give --square {args.square * s:.5g} (given {args.square:g})"


def _other_order(args: argparse.Namespace, files: list[str], poses, solve) -> str:
    """Where quaternions refused in one order are accepted in the other (scalar first or last), the line that says so
    and names the ``--pose-format`` that reads them; else an empty string."""
    other = {"quat": "quat-wxyz", "quat-wxyz": "quat"}.get(poses.format)
    if other is None:
        return ""
    T = match_poses(files, read_robot_poses(args.robot_poses, other, args.pose_units))[0]
    usable = torch.from_numpy(np.isfinite(T).all((-1, -2)))
    if not bool(solve(torch.from_numpy(T), usable, heldout=False).success[0]):
        return ""
    orders = {"quat": "qx,qy,qz,qw (scalar last)", "quat-wxyz": "qw,qx,qy,qz (scalar first)"}
    return (f"the quaternions of {os.path.basename(args.robot_poses)} are in the other order: read as "
            f"{orders[poses.format]} the robot and the images disagree, read as {orders[other]} they agree: give "
            f"--pose-format {other}")


def run(args: argparse.Namespace) -> int:
    setup = HandEyeSetup.EYE_IN_HAND if args.eye_in_hand else HandEyeSetup.EYE_TO_HAND
    require_circle_origin(args, "a hand-eye calibration")
    check_outputs(files=[("--output", args.output), ("--ros-tf", args.ros_tf), ("--moveit-yaml", args.moveit_yaml)],
                  dirs=[("--report", args.report)])
    frames = parse_frames(args.ros_frames)
    noise = parse_robot_noise(args.robot_noise)
    tag = getattr(args, "apriltag", None)
    if tag is not None:
        if args.tag_size is None:
            raise UserError("--apriltag needs --tag-size: the black square's side in metres (e.g. 0.048)")
        args.tag_target = AprilTagTarget(tag, args.tag_size, args.tag_id)
    elif args.tag_size is not None or args.tag_id is not None:
        raise UserError("--tag-size and --tag-id describe an --apriltag target")
    device = resolve_device(args.device)
    files = inputs(COMMAND, args.images)
    poses = read_robot_poses(args.robot_poses, args.pose_format, args.pose_units)
    T, missing, unused = match_poses(files, poses)
    source = os.path.basename(args.robot_poses)
    if len(missing) == len(files):
        raise UserError(f"no image has a pose in {args.robot_poses}: its rows name {', '.join(poses.names[:3])}"
                        f"{', ...' if len(poses.names) > 3 else ''}; the images are {os.path.basename(files[0])}, ... "
                        "(each row starts with its image's file name)")
    skipped: dict[str, str] = {}
    for path in missing:
        skipped[path] = f"no robot pose in {source}"
        warn(COMMAND, f"skipped {path}: no robot pose for it in {source}")
    for name in unused:
        warn(COMMAND, f"{source}: the pose of {name} matches no image (not used)")
    given = _camera(args)
    if tag is not None and given is None:
        raise UserError("--apriltag: a single tag cannot calibrate the camera; give --calibration calib.json (a "
                        "calibrate JSON; docs/hand_eye.md shows how to write one from ViSP or ROS intrinsics)")
    start = time.perf_counter()
    camera_record = None
    if tag is not None:
        corners, found, present, reasons, size = _detect_tag(files, args, device, given[0])
        obj = args.tag_target.object_points()
        board_info = {"kind": "apriltag", "family": tag, "tag_size": args.tag_size, "tag_id": args.tag_id,
                      "corners": "top left, top right, bottom left, bottom right of the black square as printed; "
                                 "origin at the tag's centre, x right, y down, z into the print"}
    else:
        corners, found, present, reasons, size, camera_record = _detect_board(files, args, device,
                                                                              None if given is None else given[0])
        obj = grid_object_points(getattr(args, "aprilgrid_board", None) or getattr(args, "circle_board", None),
                                 args.board, args.square)
        board_info = {"kind": getattr(args, "detector", "chessboard"), "board": list(args.board),
                      "square": args.square, "corners": "grid order n = row * cols + col; origin at corner 0"}
        board_info.update(board_records(args))
    if size is None:
        raise UserError(f"none of the {len(files)} input files could be read as an image")
    if given is not None:
        camera, camera_record = given
        if tuple(camera_record["image_size"]) != tuple(size):
            raise UserError(f"--calibration {args.calibration}: a calibration of {camera_record['image_size'][0]}x"
                            f"{camera_record['image_size'][1]} images, these are {size[0]}x{size[1]}")
    else:
        camera = camera_from_record(camera_record)
        camera_record = {k: camera_record[k] for k in ("image_size", "K", "distortion", "rms", "std") if k in
                         camera_record} | {"source": "calibrated from these images"}
    if not bool(found.any()):
        kind = "apriltag" if tag is not None else str(getattr(args, "detector", ""))
        what = (f"AprilTag {tag}" if tag is not None else None)
        message = (f"{what} not found in any of {len(files)} images" if what else
                   not_found_message(tuple(args.board), len(files), len(files), kind))
        raise UserError(message)
    for v, path in enumerate(files):
        if path not in skipped and not bool(found[v]):
            skipped[path] = reasons[v]
            if present[v]:  # (an unreadable file was said by the run)
                warn(COMMAND, f"skipped {path}: {reasons[v]}")
    ok = found & torch.from_numpy(np.isfinite(T).all((-1, -2)))
    info(f"{int(ok.sum())} of {len(files)} images have both a board and a robot pose")
    valid = corners.isfinite().all(-1) & ok[:, None]

    robot = torch.from_numpy(T)
    names = [os.path.basename(f) for f in files]

    def solve(robot: torch.Tensor, usable: torch.Tensor, heldout: bool = True):
        return calibrate_hand_eye(
            torch.nan_to_num(corners, nan=0.0)[None], valid[None] & usable[None, :, None], obj,
            torch.where(usable[:, None, None], robot, torch.full_like(robot, float("nan")))[None], camera, setup,
            free_intrinsics=bool(args.refine_intrinsics), robot_noise=noise, image_size=size, names=[names],
            align_orders=tag is None and board_info.get("kind") in ("learned", "opencv"), heldout=heldout,
            board_flatness=heldout and bool(getattr(args, "board_flatness", False)))

    result = solve(robot, ok)
    if not bool(result.success[0]):
        board_size_hint = _size_hint(result, args)
        order = "" if board_size_hint else _other_order(args, files, poses, solve)
        raise UserError(f"hand-eye calibration refused: {order or result.reasons[0] + board_size_hint}")

    if args.refine_intrinsics:
        refined = result.camera[0]
        camera_record = dict(camera_record, K=refined.K[0].tolist(),
                             distortion={"model": str(refined.model), "coeffs": refined.coeffs(0).tolist()},
                             refined_in_hand_eye_fit=True)
    board_info["outline"] = _outline(obj)
    data = hand_eye_record(result, files, 0, camera=camera_record, robot_poses=robot, corners=corners,
                           skipped=skipped, board=board_info)
    data["pose_file"] = {"path": args.robot_poses, "format": poses.format, "units": args.pose_units}
    data["device"] = str(device)
    data["timings"] = {"total_s": time.perf_counter() - start}
    _write_outputs(args, data, frames)
    for line in summary_lines(data, args.output):
        print(line)
    if args.report:
        print(f"report: {os.path.join(args.report, 'index.html')}")
    return 0


def _outline(obj) -> list[list[float]]:
    """The board's outline (its extreme corners, in order around it) in board coordinates."""
    xy = obj[:, :2]
    lo, hi = xy.min(0).values, xy.max(0).values
    return [[float(lo[0]), float(lo[1]), 0.0], [float(hi[0]), float(lo[1]), 0.0], [float(hi[0]), float(hi[1]), 0.0],
            [float(lo[0]), float(hi[1]), 0.0]] if bool(torch.isfinite(xy).all()) else []


def _write_outputs(args: argparse.Namespace, data: dict[str, Any], frames: tuple[str, str, str]) -> None:
    """Every requested file, prepared first, then written through temporary files renamed into place."""
    texts = {}
    if args.ros_tf:
        texts[("--ros-tf", args.ros_tf)] = ros_static_transform(data, frames)
    if args.moveit_yaml:
        texts[("--moveit-yaml", args.moveit_yaml)] = moveit_calibration_yaml(data, frames)
    if args.report:
        make_dir("--report", args.report)
        start = time.perf_counter()
        write_hand_eye_report(args.report, data)
        data["timings"]["report_s"] = time.perf_counter() - start
    try:
        write_json(args.output, data, mode=0o644)
    except OSError as err:
        raise UserError(f"--output {args.output}: cannot write ({err.strerror or err})") from None
    for (option, path), text in texts.items():
        write_text_atomic(option, path, text)


def summary_lines(data: dict[str, Any], output: str) -> list[str]:
    """The command's short summary: X with its 1-sigma, the held-out prediction error, the verdict."""
    t, q = data["X_tq"]["t"], data["X_tq"]["q"]
    std = data["X_std"]
    held = data["heldout"]
    what = "flange -> camera" if data["setup"] == "eye-in-hand" else "base -> camera"
    lines = [f"X ({data['setup']}, {what}): t = ({t[0]:.5f}, {t[1]:.5f}, {t[2]:.5f}) m, q = ({q[0]:.5f}, {q[1]:.5f}, "
             f"{q[2]:.5f}, {q[3]:.5f}); 1-sigma {std['translation_mm_norm']:.3g} mm, {std['rotation_deg_norm']:.3g} deg",
             f"fit RMS {data['rms_px']:.3f} px over {data['num_poses']['used']} poses (started from "
             f"{data['start']['method']}); wrote {output}"]
    if held["rms_px"] is not None:
        lines.append(f"held-out poses predicted from the robot alone: {held['rms_px']:.3f} px, {held['rms_mm']:.3f} mm "
                     f"RMS ({held['poses']} poses)")
    if data.get("robot_noise") and data["robot_noise"].get("corner_px") is None:  # a model chosen by held-out poses
        lines.append(f"robot poses: {data['robot_noise']['note']}")
    elif data.get("robot_noise"):
        rn = data["robot_noise"]
        corner = f" (corners {rn['corner_px']:.3g} px)" if rn.get("corner_px") is not None else ""
        lines.append(f"robot poses' noise: {rn['translation_mm']:.3g} mm, {rn['rotation_deg']:.3g} deg{corner}")
    flatness = data.get("board_flatness")
    if flatness and flatness.get("warp_m") and None not in flatness["warp_m"] + flatness["std_m"]:
        held = flatness["heldout_rms_px"]
        what = "kept" if flatness["kept"] else "not kept: the board taken as flat"
        judged = f" (held-out poses {held['flat']:.3f} px flat, {held['warp']:.3f} px bent)" \
            if None not in (held["flat"], held["warp"]) else ""
        lines.append(f"board: bent by {1000 * flatness['warp_m'][0]:+.3f} / {1000 * flatness['warp_m'][1]:+.3f} mm "
                     f"(1-sigma {1000 * flatness['std_m'][0]:.3f} / {1000 * flatness['std_m'][1]:.3f}), {what}{judged}")
    lines.append(f"verdict: {data['verdict']}")
    return lines
