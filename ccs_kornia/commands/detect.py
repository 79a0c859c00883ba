"""``ccs_kornia detect``: chessboard corners of every image, as JSON."""

from __future__ import annotations

import argparse
import time

from ccs_kornia.commands._common import (
    UserError,
    check_output_file,
    correction_record,
    detect_files,
    inputs,
    make_pipeline,
    not_found_message,
    predict_correction,
    resolve_device,
)

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    from ccs_kornia.io import write_json

    check_output_file("--output", args.output)
    device = resolve_device(args.device)
    files = inputs("detect", args.images)
    pipeline = make_pipeline(args)
    start = time.perf_counter()
    correction = None
    if pipeline.distortion_net is not None:
        correction = predict_correction("detect", files, pipeline, device, args.batch_size)
    detect_with = (correction["image_size"], correction["coeffs"]) if correction and correction["apply"] else None
    records = detect_files("detect", files, pipeline, args.board, device, args.batch_size, detect_with)
    elapsed = time.perf_counter() - start
    images = [{"path": path, **records[path]} for path in files]
    n_found = sum(r["found"] for r in images)
    data = {
        "board": list(args.board),
        "detector": args.detector,
        "images": images,
        "skipped": [{"path": r["path"], "reason": r["error"]} for r in images if "error" in r],
        "num_found": n_found,
        "distortion_correction": correction_record(
            correction, bool(detect_with), "detected on corrected images, corners given in the original images"),
        "timings": {"load_and_detect_s": elapsed, "images_per_s": len(files) / max(elapsed, 1e-9)},
    }
    write_json(args.output, data)
    if n_found == 0:
        raise UserError(not_found_message(args.board, records) + f"; wrote {args.output}")
    print(f"found the {args.board[0]}x{args.board[1]} board in {n_found} of {len(files)} images; wrote {args.output}")
    return 0
