"""``ccs_kornia calibrate``: one camera from chessboard images (JSON, optional OpenCV YAML and report)."""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from typing import Any

from ccs_kornia.commands._common import (
    UserError,
    check_output_file,
    correction_record,
    detect_files,
    inputs,
    make_dir,
    make_pipeline,
    not_found_message,
    predict_correction,
    resolve_device,
    warn,
)

__all__ = ["run", "calibrate_files"]


def calibrate_files(
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

    from ccs_kornia.records import calibration_record, plan_views

    timings: dict[str, float] = {}
    correction = None
    if pipeline.distortion_net is not None:
        start = time.perf_counter()
        correction = predict_correction(command, files, pipeline, device, batch_size)
        timings["distortion_net_s"] = time.perf_counter() - start
    start = time.perf_counter()
    detect_with = (correction["image_size"], correction["coeffs"]) if correction and correction["apply"] else None
    records = detect_files(command, files, pipeline, board, device, batch_size, detect_with)
    timings["load_and_detect_s"] = time.perf_counter() - start
    views, usable, image_size = plan_views(files, records)
    for view in views:
        if view["found"] and "reason" in view:  # found but of another size
            warn(command, f"skipped {view['path']}: {view['reason']}")
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
        raise failure(not_found_message(board, records))
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
        result = first_camera(result)
        applied = bool(applied_t[0])
        correction["refined"] = refined[0].cpu().tolist()
    else:
        result = pipeline.calibrate(corners, valid, board, square, image_size)
    timings["solve_s"] = time.perf_counter() - start
    if not bool(torch.as_tensor(result.success).all()):
        from ccs_kornia.modules.calibration.result import VIEW_REASONS

        failed_fit = "in the failed refinement (no consistent camera)"
        texts = [failed_fit if int(c) == 0 else VIEW_REASONS.get(int(c), "not used by the solver")
                 for c in result.view_reason.cpu().tolist()]
        codes = Counter(texts)
        index = {path: k for k, path in enumerate(usable)}
        for view in views:
            if view["path"] in index:
                view["reason"] = texts[index[view["path"]]]
        detail = ", ".join(f"{n} {reason}" for reason, n in codes.most_common())
        # the solver's refusals (degeneracy checks, issue 12) name the problem and the views
        refusals = [i["message"] for i in result.issues()[0] if i["severity"] == "error"]
        if refusals:
            raise failure(f"calibration refused on {len(usable)} views: " + "; ".join(refusals))
        raise failure(
            f"calibration failed on {len(usable)} views ({detail}); the views may be degenerate "
            "(e.g. all fronto-parallel) or inconsistent: add views with the board tilted in different directions"
        )
    data = calibration_record(views, usable, image_size, result, board=board, square=square,
                              detector=detector_name, model=model)
    data["distortion_correction"] = correction_record(correction, applied)
    data["timings"] = timings
    return data, result


def first_camera(result):
    from ccs_kornia.modules.calibration.result import CalibrationResult

    return CalibrationResult(**{k: (v[0] if hasattr(v, "dim") else v) for k, v in result.__dict__.items()})


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


def run(args: argparse.Namespace) -> int:
    from ccs_kornia.io import write_json

    check_output_file("--output", args.output)
    if args.opencv_yaml:
        check_output_file("--opencv-yaml", args.opencv_yaml)
    if args.report:
        make_dir("--report", args.report)
    device = resolve_device(args.device)
    files = inputs("calibrate", args.images)
    pipeline = make_pipeline(args, model=args.model, use_ransac=args.use_ransac, seed=args.seed)
    start = time.perf_counter()
    try:
        data, result = calibrate_files(
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
