"""One camera from its images to its outputs (JSON, optional OpenCV YAML, ROS YAML, report): what ``calibrate`` does, and
``capture`` with the frames it kept."""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

from ccs_kornia.commands._boards import board_records
from ccs_kornia.commands._corners import corners_source, report_note
from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._messages import verdict_line, weak_lines
from ccs_kornia.commands._output_paths import check_outputs, make_dir
from ccs_kornia.commands._printing import warn
from ccs_kornia.commands._run import calibrate_files
from ccs_kornia.commands._selection import frame_selection, save_frames, selection_line
from ccs_kornia.commands._video import (
    camera_videos,
    screening_note,
    still_gate_cause,
)
from ccs_kornia.io.files import write_json, write_text_atomic
from ccs_kornia.outputs.camera_exports import ros_camera_info, write_opencv_yaml
from ccs_kornia.outputs.report.calibration import write_report
from ccs_kornia.outputs.report.drawing import bend_unit
from ccs_kornia.pipeline.sources import FileSource
from ccs_kornia.runtime.errors import UserError

__all__ = ["calibrate_camera"]


def _failed_path(output: str) -> str:
    stem, ext = os.path.splitext(output)
    return f"{stem}.failed{ext or '.json'}"


def calibrate_camera(args: argparse.Namespace) -> int:
    """Calibrate one camera as the ``calibrate`` arguments say; returns the exit status."""
    # the report and the saved frames' folders are created once there is a calibration
    check_outputs(files=[("--output", args.output), ("--opencv-yaml", args.opencv_yaml),
                         ("--ros-yaml", args.ros_yaml), ("--output (its failed-run record)", _failed_path(args.output))],
                  dirs=[("--report", args.report), ("--save-frames", args.save_frames)])
    selection = frame_selection(args)
    if args.save_frames and selection is None:
        raise UserError("--save-frames writes the frames the frame selection kept: give --select (recordings and "
                        "images alike are selected on request only), or leave out --no-select")
    given = corners_source(args, args.images)
    if given is None and not args.images and args.bag is None and args.image_topics is None:
        raise UserError("no images given: give IMAGES (files, folders, globs or videos), --corners JSON or --bag BAG")
    device = resolve_device(args.device)
    start = time.perf_counter()
    video = camera_videos("calibrate", args) if given is None else None
    if given is not None:
        files = [given.describe(0, v) for v in range(given.counts[0])]
    else:
        files = inputs("calibrate", args.images) if video is None else video.names()[0]
    pipeline = make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed,
                             frame_selection=selection)
    try:
        data, result = calibrate_files(
            "calibrate", files, args.board, args.square, pipeline, device, args.model, args.detector, video,
            source=given,
        )
    except UserError as err:
        if video is not None:
            parallel = err.partial is not None and any(e.get("check") == "pose_diversity"
                                                       for e in err.partial.get("errors", []))
            cause = still_gate_cause(video, args) if parallel else ""
            err.args = (f"{cause + '; ' if cause else ''}{err}{screening_note(video)}",)
        # nothing lost: the per-image detections and reasons go next to the requested output, which
        # itself is only ever written for a computed calibration
        kept = (f"; the existing {os.path.basename(args.output)} was left as it was (not from this run)"
                if os.path.exists(args.output) else "")
        if err.partial is not None:
            failed = _failed_path(args.output)
            err.partial["device"] = str(device)
            write_json(failed, err.partial)
            err.args = (f"{err}; per-image results written to {failed}{kept}",)
        elif kept:
            err.args = (f"{err}{kept}",)
        raise
    data["device"] = str(device)
    data["success"] = True
    if getattr(args, "allow_weak", False):
        data["allow_weak"] = True  # the checks in "errors" did not refuse the camera
    data.update(board_records(args))
    if args.save_frames:
        source = video.source() if video is not None else FileSource([files])
        try:
            written = save_frames(args.save_frames, source, [[bool(v["used"]) for v in data["views"]]])
        finally:
            if video is not None:
                source.close()
        data["saved_frames"] = {"folder": args.save_frames, "files": written}
    data["timings"]["total_s"] = time.perf_counter() - start
    write_json(args.output, data)
    if os.path.isfile(_failed_path(args.output)):  # an earlier failure's record would now be stale
        os.unlink(_failed_path(args.output))
    if args.opencv_yaml:
        write_opencv_yaml(args.opencv_yaml, data)
    if args.ros_yaml:
        write_text_atomic("--ros-yaml", args.ros_yaml, ros_camera_info(data))
    if args.report:
        make_dir("--report", args.report)
        if given is not None:
            report_note(data["views"])
        start = time.perf_counter()
        write_report(args.report, data)
        data["timings"]["report_s"] = time.perf_counter() - start
        write_json(args.output, data)
    _print_summary(data, args.output)
    if args.save_frames:
        print(f"wrote the {written} frames used to {args.save_frames}")
    if args.report:
        print(f"report: {os.path.join(args.report, 'index.html')}")
    return 0


def _print_summary(data: dict[str, Any], output: str) -> None:
    K = data["K"]
    n = data["num_views"]
    values = data["distortion"]["coeffs"]
    # a spline's hundreds of control-point values are in the JSON; the line says how many
    coeffs = ", ".join(f"{c:.5g}" for c in values) if len(values) <= 14 else f"{len(values)} control-point values"
    print(
        f"fx {K[0][0]:.3f}  fy {K[1][1]:.3f}  cx {K[0][2]:.3f}  cy {K[1][2]:.3f}  "
        f"{data['distortion']['model']} ({coeffs})"
    )
    hidden = "corners not seen" if {"charuco", "aprilgrid", "circles"} & set(data) else "corners under glare or occluded"
    partial = f", {n['partial']} of them partial ({hidden} left out)" if n.get("partial") else ""
    print(f"RMS {data['rms']:.4f} px over {n['used']} views (board found in {n['found']} of {n['files']} files{partial}); "
          f"wrote {output}")
    if data.get("selection"):
        print(selection_line(data["selection"]))
    choice = data.get("model_selection")
    if choice:
        held = choice["heldout_rms_px"]
        figures = ", ".join(f"{m} {v:.3f}" for m, v in held.items() if v is not None)
        spline = choice.get("splined") or {}
        how = (f"asked for, from {choice['runner_up']} chosen by cross-validation" if "asked for" in spline.get("rule", "")
               else "chosen by cross-validation")
        print(f"model: {choice['chosen']} {how} (runner-up {choice['runner_up']}; held-out RMS px: {figures})")
    structure = data.get("residual_structure")
    if structure and structure["model_fit"] != "fits":
        ratio = structure.get("noise_ratio")
        text = (f"{structure['message']} ({structure['rms_cell_means_px']:.3f} px RMS of the mean residual over "
                f"{structure['cells']} image cells, {structure['cells_significant']} significant"
                + (f"; residuals {ratio:.1f}x the corners' noise" if ratio else "") + ")")
        if structure["model_fit"] == "does not fit":
            warn("calibrate", text)
        else:
            print(f"residuals: {text}")
    flatness = data.get("board_flatness")
    if flatness and flatness["heldout_median_px"]["flat"] is not None:
        cx, cy = (1000 * w for w in flatness["warp_m"])
        sx, sy = (1000 * s for s in flatness["std_m"])
        held = flatness["heldout_median_px"]
        what = "kept" if flatness["kept"] else "not kept: the board taken as flat"
        print(f"board: bent by {cx:+.3f} / {cy:+.3f} {bend_unit(data.get('square'))} (1-sigma {sx:.3f} / {sy:.3f}), {what} (held-out median "
              f"{held['flat']:.3f} px flat, {held['warp']:.3f} px bent)")
    weak = weak_lines(data)
    for text in weak[:-1]:
        warn("calibrate", text)
    if weak:
        print(weak[-1])
    line = verdict_line(data.get("diagnostics"))
    if not line and weak:  # no figures (--no-diagnostics), but the checks' errors say it all the same
        line = "verdict: not reliable: " + "; ".join(dict.fromkeys(e["advice"] for e in data["errors"]))
    if line:
        print(line)
