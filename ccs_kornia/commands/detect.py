"""``ccs_kornia detect``: chessboard corners of every image, as JSON."""

from __future__ import annotations

import argparse

import numpy as np

from ccs_kornia.commands._boards import board_records
from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._messages import not_found_message
from ccs_kornia.commands._output_paths import check_outputs
from ccs_kornia.commands._run import run_files
from ccs_kornia.commands._video import add_timestamps, camera_videos, screening_note
from ccs_kornia.io.files import write_json
from ccs_kornia.outputs.records import correction_record, view_records
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["CORNER_DECIMALS", "add_corner_sigma", "run"]

#: corners are written to 1e-4 px (the float32 detections' own digits beyond that are noise, and 17 of them per
#: coordinate made the file hard to read)
CORNER_DECIMALS = 4

#: what ``calibrate``'s records hold that does not apply to corners alone (no camera: no view is used, none has an RMS,
#: no corrected-frame calibration is tried)
_CALIBRATION_ONLY = {"view": ("used", "rms"), "correction": ("tried", "applied", "decision")}


def _image_record(view: dict) -> dict:
    record = {k: v for k, v in view.items() if k not in _CALIBRATION_ONLY["view"]}
    if record.get("corners") is not None:
        record["corners"] = [[None if c is None else round(c, CORNER_DECIMALS) for c in xy] for xy in record["corners"]]
    return record


def add_corner_sigma(images: list[dict], sigma) -> None:
    """Each record with corners gets ``corner_sigma``: each corner's measured precision (px; null where not
    measured), written to float32's own digits so that a solve on the file (``--corners``) weighs its corners as the
    solve on the images does."""
    if sigma is None:
        return
    for record, row in zip(images, sigma.cpu().numpy()):
        if record.get("corners") is not None:
            record["corner_sigma"] = [None if not np.isfinite(s) else float(str(np.float32(s))) for s in row]


def run(args: argparse.Namespace) -> int:
    check_outputs(files=[("--output", args.output)])
    device = resolve_device(args.device)
    video = camera_videos("detect", args)
    files = inputs("detect", args.images) if video is None else video.names()[0]
    pipeline = make_pipeline(args)
    source = None if video is None else video.source()
    out, elapsed = run_files("detect", pipeline, [files], args.board, 1.0, device, calibrate=False, source=source)
    one = out.select(0)
    images = [_image_record(view) for view in view_records(one, files)]
    add_corner_sigma(images, one.detections.sigma)
    if video is not None:
        add_timestamps(images, video.timestamps())
    correction = {k: v for k, v in correction_record(one).items() if k not in _CALIBRATION_ONLY["correction"]}
    n_found = sum(r["found"] for r in images)
    n_partial = sum(1 for r in images if r.get("hidden_corners"))
    data = {
        "board": list(args.board),
        "image_size": [int(x) for x in one.image_size],
        "detector": args.detector,
        **board_records(args),
        "images": images,
        "skipped": [{"path": r["path"], "reason": r["reason"]} for r in images if not r["found"] and "reason" in r
                    and r["reason"].startswith("unreadable")],
        "num_found": n_found,
        "num_partial": n_partial,
        "distortion_correction": correction,
        "timings": {"load_and_detect_s": elapsed, "images_per_s": len(files) / max(elapsed, 1e-9)},
    }
    if video is not None:
        data["video"] = video.records(0)
    readable = int(one.present.sum())
    note = "" if video is None else screening_note(video)
    if not readable:  # a usage error: nothing is written
        raise UserError(not_found_message(args.board, readable, len(files), args.detector) + note)
    write_json(args.output, data)
    if n_found == 0:  # images read, no board: the per-image reasons are kept
        raise NoResult(not_found_message(args.board, readable, len(files), args.detector) + f"{note}; wrote "
                       f"{args.output}")
    partial = f" ({n_partial} partial: corners under glare or occluded are null)" if n_partial else ""
    what = (f"{args.charuco[0]}x{args.charuco[1]} ChArUco board ({args.board[0]}x{args.board[1]} inner corners)"
            if getattr(args, "charuco_board", None) else f"{args.board[0]}x{args.board[1]} board")
    if getattr(args, "aprilgrid_board", None):
        grid = args.aprilgrid_board
        what = f"{grid.tag_cols}x{grid.tag_rows} AprilGrid ({grid.num_corners} tag corners)"
    if getattr(args, "circle_board", None):
        what = f"{args.board[0]}x{args.board[1]} circle grid"
    if board_records(args):
        partial = partial.replace("corners under glare or occluded", "corners not seen")
    print(f"found the {what} in {n_found} of {len(files)} images{partial}; "
          f"wrote {args.output}")
    return 0
