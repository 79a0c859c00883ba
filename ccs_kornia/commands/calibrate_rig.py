"""``ccs_kornia calibrate-rig``: a rig of cameras (a stereo head, a robot's cameras) from one folder of board images
per camera; writes ``rig.json`` and, on request, OpenCV, ROS and Kalibr files and a report.

Every output is written at the end, once the rig is solved: a run that stops on bad input writes nothing.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from typing import Any

import cv2
from tqdm import tqdm

from ccs_kornia.commands._boards import board_records, require_circle_origin
from ccs_kornia.commands._corners import corners_source, report_note
from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import (
    make_detector_from,
    missing_weights,
    pipeline_options,
)
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._messages import failure_message, weak_lines
from ccs_kornia.commands._models import parse_models
from ccs_kornia.commands._output_paths import (
    check_outputs,
    make_dir,
)
from ccs_kornia.commands._printing import info, warn
from ccs_kornia.commands._selection import frame_selection, save_frames, selection_line
from ccs_kornia.commands._stereo_pair import parse_pair
from ccs_kornia.commands._video import (
    add_timestamps,
    bag_recordings,
    pairing_lines,
    rig_videos,
    still_gate_cause,
)
from ccs_kornia.commands._wrong_board import WrongBoardWatch
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import camera_model
from ccs_kornia.io.files import write_json, write_text_atomic
from ccs_kornia.io.images import image_pixels
from ccs_kornia.modules.calibration.model_selection import AUTO_MODELS, ModelChoice
from ccs_kornia.outputs.calibration_file import RigFileError, read_calibration
from ccs_kornia.outputs.records import camera_record
from ccs_kornia.outputs.report.rig import write_rig_report
from ccs_kornia.outputs.rig_exports import (
    KALIBR_DISTORTION,
    kalibr_camchain,
    kalibr_problem,
    rectification,
    ros_stereo_files,
    write_opencv_stereo_yaml,
)
from ccs_kornia.outputs.rig_records import frame_lines, rig_record
from ccs_kornia.pipeline.corners_input import match_given_views
from ccs_kornia.pipeline.frame_matching import match_frames
from ccs_kornia.pipeline.rig_pipeline import RigPipeline
from ccs_kornia.pipeline.sources import FileSource
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["COMMAND", "parse_names", "parse_fixed", "run", "summary_lines"]

COMMAND = "calibrate-rig"


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
        raise UserError(f"--names {text}: {len(names)} name{'s' if len(names) != 1 else ''} for {cameras} camera "
                        "folders")
    if any(not n or "/" in n or os.sep in n or n in (".", "..") for n in names) or len(set(names)) != len(names):
        raise UserError(f"--names {text}: names must be distinct, non-empty and without '/'")
    return names


def parse_fixed(items: list[str] | None, cameras: int) -> dict[int, Any]:
    """``--fix-intrinsics CAM_INDEX=calib.json``: cameras whose intrinsics are kept as a ``calibrate`` JSON gives
    them; returns ``{index: (camera, image_size, path)}``."""
    fixed: dict[int, Any] = {}
    for item in items or []:
        index, sep, path = item.partition("=")
        if not sep or not index.strip().isdigit():
            raise UserError(f"--fix-intrinsics {item}: expected CAM_INDEX=calib.json, e.g. 0=left.json")
        c = int(index)
        if c >= cameras:
            raise UserError(f"--fix-intrinsics {item}: camera index {c} out of range (0..{cameras - 1})")
        try:  # a failed calibration, a rig file, a file that is no calibration: each said as such
            calib = read_calibration(path)
        except RigFileError as err:  # (a camera of an earlier rig: its own calibration is in the rig's "cameras")
            raise UserError(f"--fix-intrinsics {item}: {path}: {err}; give a calibration written by calibrate") \
                from None
        except ValueError as err:
            why = f"{path}: {err}" if os.path.exists(path) else f"cannot read {path} (no such file)"
            raise UserError(f"--fix-intrinsics {item}: {why}") from None
        fixed[c] = (calib.camera, calib.camera.image_size, path)
    return fixed


def _camera_files(name: str, item: str) -> list[str]:
    """The camera's image files, refused at once (before any frame is matched or any image detected) when none of
    them is an image: their headers tell, without decoding them."""
    try:
        files = inputs(COMMAND, [item])
    except UserError as err:
        raise UserError(f"camera {name} ({item}): {err}") from None
    if not any(image_pixels(f) is not None or (os.access(f, os.R_OK) and cv2.haveImageReader(f)) for f in files):
        raise UserError(f"camera {name} ({item}): none of the {len(files)} files is an image (unknown format or "
                        f"corrupt, e.g. {os.path.basename(files[0])})")
    return files


def _file_digest(path: str) -> str:
    with open(path, "rb") as handle:
        return hashlib.sha1(handle.read()).hexdigest()


def _check_distinct(files: list[list[str]], names: list[str], folders: list[str]) -> None:
    """Refuse two cameras given the same images (the same folder twice, or a copy of it): the rig would be solved
    with a baseline of zero and a verdict that says nothing of it."""

    def sizes(paths: list[str]) -> list[int]:
        return sorted(os.path.getsize(p) for p in paths)

    for a in range(len(files)):
        for b in range(a + 1, len(files)):
            same = {os.path.realpath(p) for p in files[a]} == {os.path.realpath(p) for p in files[b]}
            if not same and sizes(files[a]) == sizes(files[b]):  # the same sizes: compare the contents
                same = sorted(map(_file_digest, files[a])) == sorted(map(_file_digest, files[b]))
            if same:
                raise UserError(f"cameras {names[a]} and {names[b]} ({folders[a]}, {folders[b]}) hold the same images: "
                                "a rig needs one folder of images per camera")


def _check_distinct_videos(names: list[str], videos: list[str]) -> None:
    """Refuse two cameras given the same video file."""
    seen: dict[str, int] = {}
    for k, path in enumerate(videos):
        real = os.path.realpath(path)
        if real in seen:
            raise UserError(f"cameras {names[seen[real]]} and {names[k]} are the same video ({path}): a rig needs one "
                            "video per camera")
        seen[real] = k


def run(args: argparse.Namespace) -> int:
    require_circle_origin(args, "a rig")
    if args.cameras and args.corners:
        raise UserError(f"give either camera folders or --corners, not both: {args.cameras[0]} and --corners "
                        f"{args.corners[0]}")
    folders = args.cameras or args.corners or bag_recordings(args, one_camera=False)
    if len(folders) < 2:
        what = "--corners files (one per camera)" if args.corners else "--image-topics (one per camera)" if args.bag \
            else "camera folders or videos (one folder of images, or one video, per camera)"
        raise UserError(f"a rig needs at least two {what}, got {len(folders)}{': ' if folders else ''}"
                        f"{' '.join(folders)}")
    check_outputs(files=[("--output", args.output), ("--opencv-yaml", args.opencv_yaml),
                         ("--kalibr-yaml", args.kalibr_yaml)],
                  dirs=[("--ros-yaml-dir", args.ros_yaml_dir), ("--report", args.report),
                        ("--save-frames", args.save_frames)])
    c = len(folders)
    names = parse_names(args.names, c)
    models = parse_models(args.model, c, args.model_choices)
    fixed = parse_fixed(args.fix_intrinsics, c)
    pair = _stereo_pair(args, c)
    if args.kalibr_yaml:
        unheld = [k for k, m in enumerate(models) if isinstance(m, CameraModel) and m not in KALIBR_DISTORTION]
        if unheld:
            raise UserError(f"--kalibr-yaml: Kalibr has no {models[unheld[0]]} model, asked for camera "
                            f"{names[unheld[0]]}; use --model opencv5, k1k2 or fisheye")
    options = pipeline_options(args, args.use_ransac, args.seed)
    if args.kalibr_yaml and any(isinstance(m, ModelChoice) for m in models):
        # a camera that auto gave rational would stop the run at the end, after all the work, with no camchain:
        # this run chooses among the models Kalibr holds instead
        held = ModelChoice(tuple(m for m in AUTO_MODELS if m in KALIBR_DISTORTION))
        models = [held if isinstance(m, ModelChoice) else m for m in models]
        info(f"--kalibr-yaml: Kalibr has no rational model, so --model auto chooses among "
             f"{', '.join(map(str, held.candidates))} in this run")
    selection = frame_selection(args)
    if args.save_frames and selection is None:
        raise UserError("--save-frames writes the frames the frame selection kept: give --select (recordings and "
                        "image folders alike are selected on request only), or leave out --no-select")
    given = corners_source(args, args.cameras, names)
    device = resolve_device(args.device)
    start = time.perf_counter()
    video = rig_videos(COMMAND, args, names) if given is None else None
    if given is not None:
        files = [[given.describe(k, v) for v in range(given.counts[k])] for k in range(c)]
        try:
            frames = match_given_views(given, args.sync_tolerance)
        except ValueError as err:
            raise UserError(str(err)) from None
        for line in pairing_lines(frames, names) if frames.by == "time" else ():
            info(line)
    elif video is None:
        files = [_camera_files(names[k], folder) for k, folder in enumerate(folders)]
        frames = match_frames(files)
        for k in range(c):
            missing = frames.missing(k)
            if missing:
                info(f"camera {names[k]} has no view of frame{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                     f"({frames.num_frames - len(missing)} of {frames.num_frames} frames)")
        _check_distinct(files, names, folders)
    else:
        files, frames = video.names(), video.table
        _check_distinct_videos(names, folders)
    detector = make_detector_from(args)
    try:
        pipeline = RigPipeline(detector, models=models, fixed={k: v[0] for k, v in fixed.items()},
                               frame_selection=selection, **options)
    except FileNotFoundError as err:
        raise missing_weights(err) from None
    pipeline.to(device)
    source = given if given is not None else FileSource(files, names) if video is None else video.source(names)
    total = sum(source.counts)
    with tqdm(total=total, unit="img", desc=COMMAND, file=sys.stderr, disable=None, leave=False) as bar:
        def advance(views: int) -> None:
            bar.update(views)
            if bar.n >= total:
                bar.set_description_str(f"{COMMAND}: calibrating each camera")

        # a camera without the board is bad input here (exit status 2), as when the whole run finds none
        watch = WrongBoardWatch(files, args.board, names, error=UserError) if args.detector in ("learned", "opencv") \
            else None
        cameras = pipeline.detect_and_calibrate(source, args.board, args.square, progress=advance, on_batch=watch)
        _check_cameras(cameras, files, folders, names, fixed, models, args, video)
        bar.set_description_str(f"{COMMAND}: solving the rig")
        out = pipeline.run(source, args.board, args.square, frames, names, cameras=cameras)
    if not out.success:
        raise UserError(out.reason)
    data = rig_record(out, files, board=args.board, square=args.square, detector=args.detector, models=models)
    data.update(board_records(args))
    if video is not None:
        for c_, cam in enumerate(data["cameras"]):
            add_timestamps(cam["views"], video.timestamps())
            cam["video"] = video.records(c_)
        data["frame_times"] = frames.times
        data["frame_spread_s"] = frames.spread()
    if given is not None:
        for c_, cam in enumerate(data["cameras"]):
            add_timestamps(cam["views"], {name: given.timestamp(c_, v) for v, name in enumerate(files[c_])})
        data["corners_files"] = list(folders)
        if frames.times is not None:
            data["frame_times"] = frames.times
            data["frame_spread_s"] = frames.spread()
    if args.save_frames:
        kept, stems = _used_views(out, files)
        data["saved_frames"] = {"folder": args.save_frames,
                                "files": save_frames(args.save_frames, source, kept, names, stems)}
    data["device"] = str(device)
    data["timings"] = {"total_s": time.perf_counter() - start}
    weak = _weak_cameras(data) if args.allow_weak else []
    if args.report and given is not None:
        report_note([v for cam in data["cameras"] for v in cam["views"]])
    _write_outputs(args, data, names, pair)
    if data.get("selection"):
        print(selection_line(data["selection"]))
    if args.save_frames:
        print(f"wrote the {data['saved_frames']['files']} frames used to {args.save_frames} (one folder per camera)")
    for line in summary_lines(data, args.output):
        if line.startswith("verdict:"):
            for name, lines in weak:  # what --allow-weak let through, before the verdict it makes
                print(f"camera {name}: {lines[-1]}")
        print(line)
    for name, lines in weak:
        for text in lines[:-1]:
            warn(COMMAND, f"camera {name}: {text}")
    return 0


def _used_views(out, files: list[list[str]]) -> tuple[list[list[bool]], list[list[str]]]:
    """Per camera, per view, whether the rig's joint fit used it, and a file stem per view naming its frame (the same
    number in every camera: the folders pair again by it)."""
    used = out.rig.used.cpu()
    kept = [[False] * len(f) for f in files]
    stems = [[""] * len(f) for f in files]
    width = len(str(max(1, out.frames.num_frames)))
    for c, row in enumerate(out.frames.index):
        for f, k in enumerate(row):
            if k is not None and k < len(files[c]):
                kept[c][k] = bool(used[c, f])
                stems[c][k] = f"frame_{f:0{width}d}"
    return kept, stems


def _weak_cameras(data: dict[str, Any]) -> list[tuple[str, list[str]]]:
    """``--allow-weak``: the cameras kept although their own checks would have refused them, each with
    :func:`weak_lines`; the rig's verdict then says ``not reliable`` and why (the joint fit's figures, which alone
    make the rig verdict, do not see a camera its own views determine weakly)."""
    weak = [(cam["name"], cam["errors"]) for cam in data["cameras"] if cam.get("errors")]
    if weak:
        data["allow_weak"] = True
        data["verdict"] = "not reliable: " + "; ".join(dict.fromkeys(f"{name}: {e['advice']}" for name, errors in weak
                                                                     for e in errors))
        data["verdict_reasons"] = [f"{name}: {e['message']}" for name, errors in weak for e in errors] + \
            list(data.get("verdict_reasons") or [])
    return [(cam["name"], weak_lines(cam)) for cam in data["cameras"] if cam.get("errors")]


def _check_cameras(cameras, files, folders, names, fixed, models, args, video=None) -> None:
    """Warnings per unusable view, and one error line naming the first camera without a calibration (a recording's
    still gate first where it left that camera's boards nearly parallel)."""
    for k, result in enumerate(cameras):
        v = len(files[k])
        for i, path in enumerate(files[k]):
            if not bool(result.present[i]):
                warn(COMMAND, f"camera {names[k]}: skipped {path}: {result.detections.reasons[i]}")
        record = camera_record(result, files[k], board=args.board, square=args.square, detector=args.detector,
                               model=models[k])
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
            if v == 0:  # a recording whose frames were all left out by the frame choice
                raise NoResult(f"camera {names[k]} ({folders[k]}): no frame of its recording was chosen for the "
                               "detector (the frame choice above says why)")
            # images were read: too few views is a run without a result (exit 3), an unreadable set a usage error
            error = NoResult if readable else UserError
            parallel = any(e.get("check") == "pose_diversity" for e in record.get("errors", []))
            cause = still_gate_cause(video, args, k) if video is not None and parallel else ""
            raise error(f"camera {names[k]} ({folders[k]}): {cause + '; ' if cause else ''}"
                        f"{failure_message(record, args.board, readable)}")


def _stereo_pair(args: argparse.Namespace, cameras: int) -> tuple[int, int]:
    """The pair of ``--pair`` (default 0, 1), which a rig of more than two cameras must name for the stereo files:
    cameras 0 and 1 need not see one scene side by side."""
    if args.pair is None:
        stereo = [o for o, v in (("--opencv-yaml", args.opencv_yaml), ("--ros-yaml-dir", args.ros_yaml_dir)) if v]
        if cameras > 2 and stereo:
            raise UserError(f"{stereo[0]} holds one pair of the {cameras} cameras: give --pair I,J (the cameras of "
                            "the stereo pair, e.g. 0,1)")
        return 0, 1
    return parse_pair(args.pair, cameras)


def _write_outputs(args: argparse.Namespace, data: dict[str, Any], names: list[str], pair: tuple[int, int]) -> None:
    """Every requested file, prepared first (a format that cannot hold the rig stops the run before any is
    written), then written through temporary files renamed into place; the stereo files and the report's rectified
    pair hold the cameras ``pair``."""
    i, j = pair
    stereo = args.opencv_yaml or args.ros_yaml_dir
    if stereo or args.report:
        angle = next(p["rotation_deg"] for p in data["pairs"] if p["cameras"] == sorted(pair))
        if angle > 90.0:
            warn(COMMAND, f"cameras {names[i]} and {names[j]} are turned {angle:.0f} degrees from each other: they do "
                          "not see one scene side by side, and their rectified pair is no stereo pair (--pair chooses "
                          "another)")
    rect = rectification(data, i, j) if (stereo or args.report) else None
    ros = ros_stereo_files(data, rect, (names[i], names[j]), i, j) if args.ros_yaml_dir else {}
    camchain = None
    if args.kalibr_yaml:
        problem = kalibr_problem(data)
        if problem:
            raise UserError(problem)
        camchain, notes = kalibr_camchain(data)
        for note in notes:
            warn(COMMAND, f"--kalibr-yaml: {note}")
    if len(data["cameras"]) > 2 and stereo:
        info(f"--opencv-yaml / --ros-yaml-dir hold the pair {names[i]}-{names[j]} (cameras {i} and {j})")
    for option, path in (("--report", args.report), ("--ros-yaml-dir", args.ros_yaml_dir if ros else None)):
        if path:  # the folders first: a folder that cannot be made stops the run before any file is written
            make_dir(option, path)
    if args.report:
        start = time.perf_counter()
        write_rig_report(args.report, data, rect, pair)
        data["timings"]["report_s"] = time.perf_counter() - start
    try:
        write_json(args.output, data, mode=0o644)
    except OSError as err:
        raise UserError(f"--output {args.output}: cannot write ({err.strerror or err})") from None
    if args.opencv_yaml:
        write_opencv_stereo_yaml(args.opencv_yaml, data, rect, i, j)
    if ros:
        for name, text in ros.items():
            write_text_atomic("--ros-yaml-dir", os.path.join(args.ros_yaml_dir, name), text)
    if camchain is not None:
        write_text_atomic("--kalibr-yaml", args.kalibr_yaml, camchain)


def _moved(cam: dict[str, Any]) -> str:
    """``, moved up to 2.1 sigma (cy) from its own calibration`` for a camera's summary line ("" when unknown)."""
    moved = cam.get("intrinsics_moved_sigma")
    if not moved:
        return ""

    coeffs = camera_model(cam["distortion"]["model"]).param_names[4:]
    items = [(k, moved[k]) for k in ("fx", "fy", "cx", "cy")] + list(zip(coeffs, moved["distortion"]))
    name, value = max(((k, abs(v)) for k, v in items if v is not None), key=lambda kv: kv[1], default=(None, 0.0))
    return f", moved up to {value:.1f} sigma ({name}) from its own calibration" if name else ""


def summary_lines(data: dict[str, Any], output: str) -> list[str]:
    """The command's short summary: per camera its model, RMS and how far the joint fit moved its intrinsics, the
    frames whose cameras disagree, what to record next, per pair baseline, rotation and epipolar error, a joint fit
    that did not converge, the verdict."""

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
    flatness = data.get("board_flatness")
    if flatness and flatness.get("warp_m") and None not in flatness["warp_m"] + flatness["std_m"]:
        held = flatness["heldout_epipolar_px"]
        what = "kept" if flatness["kept"] else "not kept: the board taken as flat"
        lines.append(f"board: bent by {1000 * flatness['warp_m'][0]:+.3f} / {1000 * flatness['warp_m'][1]:+.3f} mm "
                     f"(1-sigma {1000 * flatness['std_m'][0]:.3f} / {1000 * flatness['std_m'][1]:.3f}), {what} "
                     f"(held-out epipolar {fmt(held['flat'])} px flat, {fmt(held['warp'])} px bent)")
    fit = data.get("fit") or {}
    if fit.get("converged") is False:
        lines.append(f"warning: the joint fit did not converge in {fit.get('iterations')} iterations (it stopped at "
                     "its limit before its tolerance was met): the figures above are those of where it stopped")
    lines.append(f"verdict: {data['verdict']}")
    return lines
