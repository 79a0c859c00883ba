"""Rendered recordings on disk: video files, their ground truth as JSON and, for rigs, a timestamps table.

Videos are written frame by frame as they are rendered (nothing is held in memory) with OpenCV's ``VideoWriter``,
greyscale, at the camera's frame rate. The codec follows the file's suffix (:data:`VIDEO_CODECS`): ``.mp4`` MPEG-4
part 2 (``mp4v``), ``.avi`` Motion JPEG (``MJPG``), ``.mkv`` FFV1 (lossless: the decoded frames are the rendered ones
bit for bit); OpenCV's wheels carry no H.264 encoder. A container's own frame times are uniform (``index / fps``);
the frames' real times are in the ground truth and, for rigs, in ``timestamps.csv`` (``sync_index, cam_id,
frame_index, frame_time``, as caliscope writes it; ``frame_time`` the logged timestamp, seconds from the start of the
recording; ``cam_id`` the camera's index).

Ground truth (``*.json``, :func:`read_truth` reads it back as tensors): how the recording was made (camera, lens,
board and object points, the trajectory's knots, seed) and per frame, in columns: ``index``, ``frame_start``,
``frame_time``, ``timestamp``, the board's pose ``rvec``/``tvec`` at ``frame_time`` in the camera, the ``corners``
where they land with the rolling shutter (``null`` where the lens does not image them), ``corner_time``,
``visible``, ``motion`` (px over the exposure) and ``subframes``. A rig's file holds one such entry per camera and the
rig's extrinsics from camera 0 (``x_c = R_c x_0 + T_c``).

Files are written under a temporary name and renamed when complete: a failed write leaves nothing half written.

Example:
    >>> import tempfile, pathlib
    >>> from ccs_kornia.data.recordings.patterns import ChessPattern
    >>> from ccs_kornia.data.recordings.recordings import handheld_recording, webcam
    >>> rec = handheld_recording(webcam((160, 120), seed=0), ChessPattern(5, 4, 0.02), duration=0.5, seed=0)
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> paths = write_recording(rec, folder / "board.mkv")
    >>> sorted(p.name for p in paths.values()), count_video_frames(paths["video"]) == len(rec)
    (['board.json', 'board.mkv'], True)
    >>> read_truth(paths["truth"])["frames"]["corners"].shape
    torch.Size([13, 20, 2])
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable
from pathlib import Path

import torch
from torch import Tensor

from ccs_kornia.data.recordings.recordings import Recording, RigRecording

__all__ = [
    "VIDEO_CODECS",
    "count_video_frames",
    "read_truth",
    "write_recording",
    "write_rig_recording",
    "write_timestamps",
    "write_video",
]

#: the video codec (FourCC) written for each file suffix
VIDEO_CODECS: dict[str, str] = {".mp4": "mp4v", ".avi": "MJPG", ".mkv": "FFV1"}


def _temporary(path: Path) -> Path:
    return path.with_name(f".{path.stem}.partial{path.suffix}")


def write_video(frames: Iterable[Tensor], path: str | Path, fps: float, image_size: tuple[int, int],
                codec: str | None = None) -> int:
    """Write greyscale frames :math:`(H, W)` uint8 to a video file as they come; returns how many were written.

    Args:
        frames: the frames (tensors or arrays), consumed one at a time.
        path: the video's path; its suffix chooses the codec (:data:`VIDEO_CODECS`) unless ``codec`` is given.
        fps: frame rate of the container.
        image_size: ``(W, H)``.
        codec: a FourCC such as ``"mp4v"``, ``"MJPG"``, ``"FFV1"``.

    Raises:
        ValueError: no codec for the suffix, or OpenCV cannot write it here.
    """
    import cv2
    import numpy as np

    path = Path(path)
    fourcc = codec or VIDEO_CODECS.get(path.suffix.lower())
    if fourcc is None:
        raise ValueError(f"no video codec for {path.suffix!r}; use one of {', '.join(VIDEO_CODECS)} or give a codec")
    tmp = _temporary(path)
    w, h = int(image_size[0]), int(image_size[1])
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), float(fps), (w, h), False)
    if not writer.isOpened():
        tmp.unlink(missing_ok=True)
        raise ValueError(f"OpenCV cannot write {fourcc!r} video to {path.name} here (codecs that work: "
                         f"{', '.join(f'{v} in {k}' for k, v in VIDEO_CODECS.items())})")
    count = 0
    try:
        for frame in frames:
            img = frame.numpy() if isinstance(frame, Tensor) else np.asarray(frame)
            if img.shape != (h, w) or img.dtype != np.uint8:
                raise ValueError(f"frames must be ({h}, {w}) uint8, got {img.shape} {img.dtype}")
            writer.write(np.ascontiguousarray(img))
            count += 1
        writer.release()
        os.replace(tmp, path)
    except BaseException:
        writer.release()
        tmp.unlink(missing_ok=True)
        raise
    return count


def _listed(t: Tensor, decimals: int | None = None) -> list:
    """A tensor as nested lists, NaN as ``None``, rounded to ``decimals``."""
    if t.dtype == torch.bool or not t.is_floating_point():
        return t.tolist()
    x = t.double()
    if decimals is not None:
        x = x.round(decimals=decimals)

    def clean(v):
        if isinstance(v, list):
            return [clean(u) for u in v]
        return None if math.isnan(v) else v

    return clean(x.tolist())


def _truth_json(rec: Recording, video: str | None) -> dict:
    tr = rec.truth
    frames = {
        "index": list(range(len(rec))), "frame_start": _listed(tr.frame_start, 9), "frame_time": _listed(tr.frame_time, 9),
        "timestamp": _listed(rec.timestamp, 9), "rvec": _listed(tr.rvec, 9), "tvec": _listed(tr.tvec, 9),
        "corners": _listed(tr.corners, 6), "corner_time": _listed(tr.corner_time, 9), "visible": _listed(tr.visible),
        "motion": _listed(tr.motion, 4), "subframes": _listed(tr.subframes),
    }
    return {"video": video, **rec.to_json(), "frames": frames}


def _write_json(data: dict, path: Path) -> None:
    tmp = _temporary(path)
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, allow_nan=False)
            fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _frames(rec: Recording, progress: bool, label: str):
    it = (img for _, img in rec.frames())
    if progress:
        from tqdm import tqdm

        it = tqdm(it, total=len(rec), desc=label, unit="frame")
    return it


def write_recording(rec: Recording, path: str | Path, codec: str | None = None,
                    progress: bool = False) -> dict[str, Path]:
    """Render a recording into a video file and write its ground truth beside it (same name, ``.json``).

    Args:
        rec: the recording.
        path: the video's path (its suffix chooses the codec, :data:`VIDEO_CODECS`).
        codec: a FourCC instead.
        progress: show a progress bar.

    Returns:
        ``{"video": path, "truth": path}``.
    """
    path = Path(path)
    truth = path.with_suffix(".json")
    data = _truth_json(rec, path.name)  # the truth first: it fails fast where the video would take minutes
    write_video(_frames(rec, progress, path.name), path, rec.camera.fps, rec.camera.image_size, codec)
    _write_json(data, truth)
    return {"video": path, "truth": truth}


def write_timestamps(rows: Iterable[tuple[int, int, int, float]], path: str | Path) -> None:
    """Write a timestamps table ``sync_index,cam_id,frame_index,frame_time`` (:meth:`RigRecording.sync_table`)."""
    path = Path(path)
    tmp = _temporary(path)
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            out = csv.writer(fh)
            out.writerow(["sync_index", "cam_id", "frame_index", "frame_time"])
            for s, c, f, t in rows:
                out.writerow([int(s), int(c), int(f), f"{float(t):.6f}"])
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_rig_recording(rig: RigRecording, folder: str | Path, suffix: str = ".mp4", codec: str | None = None,
                        progress: bool = False) -> dict[str, Path | list[Path]]:
    """Render a rig's recording into ``folder``: ``cam_{c}{suffix}`` per camera, ``timestamps.csv`` and
    ``truth.json``.

    Returns:
        ``{"videos": [paths], "timestamps": path, "truth": path}``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    videos = [folder / f"cam_{c}{suffix}" for c in range(len(rig))]
    R, T = rig.extrinsics
    data = {"cameras": [_truth_json(r, v.name) for r, v in zip(rig.recordings, videos)], "R": R.tolist(),
            "T": T.tolist(), "timestamps": "timestamps.csv"}
    for rec, video in zip(rig.recordings, videos):
        write_video(_frames(rec, progress, video.name), video, rec.camera.fps, rec.camera.image_size, codec)
    write_timestamps(rig.sync_table(), folder / "timestamps.csv")
    _write_json(data, folder / "truth.json")
    return {"videos": videos, "timestamps": folder / "timestamps.csv", "truth": folder / "truth.json"}


def _tensors(frames: dict) -> dict:
    out = {}
    for k, v in frames.items():
        if k == "visible":
            out[k] = torch.tensor(v, dtype=torch.bool)
        elif k in ("index", "subframes"):
            out[k] = torch.tensor(v, dtype=torch.long)
        else:
            out[k] = torch.tensor(_nan(v), dtype=torch.float64)
    return out


def _nan(v):
    if isinstance(v, list):
        return [_nan(u) for u in v]
    return math.nan if v is None else v


def read_truth(path: str | Path) -> dict:
    """A ground-truth file of :func:`write_recording` or :func:`write_rig_recording`, with every frame column (and
    a rig's ``R``, ``T``) as tensors (``null`` corners as NaN)."""
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    entries = data.get("cameras", [data])
    for entry in entries:
        entry["frames"] = _tensors(entry["frames"])
    if "cameras" in data:
        data["R"], data["T"] = torch.tensor(data["R"]), torch.tensor(data["T"])
    return data


def count_video_frames(path: str | Path) -> int:
    """Frames OpenCV decodes from a video file (read through, not the container's claim)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    n = 0
    try:
        while cap.grab():
            n += 1
    finally:
        cap.release()
    return n
