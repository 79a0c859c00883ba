"""``ccs_kornia capture``: calibrate a camera at hand. Frames of a live source are kept while the board is held still at
poses that lower the predicted uncertainty (:mod:`~ccs_kornia.pipeline.guided_capture`), the next best pose is said
as it changes, and once the target is reached (or the stream ends, or Ctrl-C) the kept frames are written to
``--frames-dir`` and calibrated with the full pipeline exactly as ``calibrate FRAMES_DIR`` would."""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile

import cv2
import numpy as np

from ccs_kornia.commands._capture_rig import run_rig
from ccs_kornia.commands._live_capture import (
    board_fill,
    calibrate_kept,
    frame_name,
    live_detector,
    live_model,
)
from ccs_kornia.commands._one_camera import calibrate_camera
from ccs_kornia.commands._output_paths import check_outputs
from ccs_kornia.io.live import open_live
from ccs_kornia.modules.detection.boards import grid_object_points
from ccs_kornia.modules.detection.screening import BoardScreen
from ccs_kornia.outputs.capture_page import CapturePage, annotate
from ccs_kornia.pipeline.guided_capture import GuidedCapture
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["frames_dir", "run"]

#: the options ``calibrate`` takes for inputs other than a folder of images, set as a folder's
_FOLDER_INPUTS = {"corners": None, "image_size": None, "bag": None, "image_topics": None, "every": 1, "start": None,
                  "end": None, "max_frames": None, "max_motion": None, "select": None, "save_frames": None}


#: capture's own options, which calibrate does not take
_CAPTURE_ONLY = ("sources", "frames_dir", "target", "fast", "port", "host", "no_page", "page_linger", "images",
                 "max_frames")


def frames_dir(args: argparse.Namespace) -> str:
    """Where the kept frames go: ``--frames-dir``, or ``<output without .json>_frames`` beside the output."""
    if args.frames_dir:
        return args.frames_dir
    stem, _ = os.path.splitext(args.output)
    return f"{stem}_frames"


def _capture_loop(args: argparse.Namespace, source, page, obj, board, staging: str):
    """Frames until done, the end of the stream, Ctrl-C or "calibrate now": the :class:`GuidedCapture` and why it
    stopped."""
    capture = None
    said = ""
    shown: dict = {}
    why = "stream ended"
    try:
        with source:
            for frame in source:
                if capture is None:
                    h, w = frame.image.shape
                    capture = GuidedCapture(tuple(args.board), obj, (w, h), live_detector(args),
                                            live_model=live_model(args), screen=BoardScreen(tuple(args.board), board),
                                            target=args.target, max_frames=args.max_frames)
                actions = page.take_actions() if page is not None else []
                if "calibrate" in actions:
                    why = "calibrate now"
                    break
                for _ in range(actions.count("undo")):
                    gone = capture.undo()
                    if gone is not None:
                        os.unlink(os.path.join(staging, frame_name(gone.index)))
                        print(f"undone {frame_name(gone.index)}", flush=True)
                        shown.clear()
                if "keep" in actions:
                    decision = capture.keep_now(frame.image, frame.index, frame.timestamp)
                else:
                    decision = capture.offer(frame.image, frame.index, frame.timestamp)
                if decision.kept:
                    kept = capture.kept[-1]
                    name = frame_name(frame.index)
                    cv2.imwrite(os.path.join(staging, name), frame.image)
                    figure = "" if not np.isfinite(decision.worst_px) else \
                        f"; predicted worst 1-sigma {decision.worst_px:.3f} px (target {args.target:g})"
                    print(f"kept {name} at {frame.timestamp:.2f} s: {kept.why}{figure}", flush=True)
                    shown.clear()
                if not shown and capture.kept:  # what changes only with the kept frames
                    best = capture.suggestion(board_fill(capture.kept[-1].outline, capture.image_size[0]))
                    shown = {"suggestion": best, "map": capture.uncertainty_map()}
                    if best.instruction and best.instruction != said and not capture.done:
                        print(f"next: {best.instruction}", flush=True)
                        said = best.instruction
                if page is not None:
                    _show(page, frame.image, capture, decision, shown, args.target)
                if decision.done:
                    why = "target reached" if capture.worst_px <= args.target else f"--max-frames {args.max_frames} reached"
                    break
    except KeyboardInterrupt:
        why = "interrupted"
    return capture, why


def _show(page, image: np.ndarray, capture: GuidedCapture, decision, shown: dict, target: float) -> None:
    best = shown.get("suggestion")
    outline = None if best is None or not len(best.poses) else best.poses.outline[0].numpy()
    worst = capture.worst_px if np.isfinite(capture.worst_px) else None
    page.show(annotate(image, decision.sighting.outline, [k.outline for k in capture.kept], outline,
                       shown.get("map"), target, worst))
    page.set_state(worst_px=worst, target_px=target, instruction="" if best is None else best.instruction,
                   status=("target reached" if decision.done else decision.reason), done=decision.done,
                   kept=[{"name": frame_name(k.index), "why": k.why} for k in capture.kept])


def run(args: argparse.Namespace) -> int:
    folder = frames_dir(args)
    check_outputs(files=[("--output", args.output), ("--opencv-yaml", args.opencv_yaml), ("--ros-yaml", args.ros_yaml)],
                  dirs=[("--report", args.report), ("--frames-dir", folder)])
    if os.path.isdir(folder) and os.listdir(folder):
        raise UserError(f"--frames-dir {folder} is not empty: the kept frames must be alone there (so that calibrate "
                        f"{folder} gives the same camera)")
    if len(args.sources) > 1:
        return run_rig(args, folder)
    page = None if args.no_page else CapturePage(args.host, args.port)
    try:
        source = open_live(args.sources[0], realtime=not args.fast)
    except UserError:
        if page is not None:
            page.close()
        raise
    if page is not None:
        print(f"page: {page.url}", flush=True)
    board = args.charuco_board if args.charuco_board is not None else args.aprilgrid_board
    obj = grid_object_points(board, tuple(args.board), args.square)
    staging = tempfile.mkdtemp(prefix=".capture-", dir=os.path.dirname(os.path.abspath(folder)) or ".")
    try:
        capture, why_stopped = _capture_loop(args, source, page, obj, board, staging)
        kept_frames = [] if capture is None else capture.kept
        if not kept_frames:
            what = "no frame came" if capture is None else (
                "the board was never seen" if not capture.sightings else "the board was never held still at a new pose")
            raise NoResult(f"{args.sources[0]}: {what}; nothing written")
        if len(kept_frames) < 3:
            raise NoResult(f"{args.sources[0]}: only {len(kept_frames)} frame(s) kept, at least 3 are needed to "
                           "calibrate; nothing written")
        print(f"{why_stopped}: {len(kept_frames)} frames kept; calibrating with the full pipeline", flush=True)
        if page is not None:
            page.set_state(status=f"{why_stopped}: calibrating {len(kept_frames)} frames", done=True)
        cal = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in _CAPTURE_ONLY}, **_FOLDER_INPUTS,
                                 images=[folder])
        moved, staging = staging, None  # in place from here on: not removed
        return calibrate_kept(
            moved, folder, lambda: calibrate_camera(cal),
            lambda seconds: f"wrote the {len(kept_frames)} kept frames to {folder} (calibrate {folder} gives the same "
                            f"camera); calibration {seconds:.1f} s",
            page, args.output, len(kept_frames), args.page_linger)
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        if page is not None:
            page.close()


