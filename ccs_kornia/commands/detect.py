"""``ccs_kornia detect``: chessboard corners of every image, as JSON."""

from __future__ import annotations

import argparse
from ccs_kornia.commands._common import (
    UserError,
    check_output_file,
    inputs,
    make_pipeline,
    not_found_message,
    resolve_device,
    run_files,
)

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    from ccs_kornia.io import write_json
    from ccs_kornia.records import correction_record, view_records

    check_output_file("--output", args.output)
    device = resolve_device(args.device)
    files = inputs("detect", args.images)
    pipeline = make_pipeline(args)
    out, elapsed = run_files("detect", pipeline, [files], args.board, 1.0, device, calibrate=False)
    one = out.select(0)
    images = view_records(one, files)
    n_found = sum(r["found"] for r in images)
    n_partial = sum(1 for r in images if r.get("hidden_corners"))
    data = {
        "board": list(args.board),
        "detector": args.detector,
        "images": images,
        "skipped": [{"path": r["path"], "reason": r["reason"]} for r in images if not r["found"] and "reason" in r
                    and r["reason"].startswith("unreadable")],
        "num_found": n_found,
        "num_partial": n_partial,
        "distortion_correction": correction_record(one),
        "timings": {"load_and_detect_s": elapsed, "images_per_s": len(files) / max(elapsed, 1e-9)},
    }
    write_json(args.output, data)
    if n_found == 0:
        raise UserError(not_found_message(args.board, int(one.present.sum()), len(files)) + f"; wrote {args.output}")
    partial = f" ({n_partial} partial: corners under glare or occluded are null)" if n_partial else ""
    print(f"found the {args.board[0]}x{args.board[1]} board in {n_found} of {len(files)} images{partial}; "
          f"wrote {args.output}")
    return 0
