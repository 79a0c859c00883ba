"""The rig pipeline entry (ccs_kornia.pipeline.rig_pipeline): observations gathered per camera and frame, connectivity, and
the whole path on rendered stereo images (detection per camera, each camera's calibration, the joint rig fit)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch
from _rig_images import ANGLE_DEG, BOARD, SQUARE, T_REL, render_stereo, write_stereo

from ccs_kornia.geometry.models import K1K2, OPENCV5
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.pipeline.frame_matching import FrameTable
from ccs_kornia.pipeline.result import PipelineResult
from ccs_kornia.pipeline.rig_pipeline import (
    RigPipeline,
    rig_observations,
    unconnected_cameras,
)
from ccs_kornia.pipeline.sources import TensorSource


def _camera(corners: torch.Tensor, found: list[bool], used: list[bool] | None = None, size=(64, 48)) -> PipelineResult:
    v = corners.shape[0]
    det = DetectionResult(corners.double(), torch.tensor(found), [""] * v)
    cal = None if used is None else SimpleNamespace(success=torch.tensor(True), used=torch.tensor(used))
    return PipelineResult(det, cal, size, torch.ones(v, dtype=torch.bool), torch.tensor(size).expand(v, 2).clone())


def test_observations_follow_the_frame_table():
    a = torch.rand(3, 4, 2) * 40
    b = torch.rand(2, 4, 2) * 40
    b[1, 2] = float("nan")  # a partial board: the detector's hidden corner
    frames = FrameTable(["1", "2", "3"], [[0, 1, 2], [None, 0, 1]], "number")
    corners, valid, weights = rig_observations([_camera(a, [True] * 3), _camera(b, [True, True])], frames)
    assert corners.shape == (2, 3, 4, 2) and valid.shape == (2, 3, 4) and weights is None
    assert valid[0].all() and not valid[1, 0].any() and valid[1, 1].all()
    assert valid[1, 2].tolist() == [True, True, False, True]
    assert torch.equal(corners[0], a.double()) and torch.equal(corners[1, 1], b[0].double())
    assert corners[1, 0].isnan().all() and corners[1, 2, 2].isnan().all()


def test_observations_leave_out_views_not_found_or_rejected():
    a = torch.rand(3, 4, 2) * 40
    frames = FrameTable(["0", "1", "2"], [[0, 1, 2], [0, 1, 2]], "order")
    cams = [_camera(a, [True, False, True]), _camera(a, [True, True, True], used=[True, True, False])]
    _, valid, _ = rig_observations(cams, frames)
    assert valid.any(-1).tolist() == [[True, False, True], [True, True, False]]


def test_observations_of_another_image_size_are_left_out():
    a = torch.rand(2, 4, 2) * 40
    cam = _camera(a, [True, True])
    cam.view_sizes[1] = torch.tensor([128, 96])
    _, valid, _ = rig_observations([cam, _camera(a, [True, True])], FrameTable(["0", "1"], [[0, 1], [0, 1]], "order"))
    assert valid.any(-1).tolist() == [[True, False], [True, True]]


def test_connected_rig_and_cut_camera():
    seen = torch.tensor([[True, True, False, False], [False, True, True, False], [False, False, True, False],
                         [False, False, False, True]])
    assert unconnected_cameras(seen[:3], ["a", "b", "c"], list("1234")) == ""  # c through b
    line = unconnected_cameras(seen, ["a", "b", "c", "d"], list("1234"))
    assert line.startswith("camera d shares no frame with camera a") and "d: 4" in line and "a sees frames 1, 2" in line


def test_fewer_than_two_cameras_raise():
    pipe = RigPipeline("opencv", models=K1K2, distortion_correction=False, use_ransac=False)
    with pytest.raises(ValueError, match="at least two cameras"):
        pipe(torch.zeros(1, 3, 1, 48, 64), BOARD, SQUARE)


@pytest.fixture(scope="module")
def stereo():
    return render_stereo(frames=8, seed=3)


def _check_rig(out, frames: int = 8) -> None:
    assert out.success, out.reason
    rig = out.rig
    assert rig.R.shape == (2, 3, 3) and rig.T.shape == (2, 3)
    baseline = float(rig.T[1].norm())
    assert abs(baseline - float(T_REL.norm())) < 0.01 * float(T_REL.norm())
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(rig.R[1])) - 1) / 2))))
    assert abs(angle - ANGLE_DEG) < 0.1
    assert out.corners.shape[:2] == (2, frames) and bool(out.valid.any(-1).any(0).all())


def test_rig_from_rendered_images_of_two_sizes(stereo):
    # image sizes differ per camera: one list entry per camera
    pipe = RigPipeline("opencv", models=K1K2, distortion_correction=False, use_ransac=False)
    out = pipe(stereo.images, BOARD, SQUARE, names=["left", "right"])
    _check_rig(out)
    assert out.names == ["left", "right"] and out.models == [K1K2, K1K2]
    assert [tuple(r.image_size) for r in out.cameras] == [(320, 240), (352, 264)]


def test_models_per_camera_and_fixed_intrinsics(stereo):
    from ccs_kornia.geometry.camera import Camera

    pipe = RigPipeline("opencv", models=[K1K2, OPENCV5], distortion_correction=False, use_ransac=False)
    cameras = pipe.detect_and_calibrate(TensorSource(stereo.images), BOARD, SQUARE)
    assert [r.calibration.camera.model for r in cameras] == [K1K2, OPENCV5]
    K0 = cameras[0].calibration.K.double()
    pipe.fixed = {0: Camera.from_opencv(K1K2, K0)}
    frames = FrameTable([str(k) for k in range(8)], [list(range(8))] * 2, "order")
    out = pipe.run(TensorSource(stereo.images), BOARD, SQUARE, frames, cameras=cameras)
    _check_rig(out)
    assert out.fixed == [True, False]
    assert torch.allclose(out.rig.cameras[0].K.double(), K0)


def test_batch_of_rigs_matches_one_rig_at_a_time():
    stereo = render_stereo(frames=6, seed=5, size1=(320, 240))
    one = torch.stack(stereo.images)  # (C, F, 1, H, W)
    batch = torch.stack([one, one.flip(1)])  # the second rig: the same frames in reverse order
    pipe = RigPipeline("opencv", models=K1K2, distortion_correction=False, use_ransac=False)
    outs = pipe(batch, BOARD, SQUARE)
    single = pipe(one, BOARD, SQUARE)
    assert isinstance(outs, list) and len(outs) == 2
    for out in (*outs, single):
        _check_rig(out, frames=6)
    for out in outs:
        assert torch.allclose(out.rig.T, single.rig.T, atol=1e-6) and torch.allclose(out.rig.R, single.rig.R, atol=1e-7)
    assert torch.equal(outs[1].corners, single.corners.flip(1))


def test_rig_from_files_matched_by_number(stereo, tmp_path):
    # the right camera misses frame 03 and its files are listed in another order
    left, right = write_stereo(stereo, tmp_path, frames=[list(range(8)), [k for k in range(8) if k != 2]])
    paths = [sorted(str(p) for p in left.iterdir()), sorted((str(p) for p in right.iterdir()), reverse=True)]
    pipe = RigPipeline("opencv", models=K1K2, distortion_correction=False, use_ransac=False)
    out = pipe.run_files(paths, BOARD, SQUARE, names=["left", "right"])
    _check_rig(out)
    assert out.frames.by == "number" and out.frames.missing(1) == ["03"]
    assert not out.valid[1, 2].any() and bool(out.rig.rms_matrix[1, 2].isnan())
