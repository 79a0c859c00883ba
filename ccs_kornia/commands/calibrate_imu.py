"""``ccs_kornia calibrate-imu``: where an IMU sits on a camera (or each camera of a rig) and the time offset between
their clocks, from one recording (docs/imu.md).

The cameras' corners come from ``detect``'s JSON (``--corners``, one per camera, each view with its ``timestamp``) or
are detected in folders of images named by their timestamps in nanoseconds (EuRoC's and Kalibr's layout, one folder
per camera); the cameras from ``--calibration`` (``calibrate``'s JSON, one per camera, or a ``calibrate-rig`` JSON, or
Kalibr's ``camchain.yaml``; without it each camera is calibrated first from its own frames); the IMU from a CSV (EuRoC's layout). Everything is read and checked before the fit;
nothing is written when an input is refused.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

import torch

from ccs_kornia.commands._devices import resolve_device
from ccs_kornia.commands._factories import make_pipeline
from ccs_kornia.commands._inputs import inputs
from ccs_kornia.commands._output_paths import check_outputs, make_dir
from ccs_kornia.commands._run import run_files
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.io.corners_file import read_corners_file
from ccs_kornia.io.files import write_json, write_text
from ccs_kornia.io.imu import ImuLog, imu_log_findings, read_imu_csv
from ccs_kornia.io.kalibr import read_camchain, read_imu_yaml
from ccs_kornia.io.rosbag import grey8, read_bag_images, read_bag_imu
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.detection.boards import grid_object_points
from ccs_kornia.modules.imu.problem import ImuCameraData
from ccs_kornia.modules.imu.solver import calibrate_imu_camera
from ccs_kornia.outputs.calibration_file import (
    RigFileError,
    camera_record_fields,
    read_calibration,
)
from ccs_kornia.outputs.imu_exports import camchain_imucam_yaml
from ccs_kornia.outputs.imu_records import imu_camera_record
from ccs_kornia.outputs.records import view_records
from ccs_kornia.outputs.report.imu import write_imu_report
from ccs_kornia.runtime.errors import NoResult, UserError

__all__ = ["run"]

_NS_NAME = re.compile(r"^\d{9,}$")


#: frames of a recording a camera is calibrated from when no calibration is given
_CALIBRATION_FRAMES = 40


def _calibrated_here(frames, obj: torch.Tensor, model) -> tuple[Camera, list[str], list[dict]]:
    """Each camera calibrated from its own frames (up to :data:`_CALIBRATION_FRAMES`, spread over the recording,
    those with most corners first), with the command's model."""
    cams, records = [], []
    for c, (times, corners, size) in enumerate(frames):
        if size is None:
            raise UserError(f"camera {c}: its corners do not say the image size; give the camera's calibration "
                            "(--calibration).")
        seen = corners.isfinite().all(-1)
        count = seen.sum(-1)
        good = (count >= max(6, int(0.5 * corners.shape[1]))).nonzero()[:, 0]
        if good.numel() < 6:
            raise NoResult(f"camera {c}: {good.numel()} frames show half of the board or more: too few to calibrate "
                           "the camera (give its calibration: --calibration).")
        pick = good[torch.linspace(0, good.numel() - 1, min(_CALIBRATION_FRAMES, good.numel())).round().long()]
        res = CalibrationSolver(model=model)(corners[pick].nan_to_num(0.0)[None], seen[pick][None], obj, tuple(size))
        if not bool(res.success[0]):
            raise NoResult(f"camera {c}: the camera could not be calibrated from the recording's frames; give its "
                           "calibration (--calibration).")
        cams.append(res.camera[0])
        records.append({**camera_record_fields(res.camera[0]), "rms": round(float(res.rms[0]), 4),
                        "frames": int(pick.numel()), "source": "calibrated from the same recording"})
    return Camera.cat(cams), [f"cam{c}" for c in range(len(frames))], records


def _cameras(args: argparse.Namespace, count: int) -> tuple[Camera, list[str]]:
    """The C cameras (held) and their names, from ``--calibration``."""
    paths = args.calibration or []
    if len(paths) == 1 and paths[0].lower().endswith((".yaml", ".yml")):
        try:
            chain = read_camchain(paths[0])
        except (OSError, ValueError) as err:
            raise UserError(f"--calibration {paths[0]}: {err}") from None
        if len(chain) != count:
            raise UserError(f"--calibration {paths[0]} holds {len(chain)} camera(s), the recording {count}.")
        return Camera.cat([c.camera for c in chain]), [c.name for c in chain]
    cams, names = [], []
    if len(paths) == 1 and count > 1:
        for c in range(count):
            try:
                cams.append(read_calibration(paths[0], camera=str(c)).camera)
            except (OSError, ValueError) as err:
                raise UserError(f"--calibration {paths[0]}: camera {c}: {err}") from None
            names.append(f"cam{c}")
        return Camera.cat(cams), names
    if len(paths) != count:
        raise UserError(f"--calibration: {len(paths)} file(s) for {count} camera(s) (one per camera, in order, or one "
                        "rig file).")
    for c, path in enumerate(paths):
        try:
            cams.append(read_calibration(path).camera)
        except RigFileError as err:
            raise UserError(f"--calibration {path}: {err}; give it alone for a rig") from None
        except (OSError, ValueError) as err:
            raise UserError(f"--calibration {path}: {err}") from None
        names.append(f"cam{c}")
    return Camera.cat(cams), names


def _from_corners_files(args: argparse.Namespace) -> list[tuple[torch.Tensor, torch.Tensor, tuple[int, int] | None]]:
    """Each camera's frame times (s), corners :math:`(F, P, 2)` (NaN where not seen) and image size, from detect's
    JSON."""
    out = []
    for path in args.corners:
        try:
            f = read_corners_file(path)
        except (OSError, ValueError) as err:
            raise UserError(f"--corners {path}: {err}") from None
        views = [v for v in f.views if v.timestamp is not None]
        if len(views) < len(f.views):
            raise UserError(f"--corners {path}: {len(f.views) - len(views)} of its {len(f.views)} views have no "
                            "timestamp (detect writes one for video frames; for images named by their time, rename "
                            "nothing: give the folder to calibrate-imu instead).")
        if not views:
            raise NoResult(f"--corners {path}: no view.")
        times = torch.tensor([v.timestamp for v in views], dtype=torch.float64)
        corners = torch.stack([v.corners.to(torch.float64) for v in views])
        order = times.argsort()
        out.append((times[order], corners[order], f.image_size))
    return out


def _image_times(files: list[str], folder: str) -> torch.Tensor:
    """The images' timestamps (s) from their names (nanoseconds)."""
    stems = [Path(f).stem for f in files]
    bad = [s for s in stems if not _NS_NAME.match(s)]
    if bad:
        raise UserError(f"{folder}: image names must be their timestamps in nanoseconds (EuRoC's and Kalibr's layout, "
                        f"e.g. 1403636579763555584.png); {bad[0]!r} is not.")
    return torch.tensor([int(s) for s in stems], dtype=torch.float64) * 1e-9


def _bag_folders(args: argparse.Namespace, workdir: str) -> list[str]:
    """Each image topic of ``--bag`` written as a folder of PNG files named by their header stamps (ns), the layout
    the folders of images have: every frame is detected (a recording's screening keeps still frames; an IMU needs the
    moving ones)."""
    import cv2

    topics = [t for t in (args.image_topics or "").split(",") if t]
    if not topics:
        raise UserError("--bag needs --image-topics (one per camera, comma-separated, in the rig's order).")
    folders = []
    for c, topic in enumerate(topics):
        folder = os.path.join(workdir, f"cam{c}")
        os.makedirs(folder)
        count = 0
        try:
            for stamp, image in read_bag_images(args.bag, topic):
                if image is None:
                    continue
                cv2.imwrite(os.path.join(folder, f"{int(round(stamp * 1e9))}.png"), grey8(image))
                count += 1
        except (OSError, ValueError) as err:
            raise UserError(f"--bag {args.bag}: {err}") from None
        if count == 0:
            raise NoResult(f"--bag {args.bag}: topic {topic} holds no image that could be decoded.")
        folders.append(folder)
    return folders


def _imu_log(args: argparse.Namespace) -> ImuLog:
    """The IMU's samples, from ``--imu`` or the bag's ``--imu-topic``."""
    if args.imu:
        try:
            return read_imu_csv(args.imu)
        except (OSError, ValueError) as err:
            raise UserError(f"--imu {args.imu}: {err}") from None
    if not (args.bag and args.imu_topic):
        raise UserError("no IMU: give --imu imu.csv, or --bag with --imu-topic.")
    try:
        t, gyro, accel = read_bag_imu(args.bag, args.imu_topic)
    except (OSError, ValueError) as err:
        raise UserError(f"--bag {args.bag}: {err}") from None
    f64 = torch.float64
    return ImuLog(t=torch.as_tensor(t, dtype=f64), gyro=torch.as_tensor(gyro, dtype=f64),
                  accel=torch.as_tensor(accel, dtype=f64), notes=[f"read from {args.bag}'s {args.imu_topic}"])


def _detected(args: argparse.Namespace, folders: list[str]) -> list[tuple[torch.Tensor, torch.Tensor, tuple[int, int] | None]]:
    """Each camera's frame times, corners and image size, detected in its folder of images."""
    device = resolve_device(args.device)
    pipeline = make_pipeline(args)
    out = []
    for folder in folders:
        if os.path.isdir(os.path.join(folder, "data")):  # EuRoC's cam0/ holds data/ and data.csv
            folder = os.path.join(folder, "data")
        if not os.path.isdir(folder):
            raise UserError(f"{folder}: give one folder of images per camera (named by their timestamps in ns), or "
                            "the corners detect wrote (--corners).")
        files = list(inputs("calibrate-imu", [folder]))
        times = _image_times(files, folder)
        order = times.argsort()
        files, times = [files[i] for i in order.tolist()], times[order]
        res, _ = run_files("calibrate-imu", pipeline, [files], args.board, 1.0, device, calibrate=False)
        one = res.select(0)
        corners = []
        for view in view_records(one, files):
            pts = view.get("corners") if view.get("found") else None
            n = args.board[0] * args.board[1]
            xy = torch.full((n, 2), float("nan"), dtype=torch.float64)
            if pts is not None:
                for i, p in enumerate(pts):
                    if p is not None and p[0] is not None:
                        xy[i] = torch.tensor(p, dtype=torch.float64)
            corners.append(xy)
        size = tuple(one.image_size) if one.image_size else None
        out.append((times, torch.stack(corners), size))
    return out


def run(args: argparse.Namespace) -> int:
    check_outputs(files=[("--output", args.output), ("--kalibr-yaml", args.kalibr_yaml)],
                  dirs=[("--report", args.report)])
    given = [what for what, value in (("folders of images", args.inputs), ("--corners", args.corners),
                                      ("--bag", args.image_topics and args.bag)) if value]
    if len(given) > 1:
        raise UserError(f"give the cameras' images one way ({' or '.join(given)}), not several.")
    if not given:
        raise UserError("no camera input: one folder of images per camera, --corners corners.json per camera, or "
                        "--bag with --image-topics.")
    if args.imu and args.imu_topic:
        raise UserError("give the IMU one way: --imu or --imu-topic, not both.")
    log = _imu_log(args)
    noise = None
    if args.imu_yaml:
        try:
            noise = read_imu_yaml(args.imu_yaml)
        except (OSError, ValueError) as err:
            raise UserError(f"--imu-yaml {args.imu_yaml}: {err}") from None
    if args.corners:
        frames = _from_corners_files(args)
    elif args.inputs:
        frames = _detected(args, args.inputs)
    else:
        with tempfile.TemporaryDirectory(prefix="ccs_bag_") as workdir:
            frames = _detected(args, _bag_folders(args, workdir))
    obj = grid_object_points(getattr(args, "aprilgrid_board", None) or getattr(args, "circle_board", None), args.board,
                             args.square).to(torch.float64)
    camera_records = None
    if args.calibration:
        cameras, names = _cameras(args, len(frames))
    else:
        cameras, names, camera_records = _calibrated_here(frames, obj, args.model)
    for c, (_, x, size) in enumerate(frames):
        expected = args.board[0] * args.board[1]
        if x.shape[1] != expected:
            raise UserError(f"camera {c}: the corners hold {x.shape[1]} points per view, the board {expected}: "
                            "check --board / --charuco / --aprilgrid.")
        cal = cameras.image_sizes[c]
        if size is not None and cal is not None and tuple(size) != tuple(cal):
            raise UserError(f"camera {c}: its images are {size[0]}x{size[1]}, its calibration's "
                            f"{cal[0]}x{cal[1]}: a calibration of another resolution.")
    data = ImuCameraData.from_corners(log.t, log.gyro, log.accel, cameras, obj, [f[0] for f in frames],
                                      [f[1] for f in frames])
    for note in log.notes:
        print(f"imu: {note}", file=sys.stderr)
    result = calibrate_imu_camera(data, noise=noise, knot_spacing=args.knot_spacing, max_shift=args.max_shift,
                                  rolling_shutter=args.rolling_shutter)
    findings = imu_log_findings(log)
    extra = {"imu": {"samples": int(log.t.shape[0]), "rate_hz": round(float(findings.rate), 3),
                     "dropped": findings.dropped, "longest_gap_s": findings.longest_gap,
                     "clipped": findings.saturated, "notes": list(log.notes)}}
    if camera_records is not None:
        extra["camera_calibrations"] = camera_records
    if findings.dropped:
        result.verdict_reasons.append(f"the IMU dropped {findings.dropped} sample(s) (longest gap "
                                      f"{1000 * findings.longest_gap:.1f} ms)")
    if findings.saturated:
        result.verdict_reasons.append(f"the IMU saturates ({', '.join(findings.saturated)} clipped): move more gently")
        if result.verdict == "good":
            result.verdict = "usable"
    record = imu_camera_record(result, names, extra)
    write_json(args.output, record)
    written = [args.output]
    if args.kalibr_yaml:
        write_text(args.kalibr_yaml, camchain_imucam_yaml(cameras, result.T_cam_imu, result.timeshift_cam_imu))
        written.append(args.kalibr_yaml)
    if args.report:
        make_dir("--report", args.report)
        write_imu_report(args.report, result, data.gyro.numpy(), data.accel.numpy(), names)
        written.append(os.path.join(args.report, "index.html"))
    for c, name in enumerate(names):
        t = result.T_cam_imu[c, :3, 3]
        print(f"{name}: T_cam_imu translation [{t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}] m (1-sigma "
              f"{1000 * float(result.translation_std[c].norm()):.2f} mm, {float(result.rotation_std_deg[c].norm()):.3f} "
              f"deg); timeshift_cam_imu {1000 * float(result.timeshift_cam_imu[c]):+.3f} ms "
              f"(1-sigma {1000 * float(result.timeshift_std[c]):.3f} ms)"
              + (f"; line delay {1e6 * float(result.line_delay[c]):.3f} us" if result.line_delay is not None else "")
              + f"; {int(result.frames_used[c])} frames")
    print(f"verdict: {result.verdict}" + (f" ({'; '.join(result.verdict_reasons)})" if result.verdict_reasons else ""))
    print("wrote " + ", ".join(written))
    return 0
