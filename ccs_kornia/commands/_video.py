"""What the commands do with recordings: videos told apart from images, screened with a progress bar, frames chosen,
and the frames' names and timestamps put in the outputs.

A command that takes image folders takes videos in their place (``calibrate cam.mp4``, ``calibrate-rig cam0.mp4
cam1.mp4``): every frame is screened (:mod:`~ccs_kornia.pipeline.screening`), a bounded set of frames is chosen
(:mod:`~ccs_kornia.pipeline.frame_candidates`) and the pipeline runs on those (:class:`~ccs_kornia.pipeline.sources.
VideoSource`), each named ``VIDEO#INDEX`` with its ``timestamp`` beside it in the JSON.
"""

from __future__ import annotations

import argparse
import glob
import math
import os
import sys
from collections.abc import Sequence
from typing import Any

from tqdm import tqdm

from ccs_kornia.commands._printing import info, warn
from ccs_kornia.io.images import IMAGE_EXTENSIONS, natural_key
from ccs_kornia.io.recordings import open_recording
from ccs_kornia.io.timestamps import read_timestamps
from ccs_kornia.io.video import FrameSpan, is_video
from ccs_kornia.modules.detection.screening import BoardScreen
from ccs_kornia.pipeline.frame_candidates import (
    DEFAULT_MAX_FRAMES,
    MAX_MOTION,
    MAX_MOVING_MOTION,
    detector_frames,
)
from ccs_kornia.pipeline.screening import screen_video
from ccs_kornia.pipeline.video_input import camera_frames, pair_videos, rig_frames
from ccs_kornia.pipeline.workers import default_workers
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["add_timestamps", "bag_recordings", "camera_videos", "detector_count", "frame_span", "make_screen",
           "max_frames", "max_motion", "pairing_lines", "rig_videos", "screen_videos", "screen_workers", "screening_note",
           "selecting", "still_gate_cause", "video_inputs", "video_summary"]


def _videos_in(directory: str) -> list[str]:
    return sorted((os.path.join(directory, n) for n in os.listdir(directory)
                   if is_video(n) and os.path.isfile(os.path.join(directory, n))), key=natural_key)


def _images_in(directory: str) -> bool:
    return any(n.lower().endswith(IMAGE_EXTENSIONS) for n in os.listdir(directory))


def video_inputs(command: str, items: Sequence[str]) -> list[str]:
    """The videos the command-line ``items`` name: video files, folders holding videos (and no images), globs
    matching videos; ``[]`` when no item is a video (the images' path then reads them). Images and videos together
    are refused (:class:`UserError`): a camera's views come from one or the other."""
    videos: list[str] = []
    others: list[str] = []
    for item in items:
        if os.path.isdir(item):
            found = [] if _images_in(item) else _videos_in(item)
            (videos.extend(found) if found else others.append(item))
        elif os.path.isfile(item):
            (videos if is_video(item) else others).append(item)
        elif set("*?[") & set(item):
            matches = [p for p in glob.glob(item, recursive=True) if os.path.isfile(p)]
            found = [p for p in matches if is_video(p)]
            videos.extend(found)
            if len(found) < len(matches) or not matches:
                others.append(item)
        else:
            others.append(item)
    if videos and others:
        raise UserError(f"give either videos or images, not both: {videos[0]} is a video, {others[0]} is not")
    seen: set[str] = set()
    return [v for v in videos if not (os.path.abspath(v) in seen or seen.add(os.path.abspath(v)))]


def bag_recordings(args: argparse.Namespace, one_camera: bool) -> list[str]:
    """``--bag BAG --image-topics TOPIC[,TOPIC...]``: each image topic as a recording (``BAG#TOPIC``, read as a video
    is, :class:`~ccs_kornia.io.rosbag.BagTopicReader`); ``[]`` without ``--bag``. Refused in one line: topics without
    a bag, a bag without topics (the line lists its image topics), a bag given with images or with ``--corners``,
    more than one topic for one camera, a topic twice."""
    bag, topics = getattr(args, "bag", None), getattr(args, "image_topics", None)
    if bag is None:
        if topics is not None:
            raise UserError("--image-topics names the image topics of a --bag; give --bag BAG too")
        return []
    inputs = getattr(args, "images", None) or getattr(args, "cameras", None)
    if inputs:
        raise UserError(f"give either images or --bag, not both: {inputs[0]} and --bag {bag}")
    if getattr(args, "corners", None):
        raise UserError(f"give either --corners or --bag, not both: --corners {args.corners[0]} and --bag {bag}")
    if not topics:
        from ccs_kornia.io.rosbag import IMAGE_TYPES, bag_topics

        listed = [t for t, kind in bag_topics(bag).items() if kind in IMAGE_TYPES]
        raise UserError(f"--bag {bag}: give --image-topics (its image topics: {', '.join(listed) or 'none'})")
    names = [t.strip() for t in topics.split(",")]
    if any(not t.startswith("/") or "#" in t for t in names):
        raise UserError(f"--image-topics {topics}: topics are names like /cam0/image_raw, separated by commas")
    if len(set(names)) != len(names):
        raise UserError(f"--image-topics {topics}: a topic given twice (one topic per camera)")
    if one_camera and len(names) != 1:
        raise UserError(f"--image-topics {topics}: one camera takes one image topic (calibrate-rig takes several)")
    from ccs_kornia.io.rosbag import bag_topic_path

    return [bag_topic_path(bag, t) for t in names]


def max_frames(args: argparse.Namespace) -> int:
    """``--max-frames`` (default :data:`~ccs_kornia.pipeline.frame_candidates.DEFAULT_MAX_FRAMES`)."""
    value = getattr(args, "max_frames", None)
    return DEFAULT_MAX_FRAMES if value is None else int(value)


def max_motion(args: argparse.Namespace) -> float | None:
    """``--max-motion`` (px per frame period; ``None``: the default, a fraction of the image diagonal)."""
    value = getattr(args, "max_motion", None)
    return None if value is None else float(value)


def selecting(args: argparse.Namespace) -> bool:
    """Whether the command keeps only the frames that make the best camera (the frame selection): ``--select``;
    off by default for recordings and folders alike: on recordings the screening's choice of still frames calibrates
    as well on average, for a third less of the full detector's time (``docs/video.md``)."""
    return bool(getattr(args, "select", None))


def detector_count(args: argparse.Namespace) -> int:
    """Frames of a recording (instants of a rig) the full detector sees: ``--max-frames``, half as many again with the
    frame selection on (:func:`~ccs_kornia.pipeline.frame_candidates.detector_frames`)."""
    return detector_frames(max_frames(args), selecting(args))


def frame_span(args: argparse.Namespace):
    """``--every``, ``--start``, ``--end`` as a :class:`~ccs_kornia.io.video.FrameSpan`."""
    try:
        return FrameSpan(getattr(args, "every", 1) or 1, getattr(args, "start", None), getattr(args, "end", None))
    except ValueError as err:
        raise UserError(f"--every/--start/--end: {err}") from None


def make_screen(args: argparse.Namespace):
    """The screening pass's quick look for the command's board (:class:`~ccs_kornia.modules.detection.screening.
    BoardScreen`)."""
    board = getattr(args, "charuco_board", None) or getattr(args, "aprilgrid_board", None) or \
        getattr(args, "circle_board", None)
    return BoardScreen(tuple(args.board), board)


def screen_workers(args: argparse.Namespace) -> int:
    """Processes of the screening pass: ``--jobs`` (``auto``: one per core, at most 4)."""
    jobs = getattr(args, "jobs", "auto")
    return default_workers("cpu") if jobs == "auto" else int(jobs)


def _estimate(info, span) -> int:
    """Frames the pass will screen, from the container's figures (for the progress bar)."""
    total = info.frame_count or 0
    if info.fps > 0 and total:
        first = int((span.start or 0.0) * info.fps)
        last = total if span.end is None else min(total, int(span.end * info.fps) + 1)
        total = max(0, last - first)
    return max(1, -(-total // max(1, span.every))) if total else 0


def screen_videos(command: str, paths: Sequence[str], screen, span, workers: int, skip_unreadable: bool) -> list:
    """Screen every video with a progress bar (frames/s and the boards seen so far); a damaged video's lost frames are
    reported; an unreadable video is skipped with a warning (``skip_unreadable``) or stops the command.

    Returns:
        The :class:`~ccs_kornia.pipeline.screening.ScreenedVideo` of each video read.
    """
    infos, bad = [], []
    for path in paths:
        video, reason = open_recording(path)
        (infos.append(video) if video is not None else bad.append((path, reason)))
    if bad and (not skip_unreadable or not infos):
        path, reason = bad[0]
        more = f" (and {len(bad) - 1} more of the {len(paths)} videos)" if len(bad) > 1 else ""
        raise UserError(f"{path}: {reason}{more}")
    for path, reason in bad:
        warn(command, f"skipped {path}: {reason}")
    total = sum(_estimate(v, span) for v in infos)
    out = []
    with tqdm(total=total or None, unit="frame", desc=f"{command}: screening", file=sys.stderr, disable=None,
              leave=False) as bar:
        seen = 0

        def advance(frames: int, boards: int) -> None:
            nonlocal seen
            seen += boards
            bar.update(frames)
            bar.set_postfix_str(f"board in {seen}", refresh=False)

        for video in infos:
            try:
                out.append(screen_video(video, screen, span, workers, advance))
            except ValueError as err:
                if not skip_unreadable:
                    raise UserError(str(err)) from None
                warn(command, f"skipped {video.path}: {err}")
    where = "" if span == type(span)() else " between --start and --end"
    empty = [v for v in out if not v.frames]
    if empty and (not skip_unreadable or len(empty) == len(out)):
        raise UserError(f"{empty[0].path}: no frame{where} could be read")
    for video in out:
        if video.stopped:
            warn(command, f"{video.path}: {video.stopped}")
        if not video.frames:
            warn(command, f"skipped {video.path}: no frame{where} could be read")
    return [v for v in out if v.frames]


def video_summary(frames, names: Sequence[str] | None = None) -> list[str]:
    """One line per video: frames screened and at what rate, the board seen in how many, chosen how many."""
    lines = []
    for c, refs in enumerate(frames.refs):
        videos = frames.videos if frames.table is None else [frames.videos[c]]
        for v, video in enumerate(videos):
            rate = len(video.frames) / max(video.seconds, 1e-9)
            chosen = sum(frames.chosen[c][v])
            who = f"camera {names[c]} " if names is not None else ""
            moving = sum(frames.moving(c)[v])
            why = ""
            if moving:
                gate = frames.still_gate(c)
                spread = gate["still_spread_deg"]
                why = (f" ({moving} of them moving: {gate['still_frames']} frames still"
                       + (f", their boards within {spread:.0f} deg of each other" if spread is not None else "") + ")")
            lines.append(f"{who}{video.path}: {len(video.frames)} frames screened ({rate:.0f} frames/s), board seen in "
                         f"{video.found}, {chosen} chosen for the detector{why}")
    return lines


def add_timestamps(views: list[dict[str, Any]], times: dict[str, float | None]) -> None:
    """Each view record whose ``path`` is a video frame gets its ``timestamp`` (s) beside it."""
    for view in views:
        if view.get("path") in times:
            t = times[view["path"]]
            view["timestamp"] = None if t is None else round(float(t), 6)


def report_screening(command: str, frames, names: Sequence[str] | None = None) -> None:
    """The screening's lines on stderr."""
    for line in video_summary(frames, names):
        info(line)


def camera_videos(command: str, args: argparse.Namespace):
    """One camera's recordings (``args.images`` naming videos) screened and their frames chosen
    (:class:`~ccs_kornia.pipeline.video_input.VideoFrames`); ``None`` when the inputs are images."""
    paths = bag_recordings(args, one_camera=True) or video_inputs(command, args.images)
    if not paths:
        return None
    span = frame_span(args)
    screened = screen_videos(command, paths, make_screen(args), span, screen_workers(args), skip_unreadable=True)
    frames = camera_frames(screened, detector_count(args), max_motion(args))
    report_screening(command, frames)
    return frames


def still_gate_cause(frames, args: argparse.Namespace, camera: int = 0) -> str:
    """The still gate named as the cause of a refusal of nearly parallel boards (``""`` where it is not one: every
    frame went to the detector, or no frame was left out or taken for its motion)."""
    gate = frames.still_gate(camera)
    if gate["still_frames"] is None:
        return ""
    videos = frames.videos if frames.table is None else [frames.videos[camera]]
    left = sum(r.startswith("moving") for per_video in frames.reasons[camera] for r in per_video)
    if not left and not gate["chosen_moving"]:
        return ""
    diagonal = math.hypot(*videos[0].info.size)
    fastest = max_motion(args)
    fastest = MAX_MOVING_MOTION * diagonal if fastest is None else fastest
    spread = gate["still_spread_deg"]
    within = f", their boards within {spread:.0f} deg of each other" if spread is not None else ""
    return (f"the board was never still long enough: {gate['still_frames']} frames still (moving at most "
            f"{MAX_MOTION * diagonal:.1f} px a frame){within}, {gate['chosen_moving']} moving frames taken (at most "
            f"{fastest:.1f} px a frame), {left} left out moving faster; hold the board still for ~0.5 s at each "
            "pose, or pass --max-motion PX to take faster frames")


def screening_note(frames) -> str:
    """``; 1800 frames of cam.mp4 screened, the board seen in none`` for a failure's message."""
    screened = sum(len(v.frames) for v in frames.videos)
    seen = sum(v.found for v in frames.videos)
    what = frames.videos[0].path if len(frames.videos) == 1 else f"{len(frames.videos)} videos"
    return f"; {screened} frames of {what} screened, the board seen in {seen or 'none'}"


def rig_videos(command: str, args: argparse.Namespace, names: Sequence[str]):
    """A rig's recordings (``args.cameras`` naming one video per camera) screened, paired into instants and chosen
    (:class:`~ccs_kornia.pipeline.video_input.VideoFrames`); ``None`` when the cameras are image folders. Says on
    stderr how many frames each camera contributed and the largest time spread of a paired frame."""
    bags = bag_recordings(args, one_camera=False)
    found = [[path] for path in bags] if bags else [video_inputs(command, [item]) for item in args.cameras]
    if not any(found):
        for option in ("timestamps", "sync_tolerance"):
            if getattr(args, option, None) is not None:
                raise UserError(f"--{option.replace('_', '-')} pairs the frames of videos; the cameras given are image "
                                "folders (their views pair by the numbers in the file names)")
        return None
    for name, item, videos in zip(names, bags or args.cameras, found):
        if len(videos) != 1:
            what = "images" if not videos else f"{len(videos)} videos"
            raise UserError(f"camera {name} ({item}): a rig of recordings takes one video per camera, got {what}")
    paths = [videos[0] for videos in found]
    table = None
    if args.timestamps is not None:
        try:
            table = read_timestamps(args.timestamps)
        except ValueError as err:
            raise UserError(f"--timestamps: {err}") from None
        if args.sync_tolerance is not None:
            warn(command, "--sync-tolerance is not used: --timestamps says which frames pair")
    screened = screen_videos(command, paths, make_screen(args), frame_span(args), screen_workers(args),
                             skip_unreadable=False)
    try:
        pairing = pair_videos(screened, args.sync_tolerance, table, f"--timestamps {args.timestamps}")
    except ValueError as err:
        raise UserError(str(err)) from None
    frames = rig_frames(screened, pairing, detector_count(args), max_motion(args))
    for line in pairing_lines(pairing, names):
        info(line)
    report_screening(command, frames, names)
    empty = [c for c, refs in enumerate(frames.refs) if not refs]
    if empty:
        raise NoResult(f"camera {names[empty[0]]} ({paths[empty[0]]}): no frame of its recording was chosen for the "
                       "detector: none of its frames pairs with another camera's at the chosen instants")
    return frames


def pairing_lines(pairing, names: Sequence[str]) -> list[str]:
    """How the rig's frames were paired: by what, each camera's frames, the largest time spread of a paired frame."""
    by = {"time": "by timestamp", "index": "by frame index (the videos carry no usable timestamps)",
          "table": "by the timestamps table (its frame_index column)",
          "table order": "by the timestamps table read as caliscope reads it (each camera's rows in order of "
                         "frame_time are its video's frames; a frame_index column is not used)"}.get(pairing.by,
                                                                                                   f"by {pairing.by}")
    shared = sum(1 for f in range(pairing.num_frames) if sum(row[f] is not None for row in pairing.index) > 1)
    each = ", ".join(f"{name} {pairing.contributed(c)}" for c, name in enumerate(names))
    spread = pairing.largest_spread()
    where = "" if spread is None else f"; largest time spread of a paired frame {spread * 1000:.1f} ms"
    return [f"frames paired {by}: {pairing.num_frames} instants, {shared} of them with frames of two cameras or more "
            f"(frames per camera: {each}){where}"]
