"""``ccs_kornia calibrate-rig``: a rig of cameras (a stereo head, a robot's cameras) from one folder of board images
per camera; writes ``rig.json`` and, on request, OpenCV, ROS and Kalibr files and a report.

Every output is written at the end, once the rig is solved: a run that stops on bad input writes nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

from ccs_kornia.commands._common import (
    UserError,
    aprilgrid_record,
    charuco_record,
    check_output_file,
    info,
    inputs,
    make_detector_from,
    missing_weights,
    pipeline_options,
    resolve_device,
    warn,
)

__all__ = ["COMMAND", "parse_models", "parse_names", "parse_fixed", "check_output_dir", "run", "summary_lines"]

COMMAND = "calibrate-rig"


def parse_models(text: str, cameras: int, choices: tuple[str, ...]) -> list[str]:
    """``--model``: one model for every camera or one per camera, comma-separated.

    Example:
        >>> parse_models("auto", 2, ("auto", "k1k2")), parse_models("k1k2,auto", 2, ("auto", "k1k2"))
        (['auto', 'auto'], ['k1k2', 'auto'])
    """
    models = [m.strip() for m in text.split(",")]
    bad = [m for m in models if m not in choices]
    if bad:
        raise UserError(f"--model {text}: unknown model {bad[0]!r} (choose from {', '.join(choices)})")
    if len(models) == 1:
        return models * cameras
    if len(models) != cameras:
        raise UserError(f"--model {text}: {len(models)} models for {cameras} cameras (give one, or one per camera)")
    return models


def parse_names(text: str | None, cameras: int) -> list[str]:
    """``--names``: one name per camera (default ``cam0``, ``cam1``, ...); names are used in file names.

    Example:
        >>> parse_names("left,right", 2), parse_names(None, 3)
        (['left', 'right'], ['cam0', 'cam1', 'cam2'])
    """
    if text is None:
        return [f"cam{c}" for c in range(cameras)]
    names = [n.strip() for n in text.split(",")]
    if len(names) != cameras:
        raise UserError(f"--names {text}: {len(names)} names for {cameras} camera folders")
    if any(not n or "/" in n or os.sep in n or n in (".", "..") for n in names) or len(set(names)) != len(names):
        raise UserError(f"--names {text}: names must be distinct, non-empty and without '/'")
    return names


def parse_fixed(items: list[str] | None, cameras: int) -> dict[int, Any]:
    """``--fix-intrinsics CAM_INDEX=calib.json``: cameras whose intrinsics are kept as a ``calibrate`` JSON gives
    them; returns ``{index: (RigCamera, image_size, path)}``."""
    import torch

    from ccs_kornia.modules.rig import RigCamera

    fixed: dict[int, Any] = {}
    for item in items or []:
        index, sep, path = item.partition("=")
        if not sep or not index.strip().isdigit():
            raise UserError(f"--fix-intrinsics {item}: expected CAM_INDEX=calib.json, e.g. 0=left.json")
        c = int(index)
        if c >= cameras:
            raise UserError(f"--fix-intrinsics {item}: camera index {c} out of range (0..{cameras - 1})")
        try:
            with open(path, encoding="utf-8") as handle:
                data = json.load(handle)
            K = torch.tensor(data["K"], dtype=torch.float64)
            model = data["distortion"]["model"]
            dist = torch.tensor(data["distortion"]["coeffs"] or [], dtype=torch.float64)
            size = (int(data["image_size"][0]), int(data["image_size"][1]))
        except OSError as err:
            raise UserError(f"--fix-intrinsics {item}: cannot read {path} ({err.strerror or err})") from None
        except (ValueError, KeyError, TypeError, IndexError):
            raise UserError(f"--fix-intrinsics {item}: {path} is not a calibration written by calibrate "
                            "(needs K, distortion and image_size)") from None
        if K.shape != (3, 3):
            raise UserError(f"--fix-intrinsics {item}: K in {path} is not 3x3")
        fixed[c] = (RigCamera(model, K, dist), size, path)
    return fixed


def check_output_dir(option: str, path: str) -> None:
    """An output directory that exists, or can be created later (its parent exists and is writable)."""
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise UserError(f"{option} {path} exists and is not a directory")
        if not os.access(path, os.W_OK):
            raise UserError(f"{option} {path}: directory is not writable")
        return
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent) or not os.access(parent, os.W_OK):
        raise UserError(f"{option} {path}: parent directory {parent} does not exist or is not writable")


def _camera_files(name: str, item: str) -> list[str]:
    try:
        return inputs(COMMAND, [item])
    except UserError as err:
        raise UserError(f"camera {name} ({item}): {err}") from None


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ccs_kornia.commands.calibrate import failure_message
    from ccs_kornia.outputs.records import camera_record
    from ccs_kornia.outputs.rig_records import rig_record
    from ccs_kornia.pipeline.frame_matching import match_frames
    from ccs_kornia.pipeline.rig_pipeline import RigPipeline
    from ccs_kornia.pipeline.sources import FileSource

    folders = args.cameras
    if len(folders) < 2:
        raise UserError(f"a rig needs at least two camera folders (one folder of images per camera), got "
                        f"{len(folders)}: {' '.join(folders)}")
    check_output_file("--output", args.output)
    for option, path in (("--opencv-yaml", args.opencv_yaml), ("--kalibr-yaml", args.kalibr_yaml)):
        if path:
            check_output_file(option, path)
    for option, path in (("--ros-yaml-dir", args.ros_yaml_dir), ("--report", args.report)):
        if path:
            check_output_dir(option, path)
    c = len(folders)
    names = parse_names(args.names, c)
    models = parse_models(args.model, c, args.model_choices)
    fixed = parse_fixed(args.fix_intrinsics, c)
    if args.kalibr_yaml and "rational" in models:
        raise UserError(f"--kalibr-yaml: Kalibr has no rational (k1..k6) model, asked for camera "
                        f"{names[models.index('rational')]}; use --model opencv5, k1k2 or fisheye")
    device = resolve_device(args.device)
    files = [_camera_files(names[k], folder) for k, folder in enumerate(folders)]
    frames = match_frames(files)
    for k in range(c):
        missing = frames.missing(k)
        if missing:
            info(f"camera {names[k]} has no view of frame{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                 f"({frames.num_frames - len(missing)} of {frames.num_frames} frames)")
    detector = make_detector_from(args)
    try:
        pipeline = RigPipeline(detector, models=models, fixed={k: v[0] for k, v in fixed.items()},
                               **pipeline_options(args, args.use_ransac, args.seed))
    except FileNotFoundError as err:
        raise missing_weights(err) from None
    pipeline.to(device)
    source = FileSource(files, names)
    start = time.perf_counter()
    total = sum(source.counts)
    with tqdm(total=total, unit="img", desc=COMMAND, file=sys.stderr, disable=None, leave=False) as bar:
        def advance(views: int) -> None:
            bar.update(views)
            if bar.n >= total:
                bar.set_description_str(f"{COMMAND}: calibrating each camera")

        cameras = pipeline.detect_and_calibrate(source, args.board, args.square, progress=advance)
        _check_cameras(cameras, files, folders, names, fixed, args, failure_message, camera_record)
        bar.set_description_str(f"{COMMAND}: solving the rig")
        out = pipeline.run(source, args.board, args.square, frames, names, cameras=cameras)
    if not out.success:
        raise UserError(out.reason)
    data = rig_record(out, files, board=args.board, square=args.square, detector=args.detector, models=models)
    for key, record in (("charuco", charuco_record(args)), ("aprilgrid", aprilgrid_record(args))):
        if record:
            data[key] = record
    data["device"] = str(device)
    data["timings"] = {"total_s": time.perf_counter() - start}
    _write_outputs(args, data, names)
    for line in summary_lines(data, args.output):
        print(line)
    return 0


def _check_cameras(cameras, files, folders, names, fixed, args, failure_message, camera_record) -> None:
    """Warnings per unusable view, and one error line naming the first camera without a calibration."""
    for k, result in enumerate(cameras):
        v = len(files[k])
        for i, path in enumerate(files[k]):
            if not bool(result.present[i]):
                warn(COMMAND, f"camera {names[k]}: skipped {path}: {result.detections.reasons[i]}")
        record = camera_record(result, files[k], board=args.board, square=args.square, detector=args.detector,
                               model=args.model)
        for issue in record.get("warnings", []):
            warn(COMMAND, f"camera {names[k]}: {issue.get('message', issue)}")
        readable = int(result.present[:v].sum())
        if k in fixed:
            size = tuple(int(x) for x in result.image_size)
            if record["num_views"]["found"] == 0:
                raise UserError(f"camera {names[k]} ({folders[k]}): {failure_message(record, args.board, readable)}")
            if size != fixed[k][1]:
                raise UserError(f"--fix-intrinsics {k}={fixed[k][2]}: calibration of {fixed[k][1][0]}x{fixed[k][1][1]} "
                                f"images, camera {names[k]}'s are {size[0]}x{size[1]}")
        elif not record["success"]:
            raise UserError(f"camera {names[k]} ({folders[k]}): {failure_message(record, args.board, readable)}")


def _write_outputs(args: argparse.Namespace, data: dict[str, Any], names: list[str]) -> None:
    """Every requested file, prepared first (a format that cannot hold the rig stops the run before any is
    written), then written through temporary files renamed into place."""
    from ccs_kornia.io.files import write_json, write_text_atomic
    from ccs_kornia.outputs.rig_exports import (
        kalibr_camchain,
        kalibr_problem,
        rectification,
        ros_stereo_files,
        write_opencv_stereo_yaml,
    )
    rect = rectification(data, 0, 1) if (args.opencv_yaml or args.ros_yaml_dir or args.report) else None
    ros = ros_stereo_files(data, rect, (names[0], names[1]) if args.names else ("left", "right")) \
        if args.ros_yaml_dir else {}
    camchain = None
    if args.kalibr_yaml:
        problem = kalibr_problem(data)
        if problem:
            raise UserError(problem)
        camchain, notes = kalibr_camchain(data)
        for note in notes:
            warn(COMMAND, f"--kalibr-yaml: {note}")
    if len(data["cameras"]) > 2 and (args.opencv_yaml or args.ros_yaml_dir):
        info(f"--opencv-yaml / --ros-yaml-dir hold the pair {names[0]}-{names[1]} (cameras 0 and 1)")
    if args.report:
        from ccs_kornia.outputs.report.rig import write_rig_report

        start = time.perf_counter()
        os.makedirs(args.report, exist_ok=True)
        write_rig_report(args.report, data, rect)
        data["timings"]["report_s"] = time.perf_counter() - start
    try:
        write_json(args.output, data, mode=0o644)
    except OSError as err:
        raise UserError(f"--output {args.output}: cannot write ({err.strerror or err})") from None
    if args.opencv_yaml:
        write_opencv_stereo_yaml(args.opencv_yaml, data, rect)
    if ros:
        os.makedirs(args.ros_yaml_dir, exist_ok=True)
        for name, text in ros.items():
            write_text_atomic("--ros-yaml-dir", os.path.join(args.ros_yaml_dir, name), text)
    if camchain is not None:
        write_text_atomic("--kalibr-yaml", args.kalibr_yaml, camchain)


def _moved(cam: dict[str, Any]) -> str:
    """``, moved up to 2.1 sigma (cy) from its own calibration`` for a camera's summary line ("" when unknown)."""
    moved = cam.get("intrinsics_moved_sigma")
    if not moved:
        return ""
    items = [(k, moved[k]) for k in ("fx", "fy", "cx", "cy")] + [(f"d{i}", v) for i, v in enumerate(moved["distortion"])]
    name, value = max(((k, abs(v)) for k, v in items if v is not None), key=lambda kv: kv[1], default=(None, 0.0))
    return f", moved up to {value:.1f} sigma ({name}) from its own calibration" if name else ""


def summary_lines(data: dict[str, Any], output: str) -> list[str]:
    """The command's short summary: per camera its model, RMS and how far the joint fit moved its intrinsics, the
    frames whose cameras disagree, what to record next, per pair baseline, rotation and epipolar error, the
    verdict."""

    from ccs_kornia.outputs.rig_records import frame_lines

    def fmt(value: float | None, digits: int = 3) -> str:
        return "n/a" if value is None else f"{value:.{digits}f}"

    lines = []
    for cam in data["cameras"]:
        K = cam["K"]
        used = sum(1 for v in cam["views"] if v.get("used"))
        lines.append(f"camera {cam['name']}: {cam['distortion']['model']}, RMS {fmt(cam['rms'])} px "
                     f"(fx {K[0][0]:.2f} fy {K[1][1]:.2f} cx {K[0][2]:.2f} cy {K[1][2]:.2f}; {used} views"
                     f"{', intrinsics fixed' if cam.get('fixed') else _moved(cam)})")
    lines += frame_lines((data.get("frame_consistency") or {}).get("frames") or [])
    lines += [f"to record next: {text}" for text in data.get("session_advice") or []]
    for pair in data["pairs"]:
        std = f" ± {pair['baseline_std']:.2g}" if pair.get("baseline_std") is not None else ""
        rot = f" ± {pair['rotation_std_deg']:.2g}" if pair.get("rotation_std_deg") is not None else ""
        held = f", held-out {fmt(pair['heldout_epipolar_rms'])} px" if pair.get("heldout_epipolar_rms") is not None \
            else ""
        lines.append(f"pair {pair['names'][0]}-{pair['names'][1]}: baseline {pair['baseline']:.5g}{std} (the "
                     f"board's unit), rotation {pair['rotation_deg']:.3f}{rot} deg, epipolar RMS "
                     f"{fmt(pair['epipolar_rms'])} px{held}")
    lines.append(f"rig RMS {fmt(data['rms'])} px over {len(data['frame_labels'])} frames; wrote {output}")
    lines.append(f"verdict: {data['verdict']}")
    return lines
