"""``ccs_kornia calibrate-many``: many cameras (one directory each) through Lightning's ``Trainer.predict``."""

from __future__ import annotations

import argparse

from ccs_kornia.commands._common import UserError, check_output_file, info, make_pipeline, resolve_device, warn

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    check_output_file("--output", args.output)
    device = resolve_device(args.device)
    if args.workers < 0:
        raise UserError(f"--workers must be >= 0, got {args.workers}")
    try:
        from ccs_kornia.predict import calibrate_many, find_image_sets
    except ImportError as err:
        raise UserError(f"calibrate-many needs Lightning ({err})") from None
    sets, problems = find_image_sets(args.sets)
    if not sets:
        detail = "; ".join(f"{item}: {reason}" for item, reason in problems)
        raise UserError(f"no image sets found ({detail})")
    for item, reason in problems:
        warn("calibrate-many", f"{item}: {reason}")
    pipeline = make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed)
    info(f"calibrating {len(sets)} image sets ({sum(len(f) for _, f in sets)} files) on {device} ...")
    summary = calibrate_many(
        sets, args.board, args.output, square=args.square, pipeline=pipeline, detector_name=args.detector,
        device=str(device), sets_per_batch=args.sets_per_batch, num_workers=args.workers,
    )
    if summary["succeeded"] == 0:
        raise UserError(f"no set could be calibrated ({summary['failed']} failed; reasons in {args.output})")
    rate = summary["sets"] / max(summary["seconds"], 1e-9)
    print(
        f"calibrated {summary['succeeded']} of {summary['sets']} sets in {summary['seconds']:.1f} s "
        f"({rate:.2f} sets/s); {summary['failed']} failed (see \"error\" in {args.output}); wrote {args.output}"
    )
    return 0
