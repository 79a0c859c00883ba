"""``ccs_kornia calibrate-many``: many cameras (one directory of images or one video each) through Lightning's ``Trainer.predict``, on one
process or on several (DDP over processes, GPUs and nodes; ``docs/fleet.md``).

The exit status says what the output file holds for the sets given, once this run is done, so runs that end in the
same file end with the same status:

* 0: every set given has its line and at least one of them is calibrated;
* 3: every set given has its line and none is calibrated ("no set could be calibrated": no result, as ``calibrate``
  whose board is never found);
* 2: the command was refused before any work (no image set, an output file that is not calibrate-many's JSON Lines,
  ...);
* 1: some set of this run has no line (a process stopped before writing it): the same command again completes them;
* 130: interrupted (Ctrl-C); every finished line is kept and the same command again completes the rest.

The line printed on stdout says both what this run did and what the file holds.
"""

from __future__ import annotations

import argparse
import sys

import torch

from ccs_kornia.commands._boards import board_records
from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._output_paths import check_outputs
from ccs_kornia.commands._printing import PROG, info, warn
from ccs_kornia.commands._video import frame_span, make_screen, max_frames, max_motion
from ccs_kornia.fleet.shards import finished_sets, not_jsonl_reason
from ccs_kornia.io.video import is_video
from ccs_kornia.pipeline.video_input import VideoOptions
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["run"]


def _placement(args: argparse.Namespace) -> tuple[str | None, int | None]:
    """``(accelerator, devices)`` for the Trainer, refused here when this machine cannot give them."""
    accelerator, devices = args.accelerator, args.devices
    if args.device.startswith("cuda"):
        if accelerator == "cpu":
            raise UserError(f"--accelerator cpu contradicts --device {args.device}")
        if ":" in args.device and devices not in (None, 1):
            raise UserError(f"--device {args.device} names one GPU; for {devices} GPUs give --devices {devices} "
                            "--accelerator gpu (CUDA_VISIBLE_DEVICES chooses which)")
    if accelerator == "gpu" or (accelerator is None and args.device.startswith("cuda")):
        if not torch.cuda.is_available():
            raise UserError("--accelerator gpu requested but CUDA is not available on this machine; "
                            "use --accelerator cpu")
        if (devices or 1) > torch.cuda.device_count():
            raise UserError(f"--devices {devices}: only {torch.cuda.device_count()} GPU(s) on this machine")
    return accelerator, devices


def run(args: argparse.Namespace) -> int:
    check_outputs(files=[("--output", args.output)])
    device = resolve_device(args.device)
    if args.workers < 0:
        raise UserError(f"--workers must be >= 0, got {args.workers}")
    accelerator, devices = _placement(args)
    try:  # Lightning is optional: without it this command says so in one line
        from ccs_kornia.fleet.predict import (
            calibrate_many,
            find_image_sets,
            launched_as_rank_zero,
        )
    except ImportError as err:
        raise UserError(f"calibrate-many needs Lightning ({err})") from None
    overwrite = bool(getattr(args, "overwrite", False))
    if not overwrite and (reason := not_jsonl_reason(args.output)) is not None:
        raise UserError(f"--output {args.output}: {reason}; give another file name (or --overwrite to replace it)")

    sets, problems = find_image_sets(args.sets)
    if not sets:
        detail = "; ".join(f"{item}: {reason}" for item, reason in problems)
        raise UserError(f"no image sets found ({detail})")
    first = launched_as_rank_zero()
    for item, reason in problems if first else ():
        warn("calibrate-many", f"{item}: {reason}")
    pipeline = make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed)
    video = None
    if any(len(files) == 1 and is_video(files[0]) for _, files in sets):
        video = VideoOptions(make_screen(args), frame_span(args), max_frames(args), max_motion(args))
    processes = (devices or 1) * args.num_nodes
    where = f"{processes} processes ({accelerator or device.type})" if processes > 1 else str(device)
    if first:
        info(f"calibrating {len(sets)} image sets ({sum(len(f) for _, f in sets)} files) on {where} ...")
        idle = _idle_processes(sets, args.output, overwrite, args.sets_per_batch, processes)
        if idle:
            info(idle)
    summary = calibrate_many(
        sets, args.board, args.output, square=args.square, pipeline=pipeline, detector_name=args.detector,
        device=str(device), sets_per_batch=args.sets_per_batch, num_workers=args.workers, overwrite=overwrite,
        accelerator=accelerator, devices=devices, num_nodes=args.num_nodes, strategy=args.strategy,
        board_record=board_records(args),
        video=video,
    )
    if summary["rank"] != 0:
        return 0  # rank 0 reports for the run
    return _report(summary, args.output)


def _idle_processes(sets: list, output: str, overwrite: bool, per_batch: int, processes: int) -> str:
    """Why some processes will have nothing to do, and the ``--sets-per-batch`` that gives each a batch (``""`` when
    every process gets one). Each process takes whole batches of the sets left to do, the batches one process would
    form (:class:`~ccs_kornia.fleet.predict.ImageSetDataModule`): splitting them otherwise would change the lines."""
    if processes < 2:
        return ""

    done = set() if overwrite else finished_sets(output)
    todo = sum(1 for name, _ in sets if str(name) not in done)
    batches = -(-todo // per_batch)
    if todo == 0 or batches >= processes:
        return ""
    idle = processes - batches
    return (f"{todo} set{'s' if todo != 1 else ''} left to do make {batches} batch{'es' if batches != 1 else ''} "
            f"(--sets-per-batch {per_batch}) for {processes} processes: {idle} process{'es' if idle != 1 else ''} "
            f"will have nothing to do (each process takes whole batches, so the lines are those one process writes)"
            + (f"; --sets-per-batch {-(-todo // processes)} gives every process a batch" if todo >= processes else ""))


def _report(summary: dict, output: str) -> int:
    """Print what this run did and what ``output`` holds; the exit status (see the module's rule)."""
    if summary["skipped"]:
        info(f"{summary['skipped']} set(s) already in {output} were skipped (--overwrite starts again)")
    ran = summary["sets"] - summary["skipped"]
    if ran == 0:
        this_run = f"nothing to do: all {summary['sets']} sets were already in {output}"
    else:
        rate = ran / max(summary["seconds"], 1e-9)
        procs = f", {summary['world_size']} processes" if summary["world_size"] > 1 else ""
        this_run = (f"calibrated {summary['succeeded']} of {ran} sets in {summary['seconds']:.1f} s "
                    f"({rate:.2f} sets/s{procs}), {summary['failed']} failed")
    held = summary["file_succeeded"] + summary["file_failed"]
    holds = (f"{output} holds {held} of the {summary['sets']} sets: {summary['file_succeeded']} calibrated, "
             f"{summary['file_failed']} failed" + (' (reasons under "error")' if summary["file_failed"] else ""))
    print(f"{this_run}; {holds}")
    if summary["missing"]:
        print(f"{PROG} calibrate-many: error: {summary['missing']} set(s) of this run have no line (a process stopped "
              "before writing them); the same command again completes them", file=sys.stderr)
        return 1
    if summary["file_succeeded"] == 0:
        raise NoResult(f"no set could be calibrated: the {held} sets in {output} all failed (reasons under \"error\")")
    return 0
