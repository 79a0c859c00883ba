"""The pipeline's run on a command's views: a progress bar on stderr, a wrong board named early, each view that
could not be read reported and skipped, and what the images say of a board found nowhere."""

from __future__ import annotations

import functools
import sys

from ccs_kornia.commands._messages import board_size_hint
from ccs_kornia.commands._printing import warn
from ccs_kornia.commands._wrong_board import WrongBoardWatch, charuco_dictionary_check

__all__ = ["run_files"]


def run_files(command: str, pipeline, cameras: list[list[str]], board: tuple[int, int], square: float, device,
              calibrate: bool = True, names: list[str] | None = None, source=None):
    """The pipeline's one composition (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.run`) on image files, with a
    progress bar; unreadable files are reported on stderr and skipped. ``source``: the views named ``cameras``
    (video frames, :class:`~ccs_kornia.pipeline.sources.VideoSource`) instead of the files.

    Returns:
        ``(result, seconds)``: the batched :class:`~ccs_kornia.pipeline.result.PipelineResult` and the wall time.
    """
    import time

    from tqdm import tqdm

    from ccs_kornia.pipeline.sources import FileSource

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


def _grey8(source, camera: int, view: int):
    """View ``view`` of ``camera`` as a grey ``uint8`` array (``None`` where it cannot be read)."""
    image, _ = source._load(camera, view)
    return None if image is None else (image[0].clamp(0, 1) * 255).round().byte().numpy()
