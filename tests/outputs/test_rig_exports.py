"""The rig export formats (ccs_kornia.outputs.rig_exports, rig_records) on a hand-made rig record: a fisheye and a
pinhole camera (the mixed pair), a third camera for the Kalibr chain."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from ccs_kornia.geometry.poses import pair_pose
from ccs_kornia.outputs.rig_exports import (
    KALIBR_DISTORTION,
    kalibr_camchain,
    kalibr_problem,
    rectification,
    ros_stereo_files,
    write_opencv_stereo_yaml,
)
from ccs_kornia.outputs.rig_records import (
    record_extrinsics,
    rectify_maps,
    rotation_angle_deg,
)

K_A = [[300.0, 0.0, 321.0], [0.0, 301.0, 239.0], [0.0, 0.0, 1.0]]
K_B = [[520.0, 0.0, 318.0], [0.0, 519.0, 242.0], [0.0, 0.0, 1.0]]
FISHEYE = [0.05, -0.01, 0.002, 0.0]
OPENCV5 = [-0.2, 0.05, 0.001, -0.0005, 0.01]


def _rot(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.array(rvec, dtype=np.float64))[0]


def _record(third: str = "k1k2") -> dict:
    R1, T1 = _rot([0.01, -0.02, 0.005]), np.array([-0.1, 0.002, 0.001])
    R2, T2 = _rot([0.0, 0.3, 0.0]), np.array([-0.25, 0.0, 0.05])
    cams = [("a", K_A, "fisheye", FISHEYE), ("b", K_B, "opencv5", OPENCV5),
            ("c", K_B, third, [-0.1, 0.01, 0, 0, 0] if third == "k1k2" else [0.1] * 8)]
    data = {
        "cameras": [{"name": n, "image_size": [640, 480], "K": K, "distortion": {"model": m, "coeffs": d}}
                    for n, K, m, d in cams],
        "extrinsics": [{"R": np.eye(3).tolist(), "T": [0.0, 0.0, 0.0]}, {"R": R1.tolist(), "T": T1.tolist()},
                       {"R": R2.tolist(), "T": T2.tolist()}],
        "rms": 0.1,
    }
    R, T = (x.numpy() for x in pair_pose(*record_extrinsics(data["extrinsics"]), 0, 1))
    E = np.array([[0, -T[2], T[1]], [T[2], 0, -T[0]], [-T[1], T[0], 0]]) @ R
    F = np.linalg.inv(np.array(K_B)).T @ E @ np.linalg.inv(np.array(K_A))
    data["pairs"] = [{"cameras": [0, 1], "E": E.tolist(), "F": F.tolist()}]
    return data


def test_pair_pose_and_rotation_angle():
    data = _record()
    R, T = pair_pose(*record_extrinsics(data["extrinsics"]), 1, 2)
    R1, T1 = np.array(data["extrinsics"][1]["R"]), np.array(data["extrinsics"][1]["T"])
    R2, T2 = np.array(data["extrinsics"][2]["R"]), np.array(data["extrinsics"][2]["T"])
    x0 = np.array([0.3, -0.2, 2.0])
    assert np.allclose(R.numpy() @ (R1 @ x0 + T1) + T.numpy(), R2 @ x0 + T2)
    assert rotation_angle_deg(_rot([0.0, 0.0, np.radians(30.0)])) == pytest.approx(30.0)


def test_mixed_pair_rectifies_to_common_rows():
    data = _record()
    rect = rectification(data, 0, 1)
    assert {"R1", "R2", "P1", "P2", "Q"} <= set(rect) and rect["image_size"] == (640, 480)
    for mx, my in rectify_maps(data, rect, 0, 1):
        assert mx.shape == (480, 640) and np.isfinite(mx).all() and np.isfinite(my).all()
    # points in front of both cameras, projected by each camera's own model, meet on the same rectified row
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.4, 0.4, 30), rng.uniform(-0.3, 0.3, 30), rng.uniform(1.5, 3.0, 30)]
    R, T = (x.numpy() for x in pair_pose(*record_extrinsics(data["extrinsics"]), 0, 1))
    a, _ = cv2.fisheye.projectPoints(pts[:, None], np.zeros(3), np.zeros(3), np.array(K_A), np.array(FISHEYE))
    b, _ = cv2.projectPoints(pts, cv2.Rodrigues(R)[0], T, np.array(K_B), np.array(OPENCV5))
    ra = cv2.fisheye.undistortPoints(a, np.array(K_A), np.array(FISHEYE), R=rect["R1"], P=rect["P1"])[:, 0]
    rb = cv2.undistortPoints(b, np.array(K_B), np.array(OPENCV5), R=rect["R2"], P=rect["P2"])[:, 0]
    assert np.abs(ra[:, 1] - rb[:, 1]).max() < 0.05


def test_opencv_yaml_of_a_fisheye_camera(tmp_path):
    data = _record()
    rect = rectification(data, 0, 1)
    path = tmp_path / "stereo.yml"
    write_opencv_stereo_yaml(str(path), data, rect)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("distortion_model1").string() == "fisheye" and fs.getNode("distortion_model2").string() == "opencv"
    assert np.allclose(fs.getNode("D1").mat().ravel(), FISHEYE) and np.allclose(fs.getNode("D2").mat().ravel(), OPENCV5)
    assert np.allclose(fs.getNode("P2").mat(), rect["P2"]) and np.allclose(fs.getNode("F").mat(), data["pairs"][0]["F"])
    fs.release()
    assert [p.name for p in tmp_path.iterdir()] == ["stereo.yml"]  # the temporary file was renamed


def test_opencv_yaml_of_the_pair_in_the_other_order(tmp_path):
    """The pair 1, 0 (camera 1 first): its E and F are the record's transposed, x1^T F x0 = 0 becomes x0^T F' x1."""
    data = _record()
    rect = rectification(data, 1, 0)
    path = tmp_path / "stereo.yml"
    write_opencv_stereo_yaml(str(path), data, rect, 1, 0)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert np.allclose(fs.getNode("K1").mat(), K_B) and np.allclose(fs.getNode("K2").mat(), K_A)
    R, T = (x.numpy() for x in pair_pose(*record_extrinsics(data["extrinsics"]), 1, 0))
    assert np.allclose(fs.getNode("R").mat(), R) and np.allclose(fs.getNode("T").mat().ravel(), T)
    E = np.array([[0, -T[2], T[1]], [T[2], 0, -T[0]], [-T[1], T[0], 0]]) @ R
    assert np.allclose(fs.getNode("E").mat(), E)
    assert np.allclose(fs.getNode("F").mat(), np.array(data["pairs"][0]["F"]).T)
    fs.release()


def test_ros_files_of_a_fisheye_camera():
    data = _record()
    files = ros_stereo_files(data, rectification(data, 0, 1), ("front", "side"))
    assert sorted(files) == ["front.yaml", "side.yaml"]
    front, side = yaml.safe_load(files["front.yaml"]), yaml.safe_load(files["side.yaml"])
    assert front["distortion_model"] == "equidistant" and front["distortion_coefficients"]["data"] == FISHEYE
    assert side["distortion_model"] == "plumb_bob" and len(side["distortion_coefficients"]["data"]) == 5
    assert front["camera_name"] == "front" and len(side["projection_matrix"]["data"]) == 12


def test_kalibr_chain_of_three_cameras():
    data = _record()
    text, notes = kalibr_camchain(data)
    chain = yaml.safe_load(text)
    assert [chain[k]["distortion_model"] for k in ("cam0", "cam1", "cam2")] == ["equidistant", "radtan", "radtan"]
    assert chain["cam0"]["distortion_coeffs"] == FISHEYE and chain["cam1"]["distortion_coeffs"] == OPENCV5[:4]
    assert len(notes) == 1 and "k3" in notes[0] and "camera b" in notes[0]
    # chaining T_cn_cnm1 from camera 0 gives every camera's extrinsics
    pose = np.eye(4)
    for k in (1, 2):
        pose = np.array(chain[f"cam{k}"]["T_cn_cnm1"]) @ pose
        assert np.allclose(pose[:3, :3], data["extrinsics"][k]["R"]) and np.allclose(pose[:3, 3], data["extrinsics"][k]["T"])
    assert kalibr_problem(data) == ""
    assert "camera c (rational)" in kalibr_problem(_record("rational"))


def test_kalibr_models():
    from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, PINHOLE, RATIONAL

    assert KALIBR_DISTORTION == {PINHOLE: "radtan", K1K2: "radtan", OPENCV5: "radtan", FISHEYE: "equidistant"}
    assert RATIONAL not in KALIBR_DISTORTION
