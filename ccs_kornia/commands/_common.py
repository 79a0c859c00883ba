"""What the commands share: the user-error type, messages, devices, output checks, streaming detection."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import Any

__all__ = [
    "PROG",
    "UserError",
    "warn",
    "info",
    "resolve_device",
    "check_output_file",
    "make_dir",
    "inputs",
    "make_pipeline",
    "detect_files",
    "not_found_message",
    "predict_correction",
    "correction_record",
]

PROG = "ccs_kornia"


class UserError(Exception):
    """A mistake in the user's input that stops the command (exit status 2).

    ``partial`` may hold what was computed before the job had to stop (written by the command).
    """

    partial: dict[str, Any] | None = None


def warn(command: str, message: str) -> None:
    print(f"{PROG} {command}: warning: {message}", file=sys.stderr)


def info(message: str) -> None:
    print(message, file=sys.stderr)


def resolve_device(text: str):
    import torch

    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            raise UserError(f"--device {text} requested but CUDA is not available on this machine; use --device cpu")
        index = int(text[5:]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise UserError(f"--device {text}: only {torch.cuda.device_count()} CUDA device(s) present")
    return torch.device(text)


def check_output_file(option: str, path: str) -> None:
    directory = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise UserError(f"{option} {path} is a directory; give a file name")
    if not os.path.isdir(directory):
        raise UserError(f"{option} {path}: output directory {directory} does not exist (create it first)")
    if not os.access(directory, os.W_OK):
        raise UserError(f"{option} {path}: output directory {directory} is not writable")


def make_dir(option: str, path: str) -> None:
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot create directory ({err.strerror or err})") from None
    if not os.path.isdir(path):
        raise UserError(f"{option} {path} exists and is not a directory")


def inputs(command: str, items: Sequence[str]) -> list[str]:
    from ccs_kornia.io import expand_inputs

    files, problems = expand_inputs(items)
    if not files:
        detail = "; ".join(f"{item}: {reason}" for item, reason in problems) or "nothing given"
        raise UserError(f"no images found ({detail})")
    for item, reason in problems:
        warn(command, f"{item}: {reason}")
    return files


def make_pipeline(args: argparse.Namespace, model: str = "opencv5", use_ransac: bool = True, seed: int = 0):
    from ccs_kornia.modules.detection.factory import make_detector
    from ccs_kornia.pipeline import CalibrationPipeline

    try:
        detector = make_detector(args.detector)
    except ValueError as err:
        raise UserError(str(err)) from None
    try:
        return CalibrationPipeline(
            detector, model=model, use_ransac=use_ransac, seed=seed, detection_batch_size=args.batch_size,
            max_detection_side=getattr(args, "max_detection_side", 2048) or None,
            distortion_correction=bool(getattr(args, "distortion_correction", False)),
        )
    except FileNotFoundError as err:
        raise UserError(str(err).replace("pass distortion_correction=False", "use --no-distortion-correction")) from None


def detect_files(
    command: str, files: list[str], pipeline, board: tuple[int, int], device, batch_size: int, correction=None
) -> dict[str, dict]:
    """Stream the files through the detector; return per path ``{found, corners, image_size, reason}``.

    ``correction``: ``(image_size, (5,) coefficients)``: images of that size are detected on radially corrected
    copies (corners mapped back to the originals).
    """
    from tqdm import tqdm

    from ccs_kornia.io import iter_image_batches

    records: dict[str, dict] = {}
    with tqdm(total=len(files), unit="img", desc=f"{command}", file=sys.stderr, disable=None, leave=False) as bar:
        for batch in iter_image_batches(files, batch_size):
            for path, reason in batch.skipped:
                records[path] = {"found": False, "corners": None, "image_size": None, "error": reason}
                warn(command, f"skipped {path}: {reason}")
            if batch.images is not None:
                if correction is not None and tuple(batch.image_size) == tuple(correction[0]):
                    det = pipeline.detect_corrected(batch.images.to(device), correction[1].to(device), board)
                else:
                    det = pipeline.detect(batch.images.to(device), board)
                corners = det.corners.cpu().double().tolist()
                found = det.found.cpu().tolist()
                reasons = det.reasons or [""] * len(batch.paths)
                for k, path in enumerate(batch.paths):
                    records[path] = {
                        "found": bool(found[k]),
                        "corners": corners[k] if found[k] else None,
                        "image_size": list(batch.image_size),  # type: ignore[arg-type]
                        "method" if found[k] else "reason": reasons[k] or ("" if found[k] else "board not found"),
                    }
            bar.update(len(batch.paths) + len(batch.skipped))
    return records


def not_found_message(board: tuple[int, int], records: dict[str, dict]) -> str:
    readable = sum(1 for r in records.values() if r.get("image_size") is not None)
    if readable == 0:
        return f"none of the {len(records)} input files could be read as an image"
    return (
        f"board {board[0]}x{board[1]} not found in any of {readable} images "
        f"(check --board: COLSxROWS counts inner corners, where four squares meet)"
    )


def predict_correction(command: str, files: list[str], pipeline, device, batch_size: int) -> dict | None:
    """First pass of the corrected calibration: the network's correction of every image, pooled over the
    images of the most common size (the camera's)."""
    from collections import defaultdict

    import torch
    from tqdm import tqdm

    from ccs_kornia.io import iter_image_batches

    per_size: dict[tuple[int, int], list] = defaultdict(list)
    with tqdm(total=len(files), unit="img", desc=f"{command}: lens", file=sys.stderr, disable=None, leave=False) as bar:
        for batch in iter_image_batches(files, batch_size):
            if batch.images is not None:
                per_size[tuple(batch.image_size)].append(pipeline.view_corrections(batch.images.to(device)).cpu())
            bar.update(len(batch.paths) + len(batch.skipped))
    if not per_size:
        return None
    size = max(per_size, key=lambda k: sum(t.shape[0] for t in per_size[k]))
    views = torch.cat(per_size[size])
    coeffs, apply = pipeline.pool_corrections(views[None], size)
    from ccs_kornia.modules.correction.pooling import correction_displacement

    return {"image_size": size, "coeffs": coeffs[0], "apply": bool(apply[0]), "views": int(views.shape[0]),
            "displacement_px": float(correction_displacement(coeffs, size)[0])}


def correction_record(correction: dict | None, applied: bool, what: str | None = None) -> dict:
    if correction is None:
        return {"enabled": False}
    return {
        "enabled": True,
        "applied": applied,
        "network_correction": [float(x) for x in correction["coeffs"].tolist()],
        "network_displacement_px": correction["displacement_px"],
        "refined_correction": correction.get("refined"),
        "note": "paper radial correction r_c = r_d (k0' + k1' r_d + ... + k4' r_d^4), radii from the image centre "
                "in units of max(W, H); applied = "
                + (what or "detected on corrected images and calibrated in the corrected frame")
                + " (see docs/architecture.md)",
    }
