"""``capture`` with several SOURCEs: a rig's cameras read together, the instants that lower a camera's predicted
uncertainty or give the pair the guidance asks for a view in common kept (:class:`~ccs_kornia.pipeline.rig_capture.
RigCapture`), the page showing every camera side by side; the kept frames written one folder per camera (the same
name for one instant) and calibrated with the full pipeline exactly as ``calibrate-rig CAM_DIR...`` would."""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from contextlib import ExitStack

import cv2
import numpy as np

from ccs_kornia.commands._live_capture import (
    board_fill,
    calibrate_kept,
    frame_name,
    live_detector,
    live_model,
)
from ccs_kornia.io.live import open_live
from ccs_kornia.modules.detection.boards import grid_object_points
from ccs_kornia.modules.detection.screening import BoardScreen
from ccs_kornia.outputs.capture_page import CapturePage, annotate
from ccs_kornia.pipeline.guided_capture import GuidedCapture
from ccs_kornia.pipeline.rig_capture import RigCapture
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["camera_dirs", "rig_view", "run_rig"]


def camera_dirs(folder: str, count: int) -> list[str]:
    """The kept frames' folders: ``cam0``, ``cam1``, ... inside ``folder``."""
    return [os.path.join(folder, f"cam{c}") for c in range(count)]


def _mosaic(images: list[np.ndarray]) -> np.ndarray:
    """The cameras' annotated frames side by side (BGR), each scaled to the first one's height."""
    h = images[0].shape[0]
    scaled = [im if im.shape[0] == h else cv2.resize(im, (round(im.shape[1] * h / im.shape[0]), h),
                                                      interpolation=cv2.INTER_AREA) for im in images]
    return np.concatenate(scaled, axis=1)


def _rig_loop(args: argparse.Namespace, sources, page, obj, board, staging: list[str]):
    """Instants until done, the end of a stream, Ctrl-C or "calibrate now": the :class:`RigCapture` and why it
    stopped."""
    rig, said, why = None, "", "stream ended"
    detect, model = live_detector(args), live_model(args)
    shown: dict = {}  # each camera's next best pose and uncertainty map: they change only with the kept instants
    try:
        for index, frames in enumerate(zip(*sources)):
            if rig is None:
                rig = RigCapture([GuidedCapture(tuple(args.board), obj, (f.image.shape[1], f.image.shape[0]), detect,
                                                live_model=model, screen=BoardScreen(tuple(args.board), board),
                                                target=args.target, max_frames=args.max_frames) for f in frames],
                                 max_frames=args.max_frames)
            actions = page.take_actions() if page is not None else []
            if "calibrate" in actions:
                why = "calibrate now"
                break
            for _ in range(actions.count("undo")):
                gone = rig.undo()
                if gone is not None:
                    for folder in staging:
                        os.unlink(os.path.join(folder, frame_name(gone.index)))
                    print(f"undone {frame_name(gone.index)}", flush=True)
                    shown.clear()
            stamp = frames[0].timestamp
            decision = rig.offer([f.image for f in frames], index, stamp)
            if decision.kept:
                name = frame_name(index)
                for folder, frame in zip(staging, frames):
                    cv2.imwrite(os.path.join(folder, name), frame.image)
                print(f"kept {name} at {stamp:.2f} s: {decision.reason}", flush=True)
                shown.clear()
            if not shown and not rig.done:
                fills = [None if not cam.kept else board_fill(cam.kept[-1].outline, cam.image_size[0])
                         for cam in rig.cameras]
                best = rig.suggestions(fills)
                shown = {"suggestions": best, "maps": [cam.uncertainty_map() for cam in rig.cameras],
                         "instruction": rig.instruction(fills, best)}
            instruction = "" if rig.done else shown["instruction"]
            if instruction and instruction != said:
                print(f"next: {instruction}", flush=True)
                said = instruction
            if page is not None:
                page.show(rig_view([f.image for f in frames], rig, decision, shown, args.target))
                _state(page, rig, decision, instruction, args.target)
            if decision.done:
                why = "target reached" if len(rig.kept) < args.max_frames else f"--max-frames {args.max_frames} reached"
                break
    except KeyboardInterrupt:
        why = "interrupted"
    return rig, why


def _caption(rig: RigCapture, c: int) -> str:
    """Camera ``c``'s name on the page, and the camera it still needs views in common with."""
    needs = rig.common_needed(c)
    return f"camera {c}: needs {needs}" if needs else f"camera {c}"


def rig_view(images: list[np.ndarray], rig: RigCapture, decision, shown: dict, target: float) -> np.ndarray:
    """The page's image of a rig (BGR): every camera's frame side by side, each annotated as one camera's page is
    (:func:`~ccs_kornia.outputs.capture_page.annotate`: its board, coverage, uncertainty map and its next best pose's
    outline) and captioned with its name and the camera it still needs views in common with.

    Args:
        images: the cameras' grey ``uint8`` frames of one instant.
        rig: the capture.
        decision: :meth:`RigCapture.offer`'s for those frames.
        shown: ``"suggestions"`` (:meth:`RigCapture.suggestions`) and ``"maps"`` (each camera's uncertainty map), or
            empty (nothing suggested).
        target: the target (px).
    """
    views = []
    suggestions = shown.get("suggestions") or [None] * len(rig.cameras)
    maps = shown.get("maps") or [None] * len(rig.cameras)
    for c, (cam, image, d) in enumerate(zip(rig.cameras, images, decision.decisions)):
        best = suggestions[c]
        outline = None if best is None or not len(best.poses) else best.poses.outline[0].numpy()
        worst = cam.worst_px if np.isfinite(cam.worst_px) else None
        views.append(annotate(image, d.sighting.outline, [k.outline for k in cam.kept], outline, maps[c], target,
                              worst, _caption(rig, c)))
    return _mosaic(views)


def _state(page, rig: RigCapture, decision, instruction: str, target: float) -> None:
    figures = [c.worst_px for c in rig.cameras if np.isfinite(c.worst_px)]
    page.set_state(worst_px=max(figures) if len(figures) == len(rig.cameras) else None, target_px=target,
                   instruction=instruction, status="target reached" if decision.done else decision.reason,
                   done=decision.done,
                   kept=[{"name": frame_name(k.index), "why": k.why} for k in rig.kept])


def run_rig(args: argparse.Namespace, folder: str) -> int:
    """``capture`` of a rig (module docstring): ``folder`` the kept frames' (checked empty by the caller)."""
    if args.ros_yaml:
        raise UserError("--ros-yaml writes one camera's file: for a rig, run calibrate-rig --ros-yaml-dir on the kept "
                        "frames")
    page = None if args.no_page else CapturePage(args.host, args.port)
    with ExitStack() as stack:
        try:
            sources = [stack.enter_context(open_live(s, realtime=not args.fast)) for s in args.sources]
        except UserError:
            if page is not None:
                page.close()
            raise
        if page is not None:
            print(f"page: {page.url}", flush=True)
        board = args.charuco_board if args.charuco_board is not None else args.aprilgrid_board
        obj = grid_object_points(board, tuple(args.board), args.square)
        root = tempfile.mkdtemp(prefix=".capture-", dir=os.path.dirname(os.path.abspath(folder)) or ".")
        staging = camera_dirs(root, len(args.sources))
        for d in staging:
            os.makedirs(d)
        try:
            rig, why_stopped = _rig_loop(args, sources, page, obj, board, staging)
            kept = [] if rig is None else rig.kept
            if not kept:
                what = "no frame came" if rig is None else "the board was never held still at a new pose"
                raise NoResult(f"{' '.join(args.sources)}: {what}; nothing written")
            views = [sum(c in k.cameras for k in kept) for c in range(len(args.sources))]
            if min(views) < 3:
                c = int(np.argmin(views))
                raise NoResult(f"{args.sources[c]}: the board was taken in only {views[c]} frame(s) of camera {c}, at "
                               "least 3 are needed to calibrate it; nothing written")
            print(f"{why_stopped}: {len(kept)} instants kept ({', '.join(map(str, views))} views per camera); "
                  "calibrating the rig with the full pipeline", flush=True)
            if not rig.linked():
                a, b, count = rig.needed_pair()
                print(f"capture: warning: cameras {a} and {b} share only {count} views (at least "
                      f"{rig.min_common} link a pair): the rig may not calibrate", flush=True)
            if page is not None:
                page.set_state(status=f"{why_stopped}: calibrating the rig from {len(kept)} instants", done=True)
            folders = camera_dirs(folder, len(args.sources))
            moved, root = root, None  # in place from here on: not removed
            return calibrate_kept(
                moved, folder, lambda: _calibrate_rig(args, folders),
                lambda seconds: f"wrote the {len(kept)} kept instants to {folder} (calibrate-rig {' '.join(folders)} "
                                f"gives the same rig); calibration {seconds:.1f} s",
                page, args.output, len(kept), args.page_linger)
        finally:
            if root is not None:
                shutil.rmtree(root, ignore_errors=True)
            if page is not None:
                page.close()


#: the options ``calibrate-rig`` takes that ``capture`` does not, as they are for folders of images
_RIG_INPUTS = {"corners": None, "image_size": None, "bag": None, "image_topics": None, "names": None,
               "fix_intrinsics": None, "ros_yaml_dir": None, "pair": None, "kalibr_yaml": None, "every": 1,
               "start": None, "end": None, "sync_tolerance": None, "timestamps": None, "select": None,
               "save_frames": None, "max_frames": None}
#: capture's own options, which calibrate-rig does not take
_CAPTURE_ONLY = ("sources", "frames_dir", "target", "fast", "port", "host", "no_page", "page_linger", "max_frames",
                 "ros_yaml", "model")


def _calibrate_rig(args: argparse.Namespace, folders: list[str]) -> int:
    """``calibrate-rig`` on the kept frames' folders with capture's board, detector, model and outputs."""
    from ccs_kornia.commands import calibrate_rig

    model = str(args.model)
    rig = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in _CAPTURE_ONLY}, **_RIG_INPUTS,
                             cameras=folders, model=model, model_choices=(model,))
    rig.command = "calibrate-rig"
    return calibrate_rig.run(rig)
