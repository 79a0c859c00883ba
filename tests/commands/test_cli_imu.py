"""``calibrate-imu`` on the command line: a rendered recording given as detect's corners JSON, an EuRoC-style IMU CSV
and calibrate's JSON; the answer against the truth, Kalibr's camchain-imucam.yaml, and every refusal as one line with
its exit status and nothing written."""

from __future__ import annotations

import functools
import json
import math

import pytest
import torch

from ccs_kornia import cli
from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.io.files import write_json
from ccs_kornia.outputs.calibration_file import camera_record_fields

EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_imu_csv(path, rec, offset_s: float = 0.0) -> None:
    rows = [EUROC_HEADER]
    for t, w, a in zip(rec.imu_times.tolist(), rec.gyro.tolist(), rec.accel.tolist()):
        rows.append(",".join([str(round((t + offset_s) * 1e9))] + [f"{v:.9f}" for v in w + a]))
    path.write_text("\n".join(rows) + "\n")


def write_corners(path, rec, camera: int = 0, timestamps: bool = True) -> None:
    images = []
    for k, (t, xy) in enumerate(zip(rec.frame_times[camera].tolist(), rec.corners[camera])):
        seen = xy.isfinite().all(-1)
        corners = [[round(float(x), 4), round(float(y), 4)] if s else [None, None] for (x, y), s in zip(xy.tolist(), seen)]
        record = {"path": f"cam{camera}.mp4#{k}", "found": bool(seen.sum() >= 6), "corners": corners}
        if timestamps:
            record["timestamp"] = round(t, 6)
        images.append(record)
    write_json(path, {"board": [7, 6], "image_size": [752, 480], "images": images})


@pytest.fixture(scope="module")
def recording():
    return visual_inertial_recording(duration=10.0, seed=21)


@pytest.fixture
def files(tmp_path, recording):
    write_imu_csv(tmp_path / "imu0.csv", recording)
    write_corners(tmp_path / "cam0.json", recording)
    write_json(tmp_path / "cam0_calib.json", {**camera_record_fields(recording.cameras[0]), "rms": 0.2})
    return tmp_path


def test_corners_json_and_csv_give_the_truth(capsys, files, recording):
    out = files / "imu_cam.json"
    code, stdout, err = run(capsys, "calibrate-imu", "--corners", files / "cam0.json", "--imu", files / "imu0.csv",
                            "--board", "7x6", "--square", "0.08", "--calibration", files / "cam0_calib.json",
                            "--output", out, "--kalibr-yaml", files / "camchain-imucam.yaml", "--report",
                            files / "report")
    assert code == 0, err
    data = json.loads(out.read_text())
    cam = data["cameras"][0]
    T = torch.tensor(cam["T_cam_imu"], dtype=torch.float64)
    assert float((T[:3, 3] - recording.T_cam_imu[0, :3, 3]).norm()) < 0.003
    assert math.degrees(float(log_so3(T[:3, :3] @ recording.T_cam_imu[0, :3, :3].T).norm())) < 0.05
    assert abs(cam["timeshift_cam_imu"] - float(recording.shift[0])) < 1e-4
    assert data["verdict"] in ("good", "usable") and "timeshift_cam_imu" in stdout
    assert data["noise"]["given"] is False and data["imu"]["samples"] == recording.imu_times.shape[0]
    assert "verdict" in (files / "report" / "index.html").read_text()
    # the board's sag judged by default, written as every fit of a board writes it (a flat board: not kept)
    flatness = data["board_flatness"]
    assert flatness["kept"] is False and len(flatness["warp_m"]) == 2 and "heldout_median_px" in flatness
    assert "board bend (mrcal's sag c_x, c_y)" in stdout and "not kept" in stdout
    assert "board bend" in (files / "report" / "index.html").read_text()
    for name in ("gyroscope.png", "accelerometer.png", "reprojection_0.png", "time_offset.png"):
        assert (files / "report" / name).stat().st_size > 1000
    from ccs_kornia.io.kalibr import read_camchain

    chain = read_camchain(files / "camchain-imucam.yaml")
    torch.testing.assert_close(torch.as_tensor(chain[0].T_cam_imu, dtype=torch.float64), T, atol=1e-6, rtol=0)
    assert abs(chain[0].timeshift_cam_imu - cam["timeshift_cam_imu"]) < 1e-9


def _refused(capsys, code_expected, argv, out, *phrases):
    code, _, err = run(capsys, *argv)
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert code == code_expected and len(lines) == 1 and "Traceback" not in err, err
    for phrase in phrases:
        assert phrase in lines[0], lines[0]
    assert not out.exists()


def _argv(files, **over):
    args = {"--corners": files / "cam0.json", "--imu": files / "imu0.csv", "--board": "7x6", "--square": "0.08",
            "--calibration": files / "cam0_calib.json", "--output": files / "imu_cam.json"}
    args.update(over)
    # the board taken as flat: its sag is judged in test_corners_json_and_csv_give_the_truth
    argv = ["calibrate-imu", "--flat-board"]
    for k, v in args.items():
        if v is not None:
            argv += [k, v]
    return argv


def test_cameras_calibrated_from_the_recording(capsys, files, recording):
    out = files / "imu_cam.json"
    code, _, err = run(capsys, *_argv(files, **{"--calibration": None}))
    assert code == 0, err
    data = json.loads(out.read_text())
    assert data["camera_calibrations"][0]["source"] == "calibrated from the same recording"
    K = torch.tensor(data["camera_calibrations"][0]["K"], dtype=torch.float64)
    assert float((K - recording.cameras.K[0]).abs().max()) < 2.0
    T = torch.tensor(data["cameras"][0]["T_cam_imu"], dtype=torch.float64)
    assert float((T[:3, 3] - recording.T_cam_imu[0, :3, 3]).norm()) < 0.005


def test_rolling_shutter(capsys, tmp_path):
    rec = visual_inertial_recording(duration=8.0, seed=41, line_delay=3e-5)
    write_imu_csv(tmp_path / "imu0.csv", rec)
    write_corners(tmp_path / "cam0.json", rec)
    write_json(tmp_path / "cam.json", {**camera_record_fields(rec.cameras[0]), "rms": 0.2})
    out = tmp_path / "imu_cam.json"
    code, stdout, err = run(capsys, "calibrate-imu", "--flat-board", "--corners", tmp_path / "cam0.json", "--imu",
                            tmp_path / "imu0.csv", "--board", "7x6", "--square", "0.08", "--calibration",
                            tmp_path / "cam.json", "--rolling-shutter", "--output", out)
    assert code == 0, err
    cam = json.loads(out.read_text())["cameras"][0]
    assert abs(cam["line_delay_s"] - 3e-5) < 1e-6 and "line delay" in stdout
    assert abs(cam["timeshift_cam_imu"] - float(rec.shift[0])) < 2e-4


def test_stereo_rig_held_and_refined(capsys, tmp_path):
    rec = visual_inertial_recording(duration=8.0, seed=42, num_cameras=2)
    write_imu_csv(tmp_path / "imu0.csv", rec)
    for c in range(2):
        write_corners(tmp_path / f"cam{c}.json", rec, camera=c)
    # a calibrate-rig JSON: each camera's record and its pose in camera 0's frame (x_c = R x_0 + T)
    rig = rec.T_cam_imu.double() @ torch.linalg.inv(rec.T_cam_imu[0].double())
    write_json(tmp_path / "rig.json", {
        "cameras": [{**camera_record_fields(rec.cameras[c]), "name": f"cam{c}", "rms": 0.2} for c in range(2)],
        "extrinsics": [{"name": f"cam{c}", "R": rig[c, :3, :3].tolist(), "T": rig[c, :3, 3].tolist()}
                       for c in range(2)]})
    argv = ["calibrate-imu", "--flat-board", "--corners", tmp_path / "cam0.json", "--corners", tmp_path / "cam1.json",
            "--imu", tmp_path / "imu0.csv", "--board", "7x6", "--square", "0.08", "--calibration", tmp_path / "rig.json"]
    code, _, err = run(capsys, *argv, "--output", tmp_path / "held.json", "--ros-tf", tmp_path / "imu.launch")
    assert code == 0, err
    held = json.loads((tmp_path / "held.json").read_text())
    assert held["rig_extrinsics"].startswith("held") and "rig_check" not in held
    T = torch.tensor([c["T_cam_imu"] for c in held["cameras"]], dtype=torch.float64)
    torch.testing.assert_close(T[1] @ torch.linalg.inv(T[0]), rig[1], atol=1e-8, rtol=0)
    assert float((T[1, :3, 3] - rec.T_cam_imu[1, :3, 3]).norm()) < 0.003
    # the launch file publishes each camera's optical frame in the IMU's: the inverse of T_cam_imu
    launch = (tmp_path / "imu.launch").read_text()
    args = [line for line in launch.splitlines() if line.strip().startswith("args=") and "cam1_optical_frame" in line]
    t_imu_cam1 = torch.tensor([float(v) for v in args[0].split('"')[1].split()[:3]], dtype=torch.float64)
    torch.testing.assert_close(t_imu_cam1, torch.linalg.inv(T[1])[:3, 3], atol=1e-6, rtol=0)
    code, stdout, err = run(capsys, *argv, "--output", tmp_path / "free.json", "--refine-rig", "--refine-intrinsics")
    assert code == 0, err
    free = json.loads((tmp_path / "free.json").read_text())
    refined = free["cameras"][1]["camera_refined"]
    K = torch.tensor(refined["K"], dtype=torch.float64)
    assert float((K - rec.cameras.K[1]).abs().max()) < 1.0 and refined["std"]["fx"] > 0
    assert "intrinsics refined" in stdout
    check = free["rig_check"][0]
    assert free["rig_extrinsics"] == "fitted" and check["translation_mm"] < 3 and check["rotation_deg"] < 0.1
    assert "imply a rig" in err


def test_dropped_samples_are_said(capsys, files, recording):
    lines = (files / "imu0.csv").read_text().splitlines()
    (files / "gappy.csv").write_text("\n".join(lines[:800] + lines[830:]) + "\n")
    # with the IMU's intrinsics estimated (an ideal IMU here: they come out as the identity)
    code, stdout, err = run(capsys, *_argv(files, **{"--imu": files / "gappy.csv"}), "--imu-model",
                            "scale-misalignment", "--kalibr-yaml", files / "camchain-imucam.yaml",
                            "--kalibr-imu-yaml", files / "imu-result.yaml")
    assert code == 0, err
    data = json.loads((files / "imu_cam.json").read_text())
    assert data["imu"]["dropped"] == 1 and any("dropped" in r for r in data["verdict_reasons"])
    imu = data["imu_intrinsics"]
    torch.testing.assert_close(torch.tensor(imu["T_g"], dtype=torch.float64), torch.eye(3, dtype=torch.float64),
                               atol=5e-3, rtol=0)
    assert imu["T_a_std"][1][0] == 0.0 and imu["T_a_std"][0][1] > 0 and "g-sensitivity" in stdout
    # Kalibr's files: its lower-triangular accelerometer, and the camchain on the IMU frame that matrix defines
    import yaml

    from ccs_kornia.io.kalibr import read_camchain, read_imu_yaml

    imu0 = yaml.safe_load((files / "imu-result.yaml").read_text())["imu0"]
    M_a = torch.tensor(imu0["accelerometers"]["M"], dtype=torch.float64)
    T_a = torch.tensor(imu["T_a"], dtype=torch.float64)
    assert imu0["model"] == "scale-misalignment" and float(torch.triu(M_a, 1).abs().max()) == 0.0
    R = torch.linalg.solve(M_a, T_a)  # Kalibr's frame from the JSON's: T_a = M_a R
    torch.testing.assert_close(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-9, rtol=0)
    T = torch.tensor(data["cameras"][0]["T_cam_imu"], dtype=torch.float64)
    chain = torch.as_tensor(read_camchain(files / "camchain-imucam.yaml")[0].T_cam_imu, dtype=torch.float64)
    torch.testing.assert_close(chain[:3, :3] @ R, T[:3, :3], atol=1e-6, rtol=0)
    assert read_imu_yaml(files / "imu-result.yaml").gyroscope_noise_density > 0


def test_clocks_that_do_not_overlap(capsys, files, recording):
    write_imu_csv(files / "late.csv", recording, offset_s=5000.0)
    _refused(capsys, 2, _argv(files, **{"--imu": files / "late.csv"}), files / "imu_cam.json", "overlap")


def test_imu_file_of_the_wrong_shape(capsys, files):
    (files / "bad.csv").write_text("1,2,3\n4,5,6\n")
    _refused(capsys, 2, _argv(files, **{"--imu": files / "bad.csv"}), files / "imu_cam.json", "bad.csv", "takes 7")


def test_calibration_of_another_resolution(capsys, files, recording):
    cam = camera_record_fields(recording.cameras[0])
    cam["image_size"] = [640, 480]
    write_json(files / "other.json", {**cam, "rms": 0.2})
    _refused(capsys, 2, _argv(files, **{"--calibration": files / "other.json"}), files / "imu_cam.json",
             "another resolution")


def test_corners_without_timestamps(capsys, files, recording):
    write_corners(files / "nots.json", recording, timestamps=False)
    _refused(capsys, 2, _argv(files, **{"--corners": files / "nots.json"}), files / "imu_cam.json", "timestamp")


def test_offset_beyond_the_search(capsys, files, recording):
    _refused(capsys, 3, _argv(files, **{"--max-shift": "0.015"}), files / "imu_cam.json", "search's edge")


def test_wrong_board(capsys, files):
    _refused(capsys, 2, _argv(files, **{"--board": "9x6"}), files / "imu_cam.json", "board")


@functools.lru_cache(maxsize=1)
def rendered_frames(seed: int):
    """A short recording whose frames are rendered along its motion (a whole board in most frames): the recording,
    its frame times and the images (uint8)."""
    from ccs_kornia.data.render.renderer import render_chessboard

    rec = visual_inertial_recording(duration=6.0, seed=seed, fps=10.0, rotation_amplitude=0.25,
                                    translation_amplitude=0.08)
    t = rec.frame_times[0]
    R, p = rec.motion.camera_pose(t + rec.shift[0])
    Rcw = R.transpose(-1, -2)
    images, _ = render_chessboard(rec.cameras.K[0].expand(len(t), 3, 3), log_so3(Rcw), -(Rcw @ p[..., None])[..., 0],
                                  (7, 6), 0.08, (752, 480), dist=rec.cameras.dist[0, :5], supersample=2)
    return rec, t, (images[:, 0].numpy() * 255).round().astype("uint8")


def test_folder_of_images_with_a_table_of_times(capsys, tmp_path):
    # images not named by their time, and EuRoC's data.csv beside them (a folder of images named by their time in ns
    # is what a bag's topic becomes: test_bag)
    import cv2

    rec, t, images = rendered_frames(31)
    folder = tmp_path / "cam0"
    folder.mkdir(parents=True)
    rows = ["#timestamp [ns],filename"]
    for k, ts in enumerate(t.tolist()):
        cv2.imwrite(str(folder / f"frame_{k:04d}.png"), images[k])
        rows.append(f"{round(ts * 1e9)},frame_{k:04d}.png")
    (tmp_path / "data.csv").write_text("\n".join(rows) + "\n")
    write_imu_csv(tmp_path / "imu0.csv", rec)
    write_json(tmp_path / "cam.json", {**camera_record_fields(rec.cameras[0]), "rms": 0.2})
    out = tmp_path / "imu_cam.json"
    argv = ["calibrate-imu", "--flat-board", tmp_path / "cam0", "--imu", tmp_path / "imu0.csv", "--board", "7x6", "--square", "0.08",
            "--calibration", tmp_path / "cam.json", "--detector", "opencv", "--jobs", "1", "--output", out]
    _refused(capsys, 2, argv, out, "--timestamps", "frame_0000")
    (tmp_path / "short.csv").write_text("\n".join(rows[:-1]) + "\n")
    _refused(capsys, 2, argv + ["--timestamps", tmp_path / "short.csv"], out, f"1 of the {len(t)} images", "not listed")
    code, _, err = run(capsys, *argv, "--timestamps", tmp_path / "data.csv")
    assert code == 0, err
    cam = json.loads(out.read_text())["cameras"][0]
    T = torch.tensor(cam["T_cam_imu"], dtype=torch.float64)
    assert cam["frames_used"] >= 20
    assert float((T[:3, 3] - rec.T_cam_imu[0, :3, 3]).norm()) < 0.01
    assert abs(cam["timeshift_cam_imu"] - float(rec.shift[0])) < 1e-3


def test_video(capsys, tmp_path):
    # a video's frame times are its container's (frame k at k / fps, from 0); the IMU's log is stamped from another
    # origin (1000 s on): refused as clocks that do not overlap, then aligned from the motion with --align-clocks
    from _videos import write_video

    rec, t, images = rendered_frames(31)
    write_video(str(tmp_path / "cam0.avi"), images, fps=10.0)
    write_imu_csv(tmp_path / "imu0.csv", rec, offset_s=1000.0)
    write_json(tmp_path / "cam.json", {**camera_record_fields(rec.cameras[0]), "rms": 0.2})
    out = tmp_path / "imu_cam.json"
    argv = ["calibrate-imu", "--flat-board", tmp_path / "cam0.avi", "--imu", tmp_path / "imu0.csv", "--board", "7x6", "--square",
            "0.08", "--calibration", tmp_path / "cam.json", "--detector", "opencv", "--jobs", "1", "--output", out]
    _refused(capsys, 2, argv, out, "overlap", "--align-clocks")
    code, _, err = run(capsys, *argv, "--align-clocks")
    assert code == 0, err
    cam = json.loads(out.read_text())["cameras"][0]
    T = torch.tensor(cam["T_cam_imu"], dtype=torch.float64)
    assert cam["frames_used"] >= 20
    assert float((T[:3, 3] - rec.T_cam_imu[0, :3, 3]).norm()) < 0.01
    truth = float(t[0]) + float(rec.shift[0]) + 1000.0  # t_imu = t_video + t[0] + shift, the log 1000 s on
    assert abs(cam["timeshift_cam_imu"] - truth) < 1e-3
    assert abs(cam["time_offset_search"]["clock_offset_s"] - truth) < 0.05
    # a video and a folder together are refused
    (tmp_path / "cam1").mkdir()
    _refused(capsys, 2, ["calibrate-imu", tmp_path / "cam0.avi", tmp_path / "cam1", "--imu", tmp_path / "imu0.csv",
                         "--board", "7x6", "--output", tmp_path / "mixed.json"], tmp_path / "mixed.json", "same way")


def test_bag(capsys, tmp_path):
    # a ROS1 bag with the camera's images and the IMU's samples, written with rosbags; the clocks from the epoch (the
    # readers of ROS2 bags are the same functions: tests/io/test_rosbag.py)
    from _rosbags import T0, BagContent, write_bag

    rec, t, images = rendered_frames(31)

    def stamp(seconds: float) -> tuple[int, int]:
        ns = round(seconds * 1e9) + T0 * 10**9
        return ns // 10**9, ns % 10**9

    frames = [(*stamp(ts), images[k]) for k, ts in enumerate(t.tolist())]
    imu = [(*stamp(ts), tuple(w), tuple(a)) for ts, w, a in zip(rec.imu_times.tolist(), rec.gyro.tolist(),
                                                                rec.accel.tolist())]
    path = write_bag(tmp_path / "rec.bag", BagContent({"/cam0/mono8": frames}, imu), ros1=True)
    write_json(tmp_path / "cam.json", {**camera_record_fields(rec.cameras[0]), "rms": 0.2})
    out = tmp_path / "imu_cam.json"
    code, _, err = run(capsys, "calibrate-imu", "--flat-board", "--bag", path, "--image-topics", "/cam0/mono8", "--imu-topic", "/imu0",
                       "--board", "7x6", "--square", "0.08", "--calibration", tmp_path / "cam.json", "--detector",
                       "opencv", "--jobs", "1", "--output", out)
    assert code == 0, err
    cam = json.loads(out.read_text())["cameras"][0]
    T = torch.tensor(cam["T_cam_imu"], dtype=torch.float64)
    assert float((T[:3, 3] - rec.T_cam_imu[0, :3, 3]).norm()) < 0.01
    assert abs(cam["timeshift_cam_imu"] - float(rec.shift[0])) < 1e-3


def test_bag_without_the_topic(capsys, tmp_path, recording):
    from _rosbags import content, write_bag

    path = write_bag(tmp_path / "rec.bag", content(), ros1=True)
    write_json(tmp_path / "cam.json", {**camera_record_fields(recording.cameras[0]), "rms": 0.2})
    _refused(capsys, 2, ["calibrate-imu", "--bag", path, "--image-topics", "/cam0/image_raw", "--imu-topic", "/imu0",
                         "--board", "7x6", "--square", "0.08", "--calibration", tmp_path / "cam.json", "--output",
                         tmp_path / "imu_cam.json"], tmp_path / "imu_cam.json", "/cam0/image_raw")
