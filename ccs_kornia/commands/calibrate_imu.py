"""``ccs_kornia calibrate-imu``: where an IMU sits on a camera (or each camera of a rig) and the time offset between
their clocks, from one recording (docs/imu.md).

The cameras' corners come from ``detect``'s JSON (``--corners``, one per camera, each view with its ``timestamp``) or
are detected in videos (frame times from the container; every frame screened, those showing the board detected, moving
ones too, at most ``--frame-rate`` per second), in folders of images named by their timestamps in nanoseconds (EuRoC's
and Kalibr's layout, one folder per camera) or in a bag's image topics; the cameras from ``--calibration`` (``calibrate``'s JSON, one per camera, or a ``calibrate-rig`` JSON, or
Kalibr's ``camchain.yaml``; without it each camera is calibrated first from its own frames); the IMU from a CSV (EuRoC's layout). Everything is read and checked before the fit;
nothing is written when an input is refused.
"""

from __future__ import annotations

import argparse
import json
import math
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
from ccs_kornia.commands._video import (
    frame_span,
    make_screen,
    screen_videos,
    screen_workers,
    video_inputs,
)
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.imu_intrinsics import ImuModel
from ccs_kornia.io.corners_file import read_corners_file
from ccs_kornia.io.files import write_json, write_text
from ccs_kornia.io.image_times import read_image_times
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
from ccs_kornia.outputs.imu_exports import (
    camchain_imucam_yaml,
    imu_ros_static_transform,
    kalibr_imu_result_yaml,
    to_kalibr_imu_frame,
)
from ccs_kornia.outputs.imu_records import imu_camera_record
from ccs_kornia.outputs.records import view_records
from ccs_kornia.outputs.report.drawing import board_bend_line
from ccs_kornia.outputs.report.imu import write_imu_report
from ccs_kornia.outputs.rig_records import record_extrinsics
from ccs_kornia.pipeline.sources import VideoFrameRef, VideoSource
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


def _camchain_rig(chain) -> torch.Tensor | None:
    """:math:`(C, 4, 4)` each camera's pose in camera 0's frame from a camchain's ``T_cn_cnm1`` (None where one is
    missing)."""
    poses = [torch.eye(4, dtype=torch.float64)]
    for cam in chain[1:]:
        if cam.T_cn_cnm1 is None:
            return None
        poses.append(cam.T_cn_cnm1.to(torch.float64) @ poses[-1])
    return torch.stack(poses)


def _rig_file_poses(path: str, count: int) -> torch.Tensor:
    """:math:`(C, 4, 4)` each camera's pose in camera 0's frame from a ``calibrate-rig`` JSON."""
    with open(path, encoding="utf-8") as handle:
        R, T = record_extrinsics(json.load(handle)["extrinsics"][:count])
    # the record's extrinsics map camera 0's frame into each camera's (x_c = R x_0 + T), camera 0 the identity
    poses = torch.eye(4, dtype=torch.float64).repeat(count, 1, 1)
    poses[:, :3, :3], poses[:, :3, 3] = R, T
    return torch.linalg.inv(poses[0]) @ poses if not torch.allclose(poses[0], torch.eye(4, dtype=torch.float64)) \
        else poses


def _cameras(args: argparse.Namespace, count: int) -> tuple[Camera, list[str], torch.Tensor | None]:
    """The C cameras (held), their names and, from a rig calibration (``calibrate-rig``'s JSON or a camchain with
    ``T_cn_cnm1``), their poses in camera 0's frame :math:`(C, 4, 4)` (else None), from ``--calibration``."""
    paths = args.calibration or []
    if len(paths) == 1 and paths[0].lower().endswith((".yaml", ".yml")):
        try:
            chain = read_camchain(paths[0])
        except (OSError, ValueError) as err:
            raise UserError(f"--calibration {paths[0]}: {err}") from None
        if len(chain) != count:
            raise UserError(f"--calibration {paths[0]} holds {len(chain)} camera(s), the recording {count}.")
        return Camera.cat([c.camera for c in chain]), [c.name for c in chain], \
            _camchain_rig(chain) if count > 1 else None
    cams, names = [], []
    if len(paths) == 1 and count > 1:
        for c in range(count):
            try:
                cams.append(read_calibration(paths[0], camera=str(c)).camera)
            except (OSError, ValueError) as err:
                raise UserError(f"--calibration {paths[0]}: camera {c}: {err}") from None
            names.append(f"cam{c}")
        return Camera.cat(cams), names, _rig_file_poses(paths[0], count)
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
    return Camera.cat(cams), names, None


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
                        f"e.g. 1403636579763555584.png), or give a table of names and times (--timestamps); "
                        f"{bad[0]!r} is not.")
    return torch.tensor([int(s) for s in stems], dtype=torch.float64) * 1e-9


def _table_times(files: list[str], folder: str, table: str) -> torch.Tensor:
    """The images' timestamps (s) as ``--timestamps`` lists them."""
    try:
        times = read_image_times(table)
    except ValueError as err:
        raise UserError(f"--timestamps {err}") from None
    missing = [f for f in files if os.path.basename(f) not in times]
    if missing:
        raise UserError(f"--timestamps {table}: {len(missing)} of the {len(files)} images of {folder} are not listed "
                        f"(e.g. {os.path.basename(missing[0])}).")
    return torch.tensor([times[os.path.basename(f)] for f in files], dtype=torch.float64)


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
    tables = args.timestamps or []
    if tables and len(tables) != len(folders):
        raise UserError(f"--timestamps: {len(tables)} table(s) for {len(folders)} folder(s) (one per folder, in "
                        "order).")
    cameras, stamps = [], []
    for c, folder in enumerate(folders):
        if os.path.isdir(os.path.join(folder, "data")):  # EuRoC's cam0/ holds data/ and data.csv
            folder = os.path.join(folder, "data")
        if not os.path.isdir(folder):
            raise UserError(f"{folder}: give one video or one folder of images per camera (named by their timestamps "
                            "in ns), or the corners detect wrote (--corners).")
        files = list(inputs("calibrate-imu", [folder]))
        times = _image_times(files, folder) if not tables else _table_times(files, folder, tables[c])
        order = times.argsort()
        cameras.append([files[i] for i in order.tolist()])
        stamps.append(times[order])
    return _detect_views(args, None, cameras, stamps)


def _detect_views(args: argparse.Namespace, sources, cameras: list[list[str]], stamps: list[torch.Tensor]):
    """The board detected in each camera's views (``cameras``: their names; ``sources``: per camera its views (video
    frames), else ``None``: the files so named): per camera its times, corners :math:`(F, P, 2)` (NaN where not seen)
    and image size."""
    device = resolve_device(args.device)
    pipeline = make_pipeline(args)
    out = []
    n = args.board[0] * args.board[1]
    for c, (names, times) in enumerate(zip(cameras, stamps)):
        res, _ = run_files("calibrate-imu", pipeline, [names], args.board, 1.0, device, calibrate=False,
                           source=None if sources is None else sources[c])
        one = res.select(0)
        corners = []
        for view in view_records(one, names):
            pts = view.get("corners") if view.get("found") else None
            xy = torch.full((n, 2), float("nan"), dtype=torch.float64)
            if pts is not None:
                for i, p in enumerate(pts):
                    if p is not None and p[0] is not None:
                        xy[i] = torch.tensor(p, dtype=torch.float64)
            corners.append(xy)
        size = tuple(one.image_size) if one.image_size else None
        out.append((times, torch.stack(corners), size))
    return out


def _ros_frames(text: str | None, names: list[str]) -> tuple[str, list[str]]:
    """``--ros-frames IMU[,CAM0,...]``: the IMU's frame and each camera's."""
    parts = [p.strip() for p in (text or "imu").split(",")]
    if not all(parts) or len(parts) not in (1, 1 + len(names)):
        raise UserError(f"--ros-frames {text}: expected the IMU's frame name, then none or one per camera "
                        f"({len(names)}), comma-separated")
    return parts[0], parts[1:] or [f"{n}_optical_frame" for n in names]


def _rig_check(T_cam_imu: torch.Tensor, rig: torch.Tensor, names: list[str]) -> list[dict]:
    """How far the rig the fitted ``T_cam_imu`` imply (``T_c_imu T_0_imu^-1``) is from the rig's calibration, per
    camera after the first."""
    out = []
    for c in range(1, T_cam_imu.shape[0]):
        implied = T_cam_imu[c] @ torch.linalg.inv(T_cam_imu[0])
        dR = implied[:3, :3] @ rig[c, :3, :3].T
        angle = math.degrees(float(torch.arccos(((dR.trace() - 1) / 2).clamp(-1, 1))))
        out.append({"names": [names[0], names[c]], "rotation_deg": round(angle, 6),
                    "translation_mm": round(1000 * float((implied[:3, 3] - rig[c, :3, 3]).norm()), 4)})
    return out


def _thinned(frames, rate: float | None) -> list:
    """The screened frames that show the board, at most ``rate`` per second (each kept frame at least ``1 / rate``
    after the one kept before it; ``None``: all of them)."""
    kept, last = [], -math.inf
    for f in frames:
        if f.found and (rate is None or f.timestamp - last >= 1.0 / rate - 1e-9):
            kept.append(f)
            last = f.timestamp
    return kept


def _from_videos(args: argparse.Namespace, paths: list[str]) -> list[tuple[torch.Tensor, torch.Tensor, tuple[int, int]]]:
    """Each camera's frame times (the container's, s), corners and image size from its video: every frame screened,
    those showing the board (moving ones too: the IMU needs them; at most ``--frame-rate`` per second) detected."""
    if args.timestamps:
        raise UserError("--timestamps gives the times of folders of images; a video's frame times are its "
                        "container's.")
    screened = screen_videos("calibrate-imu", paths, make_screen(args), frame_span(args), screen_workers(args),
                             skip_unreadable=False)
    refs = []
    for video in screened:
        if not video.timestamps_usable:
            raise UserError(f"{video.path}: the container's frame times do not increase: the frames cannot be placed "
                            "on the IMU's clock (give the frames as images named by their time instead).")
        kept = _thinned(video.frames, args.frame_rate)
        if not kept:
            raise NoResult(f"{video.path}: the board was seen in none of its {len(video.frames)} frames.")
        refs.append([VideoFrameRef(video.path, f.index, f.timestamp) for f in kept])
    sizes = {v.path: v.info.size for v in screened}
    return _detect_views(args, [VideoSource([r], None, sizes) for r in refs], [[f.name for f in r] for r in refs],
                         [torch.tensor([f.timestamp for f in r], dtype=torch.float64) for r in refs])


def run(args: argparse.Namespace) -> int:
    check_outputs(files=[("--output", args.output), ("--kalibr-yaml", args.kalibr_yaml),
                         ("--kalibr-imu-yaml", args.kalibr_imu_yaml), ("--ros-tf", args.ros_tf)],
                  dirs=[("--report", args.report)])
    given = [what for what, value in (("folders of images", args.inputs), ("--corners", args.corners),
                                      ("--bag", args.image_topics and args.bag)) if value]
    if len(given) > 1:
        raise UserError(f"give the cameras' images one way ({' or '.join(given)}), not several.")
    if not given:
        raise UserError("no camera input: one folder of images per camera, --corners corners.json per camera, or "
                        "--bag with --image-topics.")
    if args.timestamps and not args.inputs:
        raise UserError("--timestamps gives the times of folders of images (not of --corners or a bag).")
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
        videos = [bool(video_inputs("calibrate-imu", [item])) for item in args.inputs]
        if any(videos) and not all(videos):
            raise UserError("give every camera the same way: one video each, or one folder of images each.")
        frames = _from_videos(args, args.inputs) if all(videos) else _detected(args, args.inputs)
    else:
        with tempfile.TemporaryDirectory(prefix="ccs_bag_") as workdir:
            frames = _detected(args, _bag_folders(args, workdir))
    obj = grid_object_points(getattr(args, "aprilgrid_board", None) or getattr(args, "circle_board", None), args.board,
                             args.square).to(torch.float64)
    camera_records, rig = None, None
    if args.calibration:
        cameras, names, rig = _cameras(args, len(frames))
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
    ros_frames = _ros_frames(args.ros_frames, names)
    if args.refine_intrinsics and not cameras.uniform:
        raise UserError("--refine-intrinsics: the cameras are of different models; refine them with calibrate-rig, or "
                        "give cameras of one model.")
    data = ImuCameraData.from_corners(log.t, log.gyro, log.accel, cameras, obj, [f[0] for f in frames],
                                      [f[1] for f in frames])
    for note in log.notes:
        print(f"imu: {note}", file=sys.stderr)
    result = calibrate_imu_camera(data, noise=noise, knot_spacing=args.knot_spacing, max_shift=args.max_shift,
                                  rolling_shutter=args.rolling_shutter, rig=None if args.refine_rig else rig,
                                  refine_intrinsics=args.refine_intrinsics, imu_model=ImuModel(args.imu_model),
                                  align_clocks=args.align_clocks, board_flatness=args.board_flatness)
    findings = imu_log_findings(log)
    extra = {"imu": {"samples": int(log.t.shape[0]), "rate_hz": round(float(findings.rate), 3),
                     "dropped": findings.dropped, "longest_gap_s": findings.longest_gap,
                     "clipped": findings.saturated, "notes": list(log.notes)}}
    if camera_records is not None:
        extra["camera_calibrations"] = camera_records
    if rig is not None and args.refine_rig:
        extra["rig_check"] = _rig_check(result.T_cam_imu, rig, names)
        for pair in extra["rig_check"]:
            print(f"{pair['names'][1]} from {pair['names'][0]}: the fitted T_cam_imu imply a rig "
                  f"{pair['translation_mm']:.2f} mm and {pair['rotation_deg']:.3f} deg from its calibration",
                  file=sys.stderr)
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
        # on Kalibr's IMU frame, which differs from the JSON's when the IMU's intrinsics were fitted
        write_text(args.kalibr_yaml, camchain_imucam_yaml(
            result.cameras, to_kalibr_imu_frame(result.T_cam_imu, result.imu_intrinsics), result.timeshift_cam_imu))
        written.append(args.kalibr_yaml)
    if args.kalibr_imu_yaml:
        write_text(args.kalibr_imu_yaml, kalibr_imu_result_yaml(
            result.noise_measured, ImuModel(args.imu_model), result.imu_intrinsics,
            comment="noise densities as this recording's residuals show them; random walks as stated"))
        written.append(args.kalibr_imu_yaml)
    if args.ros_tf:
        write_text(args.ros_tf, imu_ros_static_transform(result.T_cam_imu, *ros_frames))
        written.append(args.ros_tf)
    if args.report:
        make_dir("--report", args.report)
        write_imu_report(args.report, result, data.gyro.numpy(), data.accel.numpy(), names, args.square)
        written.append(os.path.join(args.report, "index.html"))
    for c, name in enumerate(names):
        t = result.T_cam_imu[c, :3, 3]
        print(f"{name}: T_cam_imu translation [{t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}] m (1-sigma "
              f"{1000 * float(result.translation_std[c].norm()):.2f} mm, {float(result.rotation_std_deg[c].norm()):.3f} "
              f"deg); timeshift_cam_imu {1000 * float(result.timeshift_cam_imu[c]):+.3f} ms "
              f"(1-sigma {1000 * float(result.timeshift_std[c]):.3f} ms)"
              + (f"; line delay {1e6 * float(result.line_delay[c]):.3f} us" if result.line_delay is not None else "")
              + f"; {int(result.frames_used[c])} frames")
        if result.intrinsics_std is not None:
            moved = (result.cameras.params[c] - cameras.params[c]).abs()
            print(f"{name}: intrinsics refined: focal lengths moved {float(moved[:2].max()):.2f} px, centre "
                  f"{float(moved[2:4].max()):.2f} px (1-sigma {float(result.intrinsics_std[c, :2].max()):.2f} and "
                  f"{float(result.intrinsics_std[c, 2:4].max()):.2f} px)")
    if result.imu_intrinsics is not None:
        imu, sd = result.imu_intrinsics, result.imu_intrinsics_std
        scale_g, scale_a = imu.gyro_matrix.diagonal() - 1, imu.accel_matrix.diagonal() - 1
        print(f"imu: gyroscope scale {', '.join(f'{100 * float(v):+.2f}' for v in scale_g)} %, accelerometer scale "
              f"{', '.join(f'{100 * float(v):+.2f}' for v in scale_a)} % (1-sigma {100 * float(sd[:15].max()):.2f} % "
              f"at most); g-sensitivity up to {float(imu.g_sensitivity.abs().max()) * 180 / math.pi * 9.81:.3f} "
              "deg/s per g")
    bend = board_bend_line(result.board_flatness, args.square)
    if bend:
        print(bend.replace("&plusmn;", "+-"))
    print(f"verdict: {result.verdict}" + (f" ({'; '.join(result.verdict_reasons)})" if result.verdict_reasons else ""))
    print("wrote " + ", ".join(written))
    return 0
