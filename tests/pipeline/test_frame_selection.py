"""The frame selection: which views it keeps and why it leaves out the others (moving, blurred, a near copy, adding
nothing, over the cap), the views it keeps when few are left, and the stage inside the single-camera and rig
pipelines (the calibration uses the views kept, the records say why the others are out)."""

from __future__ import annotations

import pytest
import torch
from _rig_images import BOARD as RIG_BOARD
from _rig_images import SQUARE as RIG_SQUARE
from _rig_images import render_stereo

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.outputs.records import camera_record
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.pipeline.frame_selection import (
    CameraViews,
    FrameSelection,
    board_extent,
    choose_frames,
    motion_weight,
    near_copies,
)
from ccs_kornia.pipeline.rig_pipeline import RigPipeline

OBJ = board_object_points(9, 6, 0.03, dtype=torch.float64)
K = torch.tensor([[800.0, 0, 640], [0, 800, 360], [0, 0, 1]], dtype=torch.float64)
DIST = torch.tensor([-0.2, 0.05, 0.0, 0.0, 0.0], dtype=torch.float64)
SIZE = (1280, 720)
LABELS = [f"frame {k}" for k in range(40)]


def _camera(num: int = 16, seed: int = 0, speed=None, sharpness=None, copy: dict | None = None) -> CameraViews:
    """``num`` views of the board (view ``k`` of ``copy`` nearly repeats view ``copy[k]``'s pose), solved."""
    g = torch.Generator().manual_seed(seed)
    rvec = (torch.rand(num, 3, generator=g, dtype=torch.float64) - 0.5) * 0.8
    tvec = torch.cat([(torch.rand(num, 2, generator=g, dtype=torch.float64) - 0.5) * 0.4 - 0.12,
                      0.6 + 0.4 * torch.rand(num, 1, generator=g, dtype=torch.float64)], 1)
    for k, j in (copy or {}).items():  # nearly the pose of view j (an exact repeat the solver itself leaves out)
        rvec[k], tvec[k] = rvec[j] + 0.01, tvec[j] + 0.003
    uv = project_points(OBJ.expand(num, -1, -1), K.expand(num, 3, 3), DIST.expand(num, 5), rvec, tvec)
    uv = uv + 0.05 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
    res = CalibrationSolver(model=K1K2, use_ransac=False)(uv[None], torch.ones(1, num, 54, dtype=torch.bool), OBJ,
                                                            SIZE)
    sharp = torch.full((num,), 0.01, dtype=torch.float64) if sharpness is None else torch.tensor(sharpness)
    return CameraViews(res.camera[0], res.rvec[0], res.tvec[0], uv, torch.ones(num, 54,
                       dtype=torch.bool), torch.ones(num, 54, dtype=torch.float64), OBJ, res.used[0], sharp,
                       list(speed) if speed is not None else [None] * num, float(res.rms[0]))


def test_motion_weight_and_near_copies():
    assert motion_weight(None, 1000.0, 0.03) == 1.0
    assert motion_weight(30.0, 1000.0, 0.03) == pytest.approx(0.5)
    assert motion_weight(30.0, 1000.0, 0.03, 1.0, 1.0) == pytest.approx(1 / 3)
    board = torch.tensor([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0], [0.0, 30.0], [20.0, 15.0]])
    corners = board.repeat(3, 1, 1)
    corners[1] += 1.0  # 1.4 px: under a tenth of the board's size (RMS 22.4 px from its centre)
    corners[2] += 50.0
    valid = torch.ones(3, 5, dtype=torch.bool)
    valid[2, :2] = False
    near = near_copies(corners, valid, 0.1)
    assert near.tolist() == [[False, True, False], [True, False, False], [False, False, False]]
    assert not bool(near_copies(corners, valid, 0.1, min_common=6).any())  # too few corners in common
    # measured against the board, not the image: the same motion relative to a board ten times smaller is as new
    assert torch.equal(near_copies(corners / 10.0, valid, 0.1), near)
    assert not bool(near_copies(corners, valid, 0.05)[0, 1])


def test_board_extent():
    board = torch.tensor([[[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]], dtype=torch.float64)
    valid = torch.ones(1, 4, dtype=torch.bool)
    assert board_extent(board, valid).item() == pytest.approx(2.5)
    valid[0, 2] = False  # a corner not shown does not count, wherever its coordinates are
    far = board.clone()
    far[0, 2] = 1e6
    assert board_extent(far, valid).item() == pytest.approx(board_extent(board, valid).item())
    assert board_extent(board, torch.zeros(1, 4, dtype=torch.bool)).item() == 0.0


def test_each_view_left_out_says_why():
    speed = [0.0] * 16
    speed[3] = 1000.0  # 0.68 diagonals a second: moving
    sharp = [0.01] * 16
    sharp[7] = 0.04  # corners four times softer than the others': blurred
    cam = _camera(speed=speed, sharpness=sharp, copy={9: 2})
    choice = choose_frames([cam], selection=FrameSelection(min_gain=0.0), labels=LABELS[:16])
    assert choice.reasons[3] == "moving (1000 px/s)" and not choice.kept[3]
    assert choice.reasons[7] == "blurred (corners 4.0x the median)" and not choice.kept[7]
    # a near copy waits until every new view is taken, then counts like any view: here it comes last
    assert choice.kept[2] and choice.kept[9] and choice.order[-1] in (2, 9)
    assert choice.kept == [not r for r in choice.reasons] and choice.candidates == 16
    # with the cap reached first, the copy is the one left out, and says of what
    capped = choose_frames([cam], selection=FrameSelection(max_frames=13, min_gain=0.0), labels=LABELS[:16])
    assert capped.kept[2] != capped.kept[9]
    assert capped.reasons[9 if capped.kept[2] else 2] == f"near copy of frame {2 if capped.kept[2] else 9}"
    assert sum(capped.kept) == 13
    assert choice.view_reasons[0] == choice.reasons  # one camera: its views are the frames
    record = choice.record([f"cam.mp4#{k}" for k in range(16)])
    assert record["kept"] == sum(choice.kept) and record["frames"][3]["reason"].startswith("moving")
    assert record["order"][-1] in ("cam.mp4#2", "cam.mp4#9")
    assert len(record["uncertainty_px"][0]) == sum(choice.kept) + 1


def test_the_cap_and_the_stop():
    cam = _camera(24, seed=1)
    capped = choose_frames([cam], selection=FrameSelection(max_frames=5, min_gain=0.0))
    assert sum(capped.kept) == 5 and capped.reasons.count("over --max-frames") >= 15
    assert all(r == "over --max-frames" or r.startswith("near copy of ") for r in capped.reasons if r)
    stopped = choose_frames([cam], selection=FrameSelection(min_gain=0.05))
    assert 8 <= sum(stopped.kept) < 24 and "adds nothing" in stopped.reasons
    gains = [stopped.gain[f] for f in stopped.order]
    assert len(gains) == 8 or min(gains) >= 0.05  # at least min_keep views, whatever they add


def test_too_few_left_brings_the_moving_back():
    cam = _camera(12, seed=2, speed=[500.0] * 12)  # every view moving
    choice = choose_frames([cam], selection=FrameSelection(min_keep=8))
    assert sum(choice.kept) == 8
    assert all(r.startswith("moving") for r, k in zip(choice.reasons, choice.kept) if not k)


def test_a_rig_frame_is_judged_across_its_cameras():
    a, b = _camera(10, seed=3), _camera(10, seed=4)
    index = [list(range(10)), [None] * 5 + list(range(5))]  # camera 1 sees frames 5..9 (its views 0..4)
    spread = [None] * 5 + [0.001, 0.001, 0.05, 0.001, 0.001]
    b.speed = [100.0] * 10  # frame 7: 50 ms between the cameras at 100 px/s = 5 px
    choice = choose_frames([a, b], index, FrameSelection(min_gain=0.0, max_sync_px=2.0), spread,
                           [f"frame {k}" for k in range(10)])
    assert choice.reasons[7].startswith("moving (100 px/s, its cameras 50 ms apart: 5.0 px)")
    assert choice.view_reasons[1][2] == choice.reasons[7]  # camera 1's view of frame 7
    assert len(choice.uncertainty_px) == 2 and any(choice.kept[5:])


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="max_frames"):
        FrameSelection(max_frames=0)
    with pytest.raises(ValueError, match="min_gain"):
        FrameSelection(min_gain=-1.0)
    with pytest.raises(ValueError, match="index"):
        choose_frames([None, None])


@pytest.fixture(scope="module")
def views():
    K0 = torch.tensor([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]], dtype=torch.float64)
    return make_calibration_set(K0, (6, 4), 0.025, (320, 240), num_views=18, seed=5, supersample=1)


def test_the_stage_in_the_pipeline_calibrates_on_the_views_kept(views):
    pipe = CalibrationPipeline("opencv", model=K1K2, distortion_correction=False, use_ransac=False,
                               frame_selection=FrameSelection(max_frames=10))
    out = pipe(views.images, (6, 4), 0.025)
    choice = out.frame_choice
    kept = torch.tensor(choice.view_kept(0))
    assert 3 <= int(kept.sum()) <= 10
    assert bool((out.used <= kept).all()) and int(out.used.sum()) >= 3
    assert bool((out.K - views.K).abs().max() < 3.0)
    record = camera_record(out, [f"v{k}.png" for k in range(18)], board=(6, 4), square=0.025, detector="opencv",
                           model=K1K2)
    left = [v for v, keep in zip(record["views"], choice.view_kept(0)) if not keep and v["found"]]
    assert left and all(v["reason"].startswith("left out by the frame selection: ") and not v["used"] for v in left)
    assert record["selection"]["kept"] == int(kept.sum()) and record["num_views"]["used"] == int(out.used.sum())


def test_the_stage_sees_every_source_alike(views):
    plain = CalibrationPipeline("opencv", model=K1K2, distortion_correction=False, use_ransac=False)(
        views.images, (6, 4), 0.025)
    assert plain.frame_choice is None  # without a selection every view counts


def test_a_rig_keeps_the_frames_chosen_across_its_cameras():
    stereo = render_stereo(frames=10, seed=3)
    pipe = RigPipeline("opencv", models=K1K2, distortion_correction=False, use_ransac=False,
                       frame_selection=FrameSelection(min_gain=0.02))
    out = pipe(stereo.images, RIG_BOARD, RIG_SQUARE, names=["left", "right"])
    assert out.success, out.reason
    choice = out.frame_choice
    assert out.candidates.num_frames == 10 and out.frames.num_frames == sum(choice.kept) >= 3
    assert out.frames.labels == [out.candidates.labels[f] for f in range(10) if choice.kept[f]]
    for c in range(2):  # the cameras' views of frames left out are not in the joint fit
        left = [out.candidates.index[c][f] for f in range(10) if not choice.kept[f]]
        assert not bool(out.cameras[c].calibration.used[left].any()) if left else True
    assert abs(float(out.rig.T[1].norm()) - float(stereo.T.norm())) < 0.02 * float(stereo.T.norm())


def test_moving_views_come_in_where_the_still_ones_do_not_cover_the_poses():
    cam = _camera(14, seed=6, speed=[None] * 14)
    parallel = torch.tensor([0.02, -0.01, 0.0], dtype=torch.float64)
    cam.rvec[:6] = parallel + 0.005 * torch.arange(6, dtype=torch.float64)[:, None]  # still views, nearly parallel
    cam.speed = [0.0] * 6 + [500.0] * 8  # the rest moving
    choice = choose_frames([cam], selection=FrameSelection(min_keep=4))
    assert any(choice.kept[6:])  # the tilted poses, though moving
    cam.rvec[6:] = parallel  # moving views that add no pose stay out
    choice = choose_frames([cam], selection=FrameSelection(min_keep=4))
    assert not any(choice.kept[6:]) and all(r.startswith("moving") for r in choice.reasons[6:])
