"""Recordings in: the screened videos of a camera or a rig, their frames paired across cameras, the frames chosen for
the full detector, and the :class:`~ccs_kornia.pipeline.sources.VideoSource` of them.

The steps between the screening pass (:mod:`~ccs_kornia.pipeline.screening`) and the pipeline's loop
(:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline`,
:class:`~ccs_kornia.pipeline.rig_pipeline.RigPipeline`):

* :func:`pair_videos`: a rig's frames paired into instants, by a timestamps table where one is given, else by the
  frames' timestamps within a tolerance (half the shortest frame period by default), else by frame index (videos
  without usable timestamps, which must then run at one rate);
* :func:`camera_frames` / :func:`rig_frames`: the frame choice (:func:`~ccs_kornia.pipeline.frame_candidates.choose_frames`)
  and the views it gives, as a :class:`VideoFrames` that also keeps, per screened frame, what the screen saw and why
  the frame was or was not chosen (:meth:`VideoFrames.records`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ccs_kornia.io.timestamps import TimestampRow
from ccs_kornia.io.video import FrameSpan
from ccs_kornia.pipeline.frame_candidates import (
    DEFAULT_MAX_FRAMES,
    MAX_MOVING_MOTION,
    FrameChoice,
    board_motion,
    choose_frames,
)
from ccs_kornia.pipeline.frame_matching import (
    FrameTable,
    match_by_index,
    match_by_table,
    match_by_time,
)
from ccs_kornia.pipeline.screening import ScreenedVideo
from ccs_kornia.pipeline.sources import VideoFrameRef, VideoSource

__all__ = ["VideoFrames", "VideoOptions", "camera_frames", "default_tolerance", "load_video_set", "pair_videos",
           "rig_frames"]

#: frame rates within this fraction of each other count as one rate
SAME_RATE = 0.01


def _period(video: ScreenedVideo) -> float | None:
    """Seconds between the video's frames: the container's rate, else the screened frames' median step."""
    if video.info.period is not None:
        return video.info.period
    steps = sorted(b.timestamp - a.timestamp for a, b in zip(video.frames, video.frames[1:]))
    every = max(1, int(video.span.every))
    return steps[len(steps) // 2] / every if steps and steps[len(steps) // 2] > 0 else None


def _speed(motion: float | None, video: ScreenedVideo) -> float | None:
    """The board's speed (px/s) from its motion per frame period (:func:`~ccs_kornia.pipeline.frame_candidates.
    board_motion`)."""
    period = _period(video)
    return None if motion is None or not period else float(motion) / period


def default_tolerance(videos: Sequence[ScreenedVideo]) -> float:
    """Half the shortest frame period of ``videos`` (1/60 s where no video states a rate)."""
    periods = [p for p in (_period(v) for v in videos) if p is not None]
    return 0.5 * min(periods) if periods else 1.0 / 60.0


def _name(path: str) -> str:
    return os.path.basename(path)


def pair_videos(videos: Sequence[ScreenedVideo], tolerance: float | None = None,
                table: Sequence[TimestampRow] | None = None, table_name: str = "the timestamps table") -> FrameTable:
    """A rig's screened frames paired into instants (:class:`~ccs_kornia.pipeline.frame_matching.FrameTable`, the
    positions in each video's screened frames).

    Args:
        videos: one screened video per camera.
        tolerance: seconds between paired frames at most (``None``: :func:`default_tolerance`); by time only.
        table: a timestamps table's rows (:func:`~ccs_kornia.io.timestamps.read_timestamps`): pairs as it says.
        table_name: the table's name in messages.

    Raises:
        ValueError: the table does not match the videos; videos without usable timestamps at different rates; no
            frame of one camera within the tolerance of another's (recordings that do not overlap); one line.
    """
    indices = [[f.index for f in v.frames] for v in videos]
    times = [v.timestamps for v in videos]
    if table is not None:
        return match_by_table(table, indices, [v.length for v in videos], table_name)
    if all(v.timestamps_usable for v in videos):
        tolerance = default_tolerance(videos) if tolerance is None else float(tolerance)
        out = match_by_time(times, tolerance)
        if len(videos) > 1 and not any(sum(row[f] is not None for row in out.index) > 1 for f in range(out.num_frames)):
            spans = ", ".join(f"{_name(v.path)} {v.frames[0].timestamp:.2f}-{v.frames[-1].timestamp:.2f} s"
                              for v in videos if v.frames)
            raise ValueError(f"no two videos have frames within {tolerance:.4g} s of each other ({spans}): the "
                             "recordings do not overlap in time; give --timestamps (a table of the frames taken "
                             "together) or a larger --sync-tolerance")
        return out
    rates = [v.info.fps for v in videos]
    if min(rates) <= 0 or max(rates) > min(rates) * (1 + SAME_RATE):
        listed = ", ".join(f"{_name(v.path)} {v.info.fps:.3g} fps" for v in videos)
        raise ValueError(f"the videos carry no usable timestamps and their frame rates differ ({listed}): their "
                         "frames cannot be paired by index; give --timestamps (a table of the frames taken together)")
    return match_by_index(indices, times)


@dataclass
class VideoFrames:
    """A camera's or a rig's videos after the frame choice.

    Attributes:
        videos: the screened videos (one per camera for a rig; any number for one camera).
        refs: per camera, the chosen frames: the pipeline's views (:meth:`source`).
        table: a rig's chosen instants (positions in ``refs``); ``None`` for one camera.
        pairing: a rig's screened frames paired into instants (``None`` for one camera).
        choice: the frame choice over the instants (one camera: its frames in order, video after video).
        chosen: per camera, per video, per screened frame, whether the frame is a view.
        reasons, motion: per camera, per video, per screened frame, why it is not a view (``""``: it is, or no board)
            and the board's motion (px per frame period).
        owner: one camera: per instant of the choice, its (video, screened frame); ``None`` for a rig.
    """

    videos: list[ScreenedVideo]
    refs: list[list[VideoFrameRef]]
    table: FrameTable | None
    pairing: FrameTable | None
    choice: FrameChoice
    chosen: list[list[list[bool]]]
    reasons: list[list[list[str]]]
    motion: list[list[list[float | None]]]
    owner: list[tuple[int, int]] | None = None

    def source(self, names: Sequence[str] | None = None) -> VideoSource:
        """The chosen frames as the pipeline's views."""
        return VideoSource(self.refs, names, {v.path: v.info.size for v in self.videos})

    def names(self) -> list[list[str]]:
        """Per camera, its views' names (``VIDEO#INDEX``)."""
        return [[r.name for r in refs] for refs in self.refs]

    def timestamps(self) -> dict[str, float | None]:
        """Every view's timestamp by its name."""
        return {r.name: r.timestamp for refs in self.refs for r in refs}

    def moving(self, camera: int) -> list[list[bool]]:
        """Per video of ``camera``, per screened frame: chosen although its board moves (the still frames did not
        cover the poses, or too few were still: :func:`~ccs_kornia.pipeline.frame_candidates.choose_frames`)."""
        taken = set(self.choice.moving or [])
        out = [[False] * len(v.frames) for v in (self.videos if self.table is None else [self.videos[camera]])]
        for i in taken:
            for v, k in self._frames_of(camera, i):
                out[v][k] = bool(self.chosen[camera][v][k])
        return out

    def _frames_of(self, camera: int, instant: int) -> list[tuple[int, int]]:
        """(video, screened frame) of ``camera`` at a choice's ``instant``."""
        if self.pairing is None:
            return [self.owner[instant]]
        k = self.pairing.index[camera][instant]
        return [] if k is None else [(0, k)]

    def still_gate(self, camera: int) -> dict:
        """What the still gate did for ``camera``: ``still_frames`` (frames whose board moved at most the still
        motion), ``still_spread_deg`` (the largest angle between their board planes, from the rough outlines),
        ``chosen_moving`` (frames chosen although moving); ``None`` figures where the choice kept every frame."""
        still = None if self.choice.still is None else self.choice.still[camera]
        spread = None if self.choice.still_spread_deg is None else self.choice.still_spread_deg[camera]
        return {"still_frames": still, "still_spread_deg": None if spread is None else round(float(spread), 1),
                "chosen_moving": sum(sum(v) for v in self.moving(camera))}

    def records(self, camera: int) -> list[dict]:
        """Per video of ``camera``, what the screening saw and what the choice made of it: the JSON's ``video``
        entries (``frames``: per screened frame ``index``, ``timestamp``, ``board``, ``outline`` (px, rough),
        ``motion_px`` (per frame period), ``chosen``, ``moving`` (chosen although moving), ``reason``; and
        :meth:`still_gate`'s figures, the camera's over all its videos, and ``chosen_moving`` of the video)."""
        videos = self.videos if self.table is None else [self.videos[camera]]
        moving = self.moving(camera)
        gate = self.still_gate(camera)
        out = []
        for v, video in enumerate(videos):
            frames = []
            for k, f in enumerate(video.frames):
                seen = f.sighting
                motion = self.motion[camera][v][k]
                record = {"index": f.index, "timestamp": round(f.timestamp, 6), "board": bool(seen.found),
                          "outline": None if seen.outline is None else [[round(float(x), 1) for x in p]
                                                                        for p in seen.outline],
                          "motion_px": None if motion is None else round(float(motion), 2),
                          "chosen": self.chosen[camera][v][k]}
                if moving[v][k]:
                    record["moving"] = True
                if self.reasons[camera][v][k]:
                    record["reason"] = self.reasons[camera][v][k]
                frames.append(record)
            info = video.info
            out.append({"path": video.path, "size": [info.width, info.height], "fps": info.fps or None,
                        "frames_stated": info.frame_count or None, "frames_decoded": video.length,
                        "every": video.span.every, "start": video.span.start, "end": video.span.end,
                        "frames_screened": len(video.frames), "board_seen": video.found,
                        "chosen": sum(self.chosen[camera][v]), "chosen_moving": sum(moving[v]),
                        "still_frames": gate["still_frames"], "still_spread_deg": gate["still_spread_deg"],
                        "screening_s": round(video.seconds, 3),
                        "stopped": video.stopped or None, "frames": frames})
        return out


def _moving_fraction(max_motion_px: float | None, sizes: Sequence[tuple[int, int]]) -> list[float]:
    """Per camera the fastest moving frame admitted, as a fraction of its image diagonal per frame period
    (``max_motion_px``: px per frame period; ``None``: :data:`~ccs_kornia.pipeline.frame_candidates.MAX_MOVING_MOTION`)."""
    if max_motion_px is None:
        return [MAX_MOVING_MOTION] * len(sizes)
    return [float(max_motion_px) / math.hypot(*size) for size in sizes]


def camera_frames(videos: Sequence[ScreenedVideo], max_frames: int = DEFAULT_MAX_FRAMES,
                  max_motion_px: float | None = None) -> VideoFrames:
    """The frame choice for one camera's videos (their frames in order, video after video); ``max_motion_px``: the
    fastest moving frame (px per frame period) taken where the still frames do not cover the poses (``None``: the
    default of :func:`~ccs_kornia.pipeline.frame_candidates.choose_frames`).

    Example:
        >>> from ccs_kornia.io.video import FrameSpan, VideoInfo
        >>> from ccs_kornia.modules.detection.screening import Sighting
        >>> from ccs_kornia.pipeline.screening import ScreenedFrame
        >>> import numpy as np
        >>> box = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0], [0.0, 30.0]])
        >>> frames = [ScreenedFrame(k, k / 10, Sighting(k != 1, None if k == 1 else box)) for k in range(3)]
        >>> v = ScreenedVideo(VideoInfo("a.mp4", 640, 480, 10.0, 3), FrameSpan(), frames, length=3)
        >>> out = camera_frames([v])  # no more frames than max_frames: every frame goes to the detector
        >>> out.names(), [(f["board"], f["chosen"]) for f in out.records(0)[0]["frames"]]
        ([['a.mp4#0', 'a.mp4#1', 'a.mp4#2']], [(True, True), (False, True), (True, True)])
        >>> # frame 2 is a copy of frame 0's still pose: it fills what is left of max_frames
        >>> [f.get("reason") for f in camera_frames([v], max_frames=2).records(0)[0]["frames"]]
        [None, 'no board at screening', None]
    """
    sightings, labels, motion, owner = [], [], [], []
    several = len({v.path for v in videos}) > 1
    for v, video in enumerate(videos):
        seen = [f.sighting for f in video.frames]
        sightings += seen
        labels += [f"{_name(video.path)}#{f.index}" if several else str(f.index) for f in video.frames]
        motion += board_motion([f.index for f in video.frames], seen)
        owner += [(v, k) for k in range(len(video.frames))]
    size = videos[0].info.size if videos else (1, 1)
    choice = choose_frames([sightings], [labels], [motion], [size], max_frames,
                           max_moving=_moving_fraction(max_motion_px, [size]))
    chosen = [[[False] * len(v.frames) for v in videos]]
    reasons = [[[""] * len(v.frames) for v in videos]]
    motions = [[[None] * len(v.frames) for v in videos]]
    for i, (v, k) in enumerate(owner):
        reasons[0][v][k] = choice.reasons[0][i]
        motions[0][v][k] = motion[i]
    refs = []
    for i in choice.chosen:
        v, k = owner[i]
        chosen[0][v][k] = True
        frame = videos[v].frames[k]
        refs.append(VideoFrameRef(videos[v].path, frame.index, frame.timestamp, _speed(motion[i], videos[v])))
    return VideoFrames(list(videos), [refs], None, None, choice, chosen, reasons, motions, owner)


def rig_frames(videos: Sequence[ScreenedVideo], pairing: FrameTable,
               max_frames: int = DEFAULT_MAX_FRAMES, max_motion_px: float | None = None) -> VideoFrames:
    """The frame choice for a rig (one video per camera) over the instants of ``pairing`` (:func:`pair_videos`);
    ``max_motion_px`` as :func:`camera_frames`.

    Where every instant is kept (at most ``max_frames``), each camera's frame of it is a view; where instants are
    chosen, a camera's frame is a view where its screen saw the board, or where it saw the board in no frame. Frames the pairing left out (not in a
    timestamps table) are never views.
    """
    c, n = len(videos), pairing.num_frames
    motion_of = [board_motion([f.index for f in v.frames], [f.sighting for f in v.frames]) for v in videos]
    sightings = [[None if k is None else videos[cam].frames[k].sighting for k in pairing.index[cam]] for cam in range(c)]
    labels = [[None if k is None else str(videos[cam].frames[k].index) for k in pairing.index[cam]] for cam in range(c)]
    motion = [[None if k is None else motion_of[cam][k] for k in pairing.index[cam]] for cam in range(c)]
    sizes = [v.info.size for v in videos]
    choice = choose_frames(sightings, labels, motion, sizes, max_frames, frame_rates=[v.info.fps for v in videos],
                           max_moving=_moving_fraction(max_motion_px, sizes))
    every = n <= max_frames
    # a camera whose screen saw the board nowhere: its frames of the chosen instants go to the detector all the same
    # (the quick look may miss a board the detector finds)
    blind = [not any(f.found for f in v.frames) for v in videos]
    chosen = [[[False] * len(v.frames)] for v in videos]
    reasons = [[["not in the timestamps table" if pairing.by.startswith("table") else ""] * len(v.frames)] for v in videos]
    motions = [[list(m)] for m in motion_of]
    for cam in range(c):
        for f, k in enumerate(pairing.index[cam]):
            if k is not None:
                reasons[cam][0][k] = choice.reasons[cam][f]
    refs: list[list[VideoFrameRef]] = [[] for _ in range(c)]
    index: list[list[int | None]] = [[] for _ in range(c)]
    labels_out, times_out = [], [[] for _ in range(c)]
    for f in choice.chosen:
        picks = []
        for cam in range(c):
            k = pairing.index[cam][f]
            use = k is not None and (every or blind[cam] or videos[cam].frames[k].found)
            picks.append(k if use else None)
        if all(k is None for k in picks):
            continue
        labels_out.append(pairing.labels[f])
        for cam, k in enumerate(picks):
            if k is None:
                index[cam].append(None)
                times_out[cam].append(None)
                continue
            frame = videos[cam].frames[k]
            chosen[cam][0][k] = True
            index[cam].append(len(refs[cam]))
            refs[cam].append(VideoFrameRef(videos[cam].path, frame.index, frame.timestamp,
                                           _speed(motion_of[cam][k], videos[cam])))
            times_out[cam].append(pairing.times[cam][f] if pairing.times is not None else frame.timestamp)
    table = FrameTable(labels_out, index, pairing.by, times_out)
    return VideoFrames(list(videos), refs, table, pairing, choice, chosen, reasons, motions)


@dataclass(frozen=True)
class VideoOptions:
    """How a camera's recording becomes views: the screen (:class:`~ccs_kornia.modules.detection.screening.BoardScreen`),
    the frames read (:class:`~ccs_kornia.io.video.FrameSpan`), the frames kept at most and the fastest moving frame
    taken (px per frame period, :func:`camera_frames`)."""

    screen: Any
    span: FrameSpan = FrameSpan()
    max_frames: int = DEFAULT_MAX_FRAMES
    max_motion_px: float | None = None


def load_video_set(path: str, options: VideoOptions) -> dict[str, Any]:
    """One recording as an in-memory set of views (``calibrate-many``'s sets): screened in this process, its frames
    chosen and decoded.

    Returns:
        ``{"files": names, "images": [(1, H, W) uint8 tensor or reason], "timestamps": {name: s}, "video": records}``;
        an unreadable video gives no view and ``"error"``: why.
    """
    import torch

    from ccs_kornia.pipeline.screening import screen_video

    try:
        screened = screen_video(path, options.screen, options.span)
    except ValueError as err:
        return {"files": [], "images": [], "timestamps": {}, "video": [], "error": str(err)}
    frames = camera_frames([screened], options.max_frames, options.max_motion_px)
    source = frames.source()
    images: list[Any] = []
    for k, ref in enumerate(frames.refs[0]):
        image, reason = source._load(0, k)
        images.append(reason if image is None else (image * 255).round().to(torch.uint8))
    source.close()
    return {"files": frames.names()[0], "images": images, "timestamps": frames.timestamps(),
            "video": frames.records(0)}
