"""What the commands do with the frame selection: on request (``--select``) for recordings and folders alike, and the
frames kept written as images (``--save-frames``) so the same set can be calibrated again as a folder."""

from __future__ import annotations

import argparse
import os
import shutil
from collections.abc import Sequence

import cv2

from ccs_kornia.commands._printing import info
from ccs_kornia.commands._video import max_frames, selecting
from ccs_kornia.pipeline.frame_selection import FrameSelection
from ccs_kornia.pipeline.sources import FileSource
from ccs_kornia.runtime.errors import UserError

__all__ = ["frame_selection", "save_frames", "selecting", "selection_line"]


def frame_selection(args: argparse.Namespace):
    """The :class:`~ccs_kornia.pipeline.frame_selection.FrameSelection` the arguments ask for (``None``: every view
    counts); ``--max-frames`` caps the frames kept."""
    if not selecting(args):
        return None

    return FrameSelection(max_frames=max_frames(args))


def _stem(name: str) -> str:
    """A frame's file name stem: ``cam.mp4#412`` -> ``cam_000412``, ``IMG_1.JPG`` -> ``IMG_1``."""
    base = os.path.basename(name)
    video, sep, index = base.rpartition("#")
    if sep and index.isdigit():
        return f"{os.path.splitext(video)[0]}_{int(index):06d}"
    return os.path.splitext(base)[0]


def save_frames(folder: str, source, kept: Sequence[Sequence[bool]], names: Sequence[str] | None = None,
                labels: Sequence[Sequence[str]] | None = None) -> int:
    """Write each camera's kept views to ``folder`` (a rig's cameras to ``folder/NAME``): a file as it is (copied), a
    video frame as a grey PNG named after the video and the frame (a rig's after the instant, so the folders pair by
    the number in the names as ``calibrate-rig`` pairs them). Each file is written under a temporary name and renamed.

    Args:
        folder: the output folder (created).
        source: the run's :class:`~ccs_kornia.pipeline.sources.ViewSource` (files or video frames).
        kept: per camera, per view, whether it was kept.
        names: camera names (a rig: one sub-folder each); ``None``: one camera, straight into ``folder``.
        labels: per camera, per view, a file stem (a rig's instant) instead of the view's own name.

    Returns:
        Files written.
    """
    count = 0
    for c, keep in enumerate(kept):
        where = folder if names is None else os.path.join(folder, names[c])
        try:
            os.makedirs(where, exist_ok=True)
        except OSError as err:
            raise UserError(f"--save-frames {folder}: cannot create {where} ({err.strerror or err})") from None
        for v, keep_view in enumerate(keep):
            if not keep_view:
                continue
            stem = labels[c][v] if labels is not None else _stem(source.describe(c, v))
            if isinstance(source, FileSource):
                path = source.paths[c][v]
                target = os.path.join(where, stem + os.path.splitext(path)[1])
                tmp = os.path.join(where, f".{stem}.partial{os.path.splitext(path)[1]}")
                shutil.copyfile(path, tmp)
            else:
                image, reason = source._load(c, v)
                if image is None:
                    info(f"--save-frames: {source.describe(c, v)} not written ({reason})")
                    continue
                target = os.path.join(where, stem + ".png")
                tmp = os.path.join(where, f".{stem}.partial.png")
                if not cv2.imwrite(tmp, (image[0].clamp(0, 1) * 255).round().byte().numpy()):
                    raise UserError(f"--save-frames {folder}: cannot write {target}")
            os.replace(tmp, target)
            count += 1
    return count


def selection_line(record: dict) -> str:
    """``frame selection: kept 38 of 90 candidate frames (left out: 24 add nothing, 12 moving, ...); predicted
    projection uncertainty 0.081 px`` from the JSON's ``selection``."""
    counts: dict[str, int] = {}
    for frame in record.get("frames", []):
        why = frame.get("reason")
        if why:
            key = why.split(" (")[0]
            key = "near copies" if key.startswith("near copy") else key
            counts[key] = counts.get(key, 0) + 1
    words = {"adds nothing": "add nothing", "moving": "moving", "blurred": "blurred", "near copies": "near copies"}
    left = ", ".join(f"{n} {words.get(k, k)}" for k, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    line = f"frame selection: kept {record['kept']} of {record['candidates']} candidate frames"
    line += f" (left out: {left})" if left else ""
    finals = [cam[-1] for cam in record.get("uncertainty_px", []) if cam]
    if finals:
        line += f"; predicted projection uncertainty {max(finals):.3f} px"
    return line
