"""The pipeline's run on a command's views: a progress bar on stderr, a wrong board named early, each view that
could not be read reported and skipped, and what the images say of a board found nowhere; for one camera, its JSON
record, or one line saying why it could not be calibrated."""

from __future__ import annotations

import functools
import sys
import time
from typing import Any

from tqdm import tqdm

from ccs_kornia.commands._messages import board_size_hint, failure_message, files_note
from ccs_kornia.commands._printing import warn
from ccs_kornia.commands._video import add_timestamps
from ccs_kornia.commands._wrong_board import WrongBoardWatch, charuco_dictionary_check
from ccs_kornia.outputs.records import camera_record
from ccs_kornia.pipeline.sources import FileSource
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["calibrate_files", "run_files"]


def run_files(command: str, pipeline, cameras: list[list[str]], board: tuple[int, int], square: float, device,
              calibrate: bool = True, names: list[str] | None = None, source=None):
    """The pipeline's one composition (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.run`) on image files, with a
    progress bar; unreadable files are reported on stderr and skipped. ``source``: the views named ``cameras``
    (video frames, :class:`~ccs_kornia.pipeline.sources.VideoSource`) instead of the files.

    Returns:
        ``(result, seconds)``: the batched :class:`~ccs_kornia.pipeline.result.PipelineResult` and the wall time.
    """
    source = FileSource(cameras, names) if source is None else source
    pipeline.to(device)
    start = time.perf_counter()
    total = sum(source.counts)
    with tqdm(total=total, unit="img", desc=command, file=sys.stderr, disable=None, leave=False) as bar:
        def advance(views: int) -> None:
            bar.update(views)
            if bar.n >= total:  # detection done; what follows can take as long (second looks at missed views)
                waiting = f"{'solving; ' if calibrate else ''}second looks at any missed views"
                bar.set_description_str(f"{command}: {waiting}")

        # a plain chessboard's wrong size is named early (a marker board's detector names it itself)
        watch = WrongBoardWatch(cameras, board, names) if getattr(pipeline.detector, "board", None) is None else None
        out = pipeline.run(source, board, square, calibrate=calibrate, progress=advance, on_batch=watch)
    seconds = time.perf_counter() - start
    for c, files in enumerate(cameras):
        reasons = (out.detections.reasons or [""] * out.present.numel())[c * out.present.shape[1]:
                                                                         (c + 1) * out.present.shape[1]]
        load = None if isinstance(source, FileSource) else functools.partial(_grey8, source, c)
        charuco_dictionary_check(pipeline, files, out.detections.found.reshape(out.present.shape)[c], out.present[c],
                                 reasons, load)
    v = out.present.shape[1]
    for c, files in enumerate(cameras):
        for k, path in enumerate(files):
            if not bool(out.present[c, k]):
                warn(command, f"skipped {path}: {out.detections.reasons[c * v + k]}")
    hint = board_size_hint(board, out.detections.reasons or [])
    if hint:
        warn(command, hint)
    return out, seconds


def calibrate_files(
    command: str,
    files: list[str],
    board: tuple[int, int],
    square: float,
    pipeline,
    device,
    model: Any,
    detector_name: str,
    video=None,
    source=None,
) -> tuple[dict[str, Any], Any]:
    """The pipeline's one composition on ``files`` (one camera); returns (JSON-ready dict, PipelineResult of it).

    ``video``: the chosen frames of the camera's recordings (:class:`~ccs_kornia.pipeline.video_input.VideoFrames`,
    ``files`` their names): the views are read from the videos, each view gets its ``timestamp`` and the record a
    ``video`` entry per recording (what the screening saw of every frame, and why a frame was not chosen).

    ``source``: the views' corners detected before (:class:`~ccs_kornia.pipeline.corners_input.CornersSource`,
    ``files`` their names): nothing is detected, each view gets its ``timestamp`` where the file gives one and the
    record the file's name (``corners_file``).

    Raises :class:`UserError` when no calibration can be computed: :class:`NoResult` when images were read, with
    ``partial``: the per-view record (detections and reasons) so the caller can keep it.
    """
    given = source
    source = video.source() if video is not None else given
    out, seconds = run_files(command, pipeline, [files], board, square, device, source=source)
    one = out.select(0)
    data = camera_record(one, files, board=board, square=square, detector=detector_name, model=model)
    if video is not None:
        add_timestamps(data["views"], video.timestamps())
        data["video"] = video.records(0)
    if given is not None:
        add_timestamps(data["views"], {name: given.timestamp(0, v) for v, name in enumerate(files)})
        data["corners_file"] = given.files[0].path
    data["timings"] = {"load_detect_solve_s": seconds, "images_per_s": len(files) / max(seconds, 1e-9)}
    for view in data["views"]:
        if view["found"] and "reason" in view and view["reason"].startswith("image size"):
            warn(command, f"skipped {view['path']}: {view['reason']}")
        if "note" in view:
            warn(command, f"{view['path']}: {view['note']}")
    for issue in data.get("warnings", []) if data["success"] else []:  # a failed camera's figures say nothing
        warn(command, issue.get("message", str(issue)) + files_note(issue))
    if not data["success"]:
        readable = int(one.present.sum())
        message = failure_message(data, board, readable)
        if not readable:
            raise UserError(message)
        err = NoResult(message)
        err.partial = data
        raise err
    return data, one


def _grey8(source, camera: int, view: int):
    """View ``view`` of ``camera`` as a grey ``uint8`` array (``None`` where it cannot be read)."""
    image, _ = source._load(camera, view)
    return None if image is None else (image[0].clamp(0, 1) * 255).round().byte().numpy()
