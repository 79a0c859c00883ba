"""A single AprilTag: its corners from rendered views with exact ground truth (to a few hundredths of a pixel,
several times closer than OpenCV's own corner refinement), through a distorted lens, the tag chosen by id, refusals,
and the real tag of ViSP's Franka data."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.data.scenes.marker_views import render_marker_view
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import OPENCV5
from ccs_kornia.modules.detection.markers.apriltag import (
    AprilTagDetector,
    AprilTagTarget,
    detect_apriltag,
    refine_tag_corners,
)
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.pipeline.sources import TensorSource

K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])


def _views(target, n, seed, dist=None, blur=(0.5, 1.2)):
    rng = np.random.default_rng(seed)
    dist = np.zeros(5) if dist is None else dist
    out = []
    for _ in range(n):
        rv = rng.uniform(-0.6, 0.6, 3)
        tv = np.array([rng.uniform(-0.06, 0.06), rng.uniform(-0.05, 0.05), rng.uniform(0.25, 0.5)])
        img, truth = render_marker_view(target, rv, tv, K, dist, (640, 480), supersample=3)
        img = cv2.GaussianBlur(img.astype(np.float64), (0, 0), rng.uniform(*blur)) + rng.normal(0, 2, img.shape)
        out.append((np.clip(np.round(img), 0, 255).astype(np.uint8), truth))
    return out


def _batch(images):
    return torch.from_numpy(np.stack(images).astype(np.float32))[:, None] / 255.0


def test_target_layout():
    t = AprilTagTarget("36h11", 0.048, tag_id=5)
    obj = t.object_points()
    assert obj.shape == (4, 3) and t.board_size == (2, 2) and t.bits == 8
    assert obj[:, 0].tolist() == [-0.024, 0.024, -0.024, 0.024] and obj[:, 1].tolist() == [-0.024, -0.024, 0.024, 0.024]
    with pytest.raises(ValueError, match="unknown AprilTag family"):
        AprilTagTarget("41h12", 0.05)
    with pytest.raises(ValueError, match="positive"):
        AprilTagTarget("36h11", 0.0)


def test_corners_to_hundredths_of_a_pixel_and_closer_than_opencv():
    target = AprilTagTarget("36h11", 0.048, tag_id=10)
    views = _views(target, 8, seed=1)
    det = AprilTagDetector(target)(_batch([v[0] for v in views]))
    assert det.corners.shape == (8, 4, 2) and bool(det.found.all())
    ours = np.concatenate([np.linalg.norm(det.corners[k].numpy() - t, axis=-1) for k, (_, t) in enumerate(views)])
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    cv = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), params)
    theirs = []
    for img, truth in views:
        c, _, _ = cv.detectMarkers(img)
        theirs.append(np.linalg.norm(c[0].reshape(4, 2)[[0, 1, 3, 2]] - truth, axis=-1))
    assert ours.mean() < 0.06 and ours.max() < 0.3
    assert ours.mean() < 0.5 * np.concatenate(theirs).mean()


def test_the_lens_is_followed_when_given():
    target = AprilTagTarget("36h11", 0.06, tag_id=2)
    dist = np.array([-0.35, 0.12, 0.0, 0.0, 0.0])
    views = _views(target, 4, seed=2, dist=dist)

    def undistort(p):
        return cv2.undistortPoints(p.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)

    def distort(p):
        n = cv2.undistortPoints(p.reshape(-1, 1, 2), K, None).reshape(-1, 2)
        return cv2.projectPoints(np.c_[n, np.ones(len(n))], np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)

    det = detect_apriltag(_batch([v[0] for v in views]), target, undistort, distort)
    err = np.concatenate([np.linalg.norm(det.corners[k].numpy() - t, axis=-1) for k, (_, t) in enumerate(views)])
    assert bool(det.found.all()) and err.mean() < 0.1


def test_the_tag_by_id_and_the_reasons():
    target = AprilTagTarget("36h11", 0.05, tag_id=7)
    (img, _), = _views(target, 1, seed=3)
    blank = np.full_like(img, 200)
    det = detect_apriltag(_batch([img, blank]), AprilTagTarget("36h11", 0.05, tag_id=8))
    assert det.found.tolist() == [False, False] and "id 8 not found (tags [7] seen)" in det.reasons[0]
    det = detect_apriltag(_batch([img, blank]), AprilTagTarget("36h11", 0.05))  # the id found in most images
    assert det.found.tolist() == [True, False] and det.reasons[0] == "apriltag 36h11 id 7"


def test_the_detector_follows_the_camera_and_takes_each_image_alone():
    dist = np.array([-0.35, 0.12, 0.0, 0.0, 0.0])
    views = _views(AprilTagTarget("36h11", 0.06, tag_id=2), 2, seed=2, dist=dist) + \
        _views(AprilTagTarget("36h11", 0.06, tag_id=5), 1, seed=4, dist=dist)
    images = _batch([v[0] for v in views])
    camera = Camera.from_opencv(OPENCV5, torch.from_numpy(K), torch.from_numpy(dist))
    target = AprilTagTarget("36h11", 0.06)  # no id: each image's own tag
    det = AprilTagDetector(target, camera)(images, (2, 2))
    assert det.found.tolist() == [True, True, True] and det.reasons[2] == "apriltag 36h11 id 5"
    err = np.concatenate([np.linalg.norm(det.corners[k].numpy() - t, axis=-1) for k, (_, t) in enumerate(views)])
    assert err.mean() < 0.1
    # the whole batch at once keeps the id found in most of its images
    assert detect_apriltag(images, target).found.tolist() == [True, True, False]
    # the pipeline drives it: the same corners in batches of two, in two worker processes
    pipe = CalibrationPipeline(AprilTagDetector(target, camera), detection_batch_size=2, workers=2,
                               distortion_correction=False, weigh_corners=False)
    out = pipe.run(TensorSource(images[None]), (2, 2), calibrate=False).select(0)
    assert torch.equal(out.detections.found, det.found)
    assert torch.equal(out.detections.corners, det.corners) and out.detections.reasons == det.reasons


def test_a_side_without_an_edge_is_refused():
    img = np.full((60, 60), 200.0)
    corners, why = refine_tag_corners(img, np.array([[15.0, 20], [44, 21], [44, 39], [14, 39]]), 8)
    assert corners is None and "no clear edge" in why
    corners, why = refine_tag_corners(img, np.array([[15.0, 20], [17, 20], [17, 22], [15, 22]]), 8)
    assert corners is None and "too small" in why


FRANKA = REAL_DATA / "visp_franka_eye_to_hand"


@pytest.mark.skipif(not FRANKA.is_dir(), reason=f"real data not present in {FRANKA}")
def test_the_real_tag_of_visp_franka_data():
    from ccs_kornia.io.images import load_image_gray

    images = [np.asarray(load_image_gray(FRANKA / f"franka_image-{i}.png")[0]) for i in range(1, 9)]
    det = detect_apriltag(torch.from_numpy(np.stack(images))[:, None].float(), AprilTagTarget("36h11", 0.048))
    assert bool(det.found.all()) and det.reasons[0] == "apriltag 36h11 id 10"
    # within a pixel of OpenCV's integer corners, on every image
    cv = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11))
    for k, img in enumerate(images):
        c, _, _ = cv.detectMarkers((img * 255).astype(np.uint8) if img.dtype != np.uint8 else img)
        assert np.abs(det.corners[k].numpy() - c[0].reshape(4, 2)[[0, 1, 3, 2]]).max() < 2.0
