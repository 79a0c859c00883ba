"""Command line: ``python -m ccs_kornia detect|calibrate|calibrate-many|undistort|demo|fit|validate|test|predict``.

The contract (arguments and JSON layout) is fixed by ``DESIGN.md`` section 4; benchmarks rely on
it. Behaviour on bad input:

* a user mistake that stops the whole job (no images, board never found, malformed ``--board``,
  fewer than 3 usable views, missing output directory, ``--device cuda`` without CUDA, ...) prints
  one line ``ccs_kornia <command>: error: ...`` on stderr and exits with status 2;
* a problem with some inputs only (unreadable file, board not found in one image, image of another
  size) prints one ``warning`` line per input, is recorded in the JSON with its reason, and the job
  goes on (status 0);
* an unexpected internal error prints one line and exits with status 1 (``CCS_DEBUG=1`` re-raises
  it with the traceback).

Output files (``--output``, ``--opencv-yaml``) must go to an existing directory: the parent is not
created, so a mistyped path fails at once (before any work) instead of scattering results.
Output *directories* (``--out-dir``, ``--report``) are created when missing. ``calibrate`` writes
its JSON only when a calibration was computed, so a stale or partial file is never mistaken for one.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

__all__ = ["main", "build_parser", "UserError", "LIGHTNING_COMMANDS"]

PROG = "ccs_kornia"
LIGHTNING_COMMANDS = ("fit", "validate", "test", "predict")
MODELS = ("opencv5", "rational", "k1k2", "none")
DEFAULT_DETECTOR = "learned"

# the demo camera: independent fx/fy, off-centre principal point, strong barrel distortion
DEMO_K = ((620.0, 0.0, 322.0), (0.0, 610.0, 236.0), (0.0, 0.0, 1.0))
DEMO_DIST = (-0.28, 0.09, 0.0005, -0.0008, 0.0)
DEMO_IMAGE_SIZE = (640, 480)
DEMO_BOARD = (9, 6)
DEMO_SQUARE = 0.025
DEMO_VIEWS = 15


class UserError(Exception):
    """A mistake in the user's input that stops the command (exit status 2).

    ``partial`` may hold what was computed before the job had to stop (written by the command).
    """

    partial: dict[str, Any] | None = None


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _warn(command: str, message: str) -> None:
    print(f"{PROG} {command}: warning: {message}", file=sys.stderr)


def _info(message: str) -> None:
    print(message, file=sys.stderr)


# ----------------------------------------------------------------------------------------------
# argument types
# ----------------------------------------------------------------------------------------------


def _board_arg(text: str) -> tuple[int, int]:
    from ccs_kornia.io import parse_board

    try:
        return parse_board(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _detection_side(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0 or 0 < value < 64:
        raise argparse.ArgumentTypeError(f"expected 0 (off) or at least 64, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def _device_arg(text: str) -> str:
    if text == "cpu" or text == "cuda" or (text.startswith("cuda:") and text[5:].isdigit()):
        return text
    raise argparse.ArgumentTypeError(f"invalid device {text!r}: expected cpu, cuda or cuda:N")


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of every command except the Lightning ones (forwarded untouched)."""
    parser = _Parser(
        prog=PROG,
        description="Camera calibration from chessboard images (batched PyTorch/Kornia).",
        epilog="Training: python -m ccs_kornia fit|validate|test|predict --config lightning_configs/<x>.yaml "
        "(LightningCLI; see its --help).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    def common(p: argparse.ArgumentParser, board: bool = True) -> None:
        p.add_argument("images", nargs="+", metavar="IMAGES", help="image files, directories or globs")
        if board:
            p.add_argument("--board", required=True, type=_board_arg, metavar="COLSxROWS",
                           help="inner corners per row x rows of inner corners, e.g. 9x6")
            p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"),
                           help=f"corner detector (default: {DEFAULT_DETECTOR})")
        p.add_argument("--device", default="cpu", type=_device_arg, help="cpu, cuda or cuda:N (default: cpu)")
        if board:
            p.add_argument("--batch-size", default=16, type=_positive_int, metavar="N",
                           help="images loaded and processed at once (default: 16; fewer when images are "
                                "large: at most 64 Mpx per batch)")
            p.add_argument("--max-detection-side", default=2048, type=_detection_side, metavar="PX",
                           help="detect on a downscaled copy of larger images, then refine corners at full "
                                "resolution (default: 2048; 0 = always full resolution)")

    p = sub.add_parser("detect", help="detect chessboard corners, write them as JSON")
    common(p)
    p.add_argument("--output", required=True, metavar="JSON", help="corners file to write")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="detect on the images as they are (by default a strongly distorted lens's images are "
                        "corrected for detection; corners are always given in the original images)")
    p.set_defaults(func=_cmd_detect)

    p = sub.add_parser("calibrate", help="calibrate a camera from chessboard images")
    common(p)
    p.add_argument("--square", default=1.0, type=_positive_float,
                   help="square side in world units (scales the poses only; default 1)")
    p.add_argument("--output", required=True, metavar="JSON", help="calibration file to write")
    p.add_argument("--model", default="opencv5", choices=MODELS,
                   help="distortion model: opencv5 (k1,k2,p1,p2,k3; default), rational (k1..k6), k1k2, none")
    p.add_argument("--no-ransac", dest="use_ransac", action="store_false", help="keep every detected view")
    p.add_argument("--seed", default=0, type=int, help="RANSAC seed (default 0)")
    p.add_argument("--report", metavar="DIR", help="also write overlays and a summary to DIR (created)")
    p.add_argument("--opencv-yaml", metavar="FILE", help="also write an OpenCV FileStorage YAML (camera_matrix, ...)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="do not run the distortion-correction network (strongly distorted lenses are then "
                        "calibrated by the joint refinement alone)")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("undistort", help="undistort images with a calibration (as cv2.undistort)")
    common(p, board=False)
    p.add_argument("--calibration", required=True, metavar="JSON", help="calib.json written by calibrate")
    p.add_argument("--out-dir", required=True, metavar="DIR", help="where to write the images (created)")
    p.set_defaults(func=_cmd_undistort)

    p = sub.add_parser("calibrate-many", help="calibrate many cameras (one directory of images each) with "
                       "Lightning's Trainer.predict; one JSON line per camera")
    p.add_argument("sets", nargs="+", metavar="SETS",
                   help="directories of images (one camera each), parents of such directories, or globs")
    p.add_argument("--board", required=True, type=_board_arg, metavar="COLSxROWS", help="inner corners, e.g. 9x6")
    p.add_argument("--square", default=1.0, type=_positive_float, help="square side in world units (default 1)")
    p.add_argument("--output", required=True, metavar="JSONL", help="JSON Lines file: one calibration per set")
    p.add_argument("--model", default="opencv5", choices=MODELS, help="distortion model (default opencv5)")
    p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"))
    p.add_argument("--device", default="cpu", type=_device_arg, help="cpu, cuda or cuda:N (default: cpu)")
    p.add_argument("--no-ransac", dest="use_ransac", action="store_false", help="keep every detected view")
    p.add_argument("--seed", default=0, type=int, help="RANSAC seed (default 0)")
    p.add_argument("--sets-per-batch", default=4, type=_positive_int, metavar="N",
                   help="sets per predict step; sets of one image size are solved in one batched call (default 4)")
    p.add_argument("--workers", default=0, type=int, metavar="N", help="DataLoader workers loading sets (default 0)")
    p.add_argument("--batch-size", default=16, type=_positive_int, metavar="N",
                   help="images handed to the detector at once (default 16)")
    p.add_argument("--max-detection-side", default=2048, type=_detection_side, metavar="PX",
                   help="detect larger images on a downscaled copy (default 2048; 0 = off)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="do not run the distortion-correction network")
    p.set_defaults(func=_cmd_calibrate_many)

    p = sub.add_parser("demo", help="render a synthetic set with a known camera, calibrate it, compare")
    p.add_argument("--out-dir", default="ccs_demo", metavar="DIR", help="where to write images and results (default ./ccs_demo)")
    p.add_argument("--views", default=DEMO_VIEWS, type=_positive_int, help=f"number of views (default {DEMO_VIEWS})")
    p.add_argument("--detector", default=DEFAULT_DETECTOR, choices=("learned", "opencv"))
    p.add_argument("--device", default="cpu", type=_device_arg)
    p.add_argument("--seed", default=0, type=int, help="seed of the rendered poses (default 0)")
    p.add_argument("--no-distortion-correction", dest="distortion_correction", action="store_false",
                   help="calibrate without the distortion-correction network")
    p.set_defaults(func=_cmd_demo)

    sub.add_parser("bench", help="benchmarks against OpenCV and other peers (see --help)", add_help=False)
    for name in LIGHTNING_COMMANDS:  # listed for --help; main() forwards them before parsing
        sub.add_parser(name, help=f"LightningCLI {name} (training; --config lightning_configs/<x>.yaml)", add_help=False)
    return parser


# ----------------------------------------------------------------------------------------------
# shared steps
# ----------------------------------------------------------------------------------------------


def _resolve_device(text: str):
    import torch

    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            raise UserError(f"--device {text} requested but CUDA is not available on this machine; use --device cpu")
        index = int(text[5:]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise UserError(f"--device {text}: only {torch.cuda.device_count()} CUDA device(s) present")
    return torch.device(text)


def _check_output_file(option: str, path: str) -> None:
    directory = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise UserError(f"{option} {path} is a directory; give a file name")
    if not os.path.isdir(directory):
        raise UserError(f"{option} {path}: output directory {directory} does not exist (create it first)")
    if not os.access(directory, os.W_OK):
        raise UserError(f"{option} {path}: output directory {directory} is not writable")


def _make_dir(option: str, path: str) -> None:
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise UserError(f"{option} {path}: cannot create directory ({err.strerror or err})") from None
    if not os.path.isdir(path):
        raise UserError(f"{option} {path} exists and is not a directory")


def _inputs(command: str, items: Sequence[str]) -> list[str]:
    from ccs_kornia.io import expand_inputs

    files, problems = expand_inputs(items)
    if not files:
        detail = "; ".join(f"{item}: {reason}" for item, reason in problems) or "nothing given"
        raise UserError(f"no images found ({detail})")
    for item, reason in problems:
        _warn(command, f"{item}: {reason}")
    return files


def _make_pipeline(args: argparse.Namespace, model: str = "opencv5", use_ransac: bool = True, seed: int = 0):
    from ccs_kornia.modules.detector import make_detector
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


def _detect_files(
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
                _warn(command, f"skipped {path}: {reason}")
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


def _not_found_message(board: tuple[int, int], records: dict[str, dict]) -> str:
    readable = sum(1 for r in records.values() if r.get("image_size") is not None)
    if readable == 0:
        return f"none of the {len(records)} input files could be read as an image"
    return (
        f"board {board[0]}x{board[1]} not found in any of {readable} images "
        f"(check --board: COLSxROWS counts inner corners, where four squares meet)"
    )


# ----------------------------------------------------------------------------------------------
# detect
# ----------------------------------------------------------------------------------------------


def _cmd_detect(args: argparse.Namespace) -> int:
    from ccs_kornia.io import write_json

    _check_output_file("--output", args.output)
    device = _resolve_device(args.device)
    files = _inputs("detect", args.images)
    pipeline = _make_pipeline(args)
    start = time.perf_counter()
    correction = None
    if pipeline.distortion_net is not None:
        correction = _predict_correction("detect", files, pipeline, device, args.batch_size)
    detect_with = (correction["image_size"], correction["coeffs"]) if correction and correction["apply"] else None
    records = _detect_files("detect", files, pipeline, args.board, device, args.batch_size, detect_with)
    elapsed = time.perf_counter() - start
    images = [{"path": path, **records[path]} for path in files]
    n_found = sum(r["found"] for r in images)
    data = {
        "board": list(args.board),
        "detector": args.detector,
        "images": images,
        "skipped": [{"path": r["path"], "reason": r["error"]} for r in images if "error" in r],
        "num_found": n_found,
        "distortion_correction": _correction_record(
            correction, bool(detect_with), "detected on corrected images, corners given in the original images"),
        "timings": {"load_and_detect_s": elapsed, "images_per_s": len(files) / max(elapsed, 1e-9)},
    }
    write_json(args.output, data)
    if n_found == 0:
        raise UserError(_not_found_message(args.board, records) + f"; wrote {args.output}")
    print(f"found the {args.board[0]}x{args.board[1]} board in {n_found} of {len(files)} images; wrote {args.output}")
    return 0


# ----------------------------------------------------------------------------------------------
# calibrate
# ----------------------------------------------------------------------------------------------


def _calibrate_files(
    command: str,
    files: list[str],
    board: tuple[int, int],
    square: float,
    pipeline,
    device,
    batch_size: int,
    model: str,
    detector_name: str,
) -> tuple[dict[str, Any], Any]:
    """Detect on ``files`` and calibrate; returns (JSON-ready dict, CalibrationResult).

    Raises :class:`UserError` when no calibration can be computed; when images were read, the error
    carries ``partial``: the per-view record (detections and reasons) so the caller can keep it.
    """
    import torch

    from ccs_kornia.io import calibration_record, plan_views

    timings: dict[str, float] = {}
    correction = None
    if pipeline.distortion_net is not None:
        start = time.perf_counter()
        correction = _predict_correction(command, files, pipeline, device, batch_size)
        timings["distortion_net_s"] = time.perf_counter() - start
    start = time.perf_counter()
    detect_with = (correction["image_size"], correction["coeffs"]) if correction and correction["apply"] else None
    records = _detect_files(command, files, pipeline, board, device, batch_size, detect_with)
    timings["load_and_detect_s"] = time.perf_counter() - start
    views, usable, image_size = plan_views(files, records)
    for view in views:
        if view["found"] and "reason" in view:  # found but of another size
            _warn(command, f"skipped {view['path']}: {view['reason']}")
    n_found = sum(1 for v in views if v["found"])

    def failure(message: str) -> UserError:
        err = UserError(message)
        if any(r.get("image_size") is not None for r in records.values()):
            err.partial = {
                "success": False, "error": message, "board": list(board), "square": square,
                "detector": detector_name, "model": model,
                "image_size": list(image_size) if image_size else None, "K": None, "distortion": None, "rms": None,
                "views": views,
                "num_views": {"files": len(files), "found": n_found, "usable": len(usable), "used": 0},
                "skipped": [{"path": v["path"], "reason": v["reason"]} for v in views if "reason" in v],
                "timings": timings,
            }
        return err

    if image_size is None:
        raise failure(_not_found_message(board, records))
    if len(usable) < 3:
        raise failure(
            f"only {len(usable)} usable view(s) of the {board[0]}x{board[1]} board among {len(files)} files "
            f"(board found in {n_found}); at least 3 are needed"
        )

    corners = torch.tensor([records[p]["corners"] for p in usable], dtype=torch.float64, device=device)
    valid = torch.ones(corners.shape[:-1], dtype=torch.bool, device=device)
    start = time.perf_counter()
    applied = False
    if correction is not None and correction["apply"] and tuple(correction["image_size"]) == tuple(image_size):
        result, refined, applied_t = pipeline.solve_with_correction(
            corners[None], valid[:, 0][None], correction["coeffs"][None].to(device), torch.ones(1, dtype=torch.bool),
            board, square, image_size,
        )
        result = _first_camera(result)
        applied = bool(applied_t[0])
        correction["refined"] = refined[0].cpu().tolist()
    else:
        result = pipeline.calibrate(corners, valid, board, square, image_size)
    timings["solve_s"] = time.perf_counter() - start
    if not bool(torch.as_tensor(result.success).all()):
        from ccs_kornia.modules.calibrator import VIEW_REASONS

        failed_fit = "in the failed refinement (no consistent camera)"
        texts = [failed_fit if int(c) == 0 else VIEW_REASONS.get(int(c), "not used by the solver")
                 for c in result.view_reason.cpu().tolist()]
        codes = Counter(texts)
        index = {path: k for k, path in enumerate(usable)}
        for view in views:
            if view["path"] in index:
                view["reason"] = texts[index[view["path"]]]
        detail = ", ".join(f"{n} {reason}" for reason, n in codes.most_common())
        # trust (issue 12): the solver's refusals name the problem and the views
        refusals = [i["message"] for i in result.issues()[0] if i["severity"] == "error"] if hasattr(result, "issues") else []
        if refusals:
            raise failure(f"calibration refused on {len(usable)} views: " + "; ".join(refusals))
        raise failure(
            f"calibration failed on {len(usable)} views ({detail}); the views may be degenerate "
            "(e.g. all fronto-parallel) or inconsistent: add views with the board tilted in different directions"
        )
    data = calibration_record(views, usable, image_size, result, board=board, square=square,
                              detector=detector_name, model=model)
    data["distortion_correction"] = _correction_record(correction, applied)
    data["timings"] = timings
    return data, result


def _first_camera(result):
    from ccs_kornia.modules.calibrator import CalibrationResult

    return CalibrationResult(**{k: (v[0] if hasattr(v, "dim") else v) for k, v in result.__dict__.items()})


def _predict_correction(command: str, files: list[str], pipeline, device, batch_size: int) -> dict | None:
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
    from ccs_kornia.modules.undistort import correction_displacement

    return {"image_size": size, "coeffs": coeffs[0], "apply": bool(apply[0]), "views": int(views.shape[0]),
            "displacement_px": float(correction_displacement(coeffs, size)[0])}


def _correction_record(correction: dict | None, applied: bool, what: str | None = None) -> dict:
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


def _failed_path(output: str) -> str:
    stem, ext = os.path.splitext(output)
    return f"{stem}.failed{ext or '.json'}"


def _write_opencv_yaml(path: str, data: dict[str, Any]) -> None:
    import cv2
    import numpy as np

    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise UserError(f"--opencv-yaml {path}: cannot open for writing")
    try:
        fs.write("calibration_time", time.strftime("%Y-%m-%d %H:%M:%S"))
        fs.write("nr_of_frames", int(data["num_views"]["used"]))
        fs.write("image_width", int(data["image_size"][0]))
        fs.write("image_height", int(data["image_size"][1]))
        fs.write("board_width", int(data["board"][0]))
        fs.write("board_height", int(data["board"][1]))
        fs.write("square_size", float(data["square"]))
        fs.write("camera_matrix", np.array(data["K"], dtype=np.float64))
        coeffs = data["distortion"]["coeffs"] or [0.0, 0.0, 0.0, 0.0, 0.0]
        fs.write("distortion_coefficients", np.array(coeffs, dtype=np.float64).reshape(-1, 1))
        fs.write("avg_reprojection_error", float(data["rms"]))
    finally:
        fs.release()


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ccs_kornia.io import write_json

    _check_output_file("--output", args.output)
    if args.opencv_yaml:
        _check_output_file("--opencv-yaml", args.opencv_yaml)
    if args.report:
        _make_dir("--report", args.report)
    device = _resolve_device(args.device)
    files = _inputs("calibrate", args.images)
    pipeline = _make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed)
    start = time.perf_counter()
    try:
        data, result = _calibrate_files(
            "calibrate", files, args.board, args.square, pipeline, device, args.batch_size, args.model, args.detector
        )
    except UserError as err:
        # nothing lost: the per-image detections and reasons go next to the requested output, which
        # itself is only ever written for a computed calibration
        if err.partial is not None:
            failed = _failed_path(args.output)
            err.partial["device"] = str(device)
            write_json(failed, err.partial)
            raise UserError(f"{err}; per-image results written to {failed}") from None
        raise
    data["device"] = str(device)
    data["success"] = True
    data["timings"]["total_s"] = time.perf_counter() - start
    write_json(args.output, data)
    if args.opencv_yaml:
        _write_opencv_yaml(args.opencv_yaml, data)
    if args.report:
        from ccs_kornia.report import write_report

        start = time.perf_counter()
        write_report(args.report, data)
        data["timings"]["report_s"] = time.perf_counter() - start
        write_json(args.output, data)
    _print_summary(data, args.output)
    if args.report:
        print(f"report: {os.path.join(args.report, 'index.html')}")
    return 0


def _print_summary(data: dict[str, Any], output: str) -> None:
    K = data["K"]
    n = data["num_views"]
    coeffs = ", ".join(f"{c:.5g}" for c in data["distortion"]["coeffs"])
    print(
        f"fx {K[0][0]:.3f}  fy {K[1][1]:.3f}  cx {K[0][2]:.3f}  cy {K[1][2]:.3f}  "
        f"{data['distortion']['model']} ({coeffs})"
    )
    print(f"RMS {data['rms']:.4f} px over {n['used']} views (board found in {n['found']} of {n['files']} files); wrote {output}")


# ----------------------------------------------------------------------------------------------
# undistort
# ----------------------------------------------------------------------------------------------


def _read_calibration(path: str) -> tuple[Any, Any, tuple[int, int] | None]:
    import json

    import torch

    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except FileNotFoundError:
        raise UserError(f"--calibration {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserError(f"--calibration {path}: not a readable JSON file ({err})") from None
    try:
        K = torch.tensor(data["K"], dtype=torch.float64)
        coeffs = data.get("distortion", {}).get("coeffs") or []
        dist = torch.tensor([float(c) for c in coeffs], dtype=torch.float64)
        size = data.get("image_size")
        size = (int(size[0]), int(size[1])) if size else None
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise UserError(f"--calibration {path}: not a calibration written by 'calibrate' ({type(err).__name__}: {err})") from None
    if K.shape != (3, 3) or dist.numel() not in (0, 4, 5, 8, 12, 14):
        raise UserError(f"--calibration {path}: K must be 3x3 and distortion.coeffs have 0, 4, 5, 8, 12 or 14 values")
    if dist.numel() == 0:
        dist = torch.zeros(5, dtype=torch.float64)
    return K, dist, size


def _cmd_undistort(args: argparse.Namespace) -> int:
    import torch
    from kornia.geometry.calibration import undistort_image
    from tqdm import tqdm

    from ccs_kornia.io import read_image, write_image

    K, dist, calib_size = _read_calibration(args.calibration)
    device = _resolve_device(args.device)
    files = _inputs("undistort", args.images)
    _make_dir("--out-dir", args.out_dir)
    K, dist = K.to(device), dist.to(device)
    written, used_names = 0, set()
    for path in tqdm(files, unit="img", desc="undistort", file=sys.stderr, disable=None, leave=False):
        image, reason, depth = read_image(path, gray=False)
        if image is None:
            _warn("undistort", f"skipped {path}: {reason}")
            continue
        h, w = image.shape[:2]
        if calib_size is not None and (w, h) != calib_size:
            _warn("undistort", f"skipped {path}: image size {w}x{h} differs from the calibration's {calib_size[0]}x{calib_size[1]}")
            continue
        stem, ext = os.path.splitext(os.path.basename(path))
        if ext.lower() not in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"):
            ext = ".png"
        name, k = stem + ext, 1
        while name in used_names:  # same file name from different input folders
            name, k = f"{stem}_{k}{ext}", k + 1
        used_names.add(name)
        target = os.path.join(args.out_dir, name)
        if os.path.exists(target) and os.path.samefile(target, path):
            _warn("undistort", f"skipped {path}: writing to --out-dir would overwrite the input")
            continue
        tensor = torch.from_numpy(image).to(device)
        tensor = tensor[None, None] if tensor.dim() == 2 else tensor.permute(2, 0, 1)[None]
        out = undistort_image(tensor.double(), K[None], dist[None])[0]
        if not write_image(target, out, bit_depth=16 if depth > 8 and ext.lower() in (".png", ".tif", ".tiff") else 8):
            _warn("undistort", f"could not write {target}")
            continue
        written += 1
    if written == 0:
        raise UserError(f"no image undistorted (all {len(files)} inputs were skipped)")
    print(f"undistorted {written} of {len(files)} images into {args.out_dir}")
    return 0


# ----------------------------------------------------------------------------------------------
# calibrate-many
# ----------------------------------------------------------------------------------------------


def _cmd_calibrate_many(args: argparse.Namespace) -> int:
    _check_output_file("--output", args.output)
    device = _resolve_device(args.device)
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
        _warn("calibrate-many", f"{item}: {reason}")
    pipeline = _make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed)
    _info(f"calibrating {len(sets)} image sets ({sum(len(f) for _, f in sets)} files) on {device} ...")
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


# ----------------------------------------------------------------------------------------------
# demo
# ----------------------------------------------------------------------------------------------


def _cmd_demo(args: argparse.Namespace) -> int:
    import torch

    from ccs_kornia.data.synthetic import make_calibration_set
    from ccs_kornia.io import write_image, write_json
    from ccs_kornia.metrics import e_fl, e_ip, e_pp

    device = _resolve_device(args.device)
    _make_dir("--out-dir", args.out_dir)
    K_true = torch.tensor(DEMO_K, dtype=torch.float64)
    dist_true = torch.tensor(DEMO_DIST, dtype=torch.float64)
    _info(f"rendering {args.views} views of a {DEMO_BOARD[0]}x{DEMO_BOARD[1]} board ({DEMO_IMAGE_SIZE[0]}x{DEMO_IMAGE_SIZE[1]}) ...")
    start = time.perf_counter()
    batch = make_calibration_set(
        K_true, DEMO_BOARD, DEMO_SQUARE, DEMO_IMAGE_SIZE, num_views=args.views, dist=dist_true, seed=args.seed, supersample=2
    )
    files = []
    for k in range(batch.images.shape[0]):
        path = os.path.join(args.out_dir, f"view_{k:02d}.png")
        write_image(path, batch.images[k, 0])
        files.append(path)
    render_s = time.perf_counter() - start
    write_json(
        os.path.join(args.out_dir, "ground_truth.json"),
        {
            "image_size": list(DEMO_IMAGE_SIZE), "K": K_true.tolist(),
            "distortion": {"model": "opencv5", "coeffs": dist_true.tolist()},
            "board": list(DEMO_BOARD), "square": DEMO_SQUARE,
            "views": [{"path": f, "corners": batch.corners[k].tolist(), "rvec": batch.rvec[k].tolist(),
                       "tvec": batch.tvec[k].tolist()} for k, f in enumerate(files)],
        },
    )
    # the very path of `calibrate`, on the files just written
    pipeline = _make_pipeline(argparse.Namespace(detector=args.detector, batch_size=16,
                                                 distortion_correction=args.distortion_correction))
    output = os.path.join(args.out_dir, "calib.json")
    data, _ = _calibrate_files("demo", files, DEMO_BOARD, DEMO_SQUARE, pipeline, device, 16, "opencv5", args.detector)
    data["device"] = str(device)
    data["success"] = True
    data["timings"]["render_s"] = render_s
    write_json(output, data)
    from ccs_kornia.report import write_report

    report_dir = os.path.join(args.out_dir, "report")
    _make_dir("--out-dir", report_dir)
    write_report(report_dir, data)

    K_est = torch.tensor(data["K"], dtype=torch.float64)
    dist_est = data["distortion"]["coeffs"]
    rows = [
        ("fx", K_true[0, 0].item(), K_est[0, 0].item()),
        ("fy", K_true[1, 1].item(), K_est[1, 1].item()),
        ("cx", K_true[0, 2].item(), K_est[0, 2].item()),
        ("cy", K_true[1, 2].item(), K_est[1, 2].item()),
    ] + [(name, float(t), float(e)) for name, t, e in zip(("k1", "k2", "p1", "p2", "k3"), DEMO_DIST, dist_est)]
    print(f"{'param':>6} {'true':>12} {'estimated':>12} {'error':>11}")
    for name, t, e in rows:
        print(f"{name:>6} {t:12.5f} {e:12.5f} {e - t:+11.5f}")
    print(f"E_FL {float(e_fl(K_est, K_true)):.4f} px   E_PP {float(e_pp(K_est, K_true)):.4f} px   "
          f"E_IP {float(e_ip(K_est, K_true)):.4f} px   RMS {data['rms']:.4f} px "
          f"({data['num_views']['used']} of {args.views} views used)")
    print(f"wrote {len(files)} images, ground_truth.json, calib.json and report/index.html to {args.out_dir}")
    return 0


# ----------------------------------------------------------------------------------------------
# entry point
# ----------------------------------------------------------------------------------------------


def _run_lightning(argv: list[str]) -> int:
    try:
        from ccs_kornia.training.cli import main as lightning_main
    except Exception as err:  # ImportError, or a broken optional dependency
        print(
            f"{PROG} {argv[0]}: error: the training command line is not available "
            f"(ccs_kornia.training.cli: {type(err).__name__}: {err})",
            file=sys.stderr,
        )
        return 2
    result = lightning_main(argv)
    return int(result or 0)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 user error, 1 internal error).

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in LIGHTNING_COMMANDS:
        return _run_lightning(argv)
    if argv and argv[0] == "bench":
        from ccs_kornia.bench.__main__ import main as bench_main

        return bench_main(argv[1:], prog=f"{PROG} bench")
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:
        return int(exit_.code or 0) if not isinstance(exit_.code, str) else 2
    command = args.command
    try:
        return int(args.func(args) or 0)
    except UserError as err:
        print(f"{PROG} {command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG} {command}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:
        if os.environ.get("CCS_DEBUG", "") not in ("", "0"):
            raise
        message = str(err).strip().splitlines()[0] if str(err).strip() else ""
        print(
            f"{PROG} {command}: internal error: {type(err).__name__}: {message} "
            "(run with CCS_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
