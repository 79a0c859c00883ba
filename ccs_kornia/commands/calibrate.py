"""``ccs_kornia calibrate``: one camera from chessboard images (JSON, optional OpenCV YAML and report)."""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

from ccs_kornia.commands._boards import aprilgrid_record, charuco_record
from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._messages import not_found_message, weak_lines
from ccs_kornia.commands._output_paths import (
    check_output_dir,
    check_output_file,
    make_dir,
)
from ccs_kornia.commands._printing import warn
from ccs_kornia.commands._run import run_files
from ccs_kornia.commands._selection import frame_selection, save_frames, selection_line
from ccs_kornia.commands._video import (
    add_timestamps,
    camera_videos,
    screening_note,
)
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["calibrate_files", "failure_message", "run", "verdict_line"]


def calibrate_files(
    command: str,
    files: list[str],
    board: tuple[int, int],
    square: float,
    pipeline,
    device,
    model: str,
    detector_name: str,
    video=None,
) -> tuple[dict[str, Any], Any]:
    """The pipeline's one composition on ``files`` (one camera); returns (JSON-ready dict, PipelineResult of it).

    ``video``: the chosen frames of the camera's recordings (:class:`~ccs_kornia.pipeline.video_input.VideoFrames`,
    ``files`` their names): the views are read from the videos, each view gets its ``timestamp`` and the record a
    ``video`` entry per recording (what the screening saw of every frame, and why a frame was not chosen).

    Raises :class:`UserError` when no calibration can be computed: :class:`NoResult` when images were read, with
    ``partial``: the per-view record (detections and reasons) so the caller can keep it.
    """
    from ccs_kornia.outputs.records import camera_record

    source = None if video is None else video.source()
    out, seconds = run_files(command, pipeline, [files], board, square, device, source=source)
    one = out.select(0)
    data = camera_record(one, files, board=board, square=square, detector=detector_name, model=model)
    if video is not None:
        add_timestamps(data["views"], video.timestamps())
        data["video"] = video.records(0)
    data["timings"] = {"load_detect_solve_s": seconds, "images_per_s": len(files) / max(seconds, 1e-9)}
    for view in data["views"]:
        if view["found"] and "reason" in view and view["reason"].startswith("image size"):
            warn(command, f"skipped {view['path']}: {view['reason']}")
        if "note" in view:
            warn(command, f"{view['path']}: {view['note']}")
    for issue in data.get("warnings", []) if data["success"] else []:  # a failed camera's figures say nothing
        warn(command, issue.get("message", str(issue)) + _files_note(issue))
    if not data["success"]:
        readable = int(one.present.sum())
        message = failure_message(data, board, readable)
        if not readable:
            raise UserError(message)
        err = NoResult(message)
        err.partial = data
        raise err
    return data, one


def failure_message(data: dict[str, Any], board: tuple[int, int], readable: int) -> str:
    """Why a camera's record (:func:`~ccs_kornia.outputs.records.camera_record`, ``success`` false) holds no calibration, in
    one line: board never found, too few usable views, the solver's refusals with the views they name."""
    files = data["num_views"]["files"]
    if data["num_views"]["found"] == 0:
        return not_found_message(board, readable, files, str(data.get("detector", "")))
    if data["num_views"]["usable"] < 3:
        return (f"only {data['num_views']['usable']} usable view(s) of the {board[0]}x{board[1]} board among "
                f"{files} files (board found in {data['num_views']['found']}); at least 3 are needed")
    if data.get("errors"):  # the solver's refusals (degeneracy checks) name the problem and the views
        from ccs_kornia.modules.calibration.quality.degeneracy import WEAK_CHECKS

        weak = all(i.get("check") in WEAK_CHECKS and i.get("value") is not None for i in data["errors"])
        return (f"calibration refused on {data['num_views']['usable']} views: "
                + "; ".join(i["message"] + _files_note(i) for i in data["errors"])
                + ("; --allow-weak calibrates anyway (verdict not reliable)" if weak else ""))
    why = data["error"] if data["error"].startswith("calibration failed") else \
        f"calibration failed on {data['num_views']['usable']} views: {data['error']}"
    return (f"{why}; the views may be degenerate (e.g. all fronto-parallel, or copies of one view) or "
            "inconsistent: add views with the board tilted in different directions")


def _files_note(issue: dict[str, Any], most: int = 6) -> str:
    """`` (files: a.jpg, b.jpg, ...)`` for the views a degeneracy check names."""
    names = [os.path.basename(f) for f in issue.get("files", [])]
    if not names:
        return ""
    more = f", ... ({len(names)} in all)" if len(names) > most else ""
    return f" (files: {', '.join(names[:most])}{more})"


def _failed_path(output: str) -> str:
    stem, ext = os.path.splitext(output)
    return f"{stem}.failed{ext or '.json'}"


def run(args: argparse.Namespace) -> int:
    from ccs_kornia.io.files import write_json, write_text_atomic
    from ccs_kornia.outputs.camera_exports import ros_camera_info, write_opencv_yaml
    from ccs_kornia.pipeline.sources import FileSource
    check_output_file("--output", args.output)
    if args.opencv_yaml:
        check_output_file("--opencv-yaml", args.opencv_yaml)
    if args.ros_yaml:
        check_output_file("--ros-yaml", args.ros_yaml)
    if args.report:
        check_output_dir("--report", args.report)  # created once there is a calibration to report
    if args.save_frames:
        check_output_dir("--save-frames", args.save_frames)  # written once there is a calibration
    selection = frame_selection(args)
    if args.save_frames and selection is None:
        raise UserError("--save-frames writes the frames the frame selection kept: give --select (recordings and "
                        "images alike are selected on request only), or leave out --no-select")
    device = resolve_device(args.device)
    start = time.perf_counter()
    video = camera_videos("calibrate", args)
    files = inputs("calibrate", args.images) if video is None else video.names()[0]
    pipeline = make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed,
                             frame_selection=selection)
    try:
        data, result = calibrate_files(
            "calibrate", files, args.board, args.square, pipeline, device, args.model, args.detector, video
        )
    except UserError as err:
        if video is not None:
            err.args = (f"{err}{screening_note(video)}",)
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
    if charuco_record(args):
        data["charuco"] = charuco_record(args)
    if aprilgrid_record(args):
        data["aprilgrid"] = aprilgrid_record(args)
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
        from ccs_kornia.outputs.report.calibration import write_report

        make_dir("--report", args.report)
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
    coeffs = ", ".join(f"{c:.5g}" for c in data["distortion"]["coeffs"])
    print(
        f"fx {K[0][0]:.3f}  fy {K[1][1]:.3f}  cx {K[0][2]:.3f}  cy {K[1][2]:.3f}  "
        f"{data['distortion']['model']} ({coeffs})"
    )
    hidden = "corners not seen" if "charuco" in data or "aprilgrid" in data else "corners under glare or occluded"
    partial = f", {n['partial']} of them partial ({hidden} left out)" if n.get("partial") else ""
    print(f"RMS {data['rms']:.4f} px over {n['used']} views (board found in {n['found']} of {n['files']} files{partial}); "
          f"wrote {output}")
    if data.get("selection"):
        print(selection_line(data["selection"]))
    choice = data.get("model_selection")
    if choice:
        held = choice["heldout_rms_px"]
        figures = ", ".join(f"{m} {v:.3f}" for m, v in held.items() if v is not None)
        print(f"model: {choice['chosen']} chosen by cross-validation (runner-up {choice['runner_up']}; "
              f"held-out RMS px: {figures})")
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


def verdict_line(quality: dict[str, Any] | None) -> str:
    """``verdict: ... (held-out views ... px, ...)`` from the diagnostics (empty without them)."""
    if not quality:
        return ""
    figures = [f"{label} {quality[key]:.3f} px" for label, key in (
        ("held-out views", "heldout_rms_px"), ("halves differ where the boards were by", "cv_covered_rms_px"),
        ("uncertainty at the centre", "uncertainty_centre_px")) if quality.get(key) is not None]
    return f"verdict: {quality['verdict']}" + (f" ({', '.join(figures)})" if figures else "")
