"""Tests of the recording renderer: hand-held trajectories, rolling shutter, motion blur, exact corners, rigs' clocks
and extrinsics, video files and their ground truth."""

from __future__ import annotations

import csv
import inspect
import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.recordings.exposure import exposure_truth, render_exposure
from ccs_kornia.data.recordings.handheld import (
    BoardTrajectory,
    sample_handheld_trajectory,
)
from ccs_kornia.data.recordings.patterns import ChessPattern, TexturePattern
from ccs_kornia.data.recordings.recording_camera import (
    FisheyeLens,
    OpenCVLens,
    PinholeLens,
    RecordingCamera,
    lens_from_json,
)
from ccs_kornia.data.recordings.recording_files import (
    count_video_frames,
    read_truth,
    write_recording,
    write_rig_recording,
    write_video,
)
from ccs_kornia.data.recordings.recordings import (
    Recording,
    RigRecording,
    handheld_recording,
    handheld_rig_recording,
    webcam,
    webcam_rig,
)
from ccs_kornia.data.render.lens import project_board
from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.geometry.so3 import exp_so3

W, H = 640, 480
K = torch.tensor([[520.0, 0.0, 321.3], [0.0, 525.0, 238.6], [0.0, 0.0, 1.0]], dtype=torch.float64)
BOARD = ChessPattern(7, 5, 0.03)
LENSES = {"pinhole": PinholeLens(), "opencv": OpenCVLens([-0.2, 0.05, 0.001, -0.0008, 0.0]),
          "fisheye": FisheyeLens([0.02, -0.005, 0.001, 0.0], 190.0)}


def _pose(rv=(0.25, -0.3, 0.15), t=(-0.09, -0.05, 0.55)):
    return exp_so3(torch.tensor(rv, dtype=torch.float64)), torch.tensor(t, dtype=torch.float64)


def _moving(angular=(0.2, 0.3, 0.5), linear=(0.3, 0.1, 0.0)) -> BoardTrajectory:
    return BoardTrajectory.uniform(*_pose(), 2.0, angular=angular, linear=linear)


def _subpix_error(img: torch.Tensor, corners: torch.Tensor, board=(7, 5), blur: float = 1.0) -> np.ndarray:
    """cv2.findChessboardCorners must find the board on the 8-bit image; cv2.cornerSubPix (window about half a
    square, a little optical blur so that it does not lock to the pixel grid) then starts near each true corner."""
    u8 = (img.numpy() * 255).round().astype(np.uint8)
    found, _ = cv2.findChessboardCorners(u8, board)
    assert found
    im = cv2.GaussianBlur(img.numpy().astype(np.float32), (0, 0), blur)
    cc = corners.numpy()
    grid = cc.reshape(board[1], board[0], 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=1), axis=-1).min(), np.linalg.norm(np.diff(grid, axis=0), axis=-1).min())
    win = max(2, int(round(spacing / 4)))
    start = (cc + np.random.RandomState(0).uniform(-0.7, 0.7, cc.shape)).astype(np.float32).reshape(-1, 1, 2)
    out = cv2.cornerSubPix(im, start, (win, win), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5))
    return out.reshape(-1, 2) - cc


# ----------------------------------------------------------------------------------------------
# cameras and lenses
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(LENSES))
def test_lens_projection_is_the_renderers(name):
    lens = LENSES[name]
    pts = torch.tensor([[[0.1, -0.05, 0.6], [-0.2, 0.15, 0.5], [0.0, 0.0, 1.0], [0.3, 0.2, -0.5]]], dtype=torch.float64)
    cam = RecordingCamera(K, (W, H), lens).camera
    assert cam.model == lens.model and cam.image_size == (W, H) and torch.equal(cam.K[0], K.double())
    pix, ok = lens.project(pts, cam)
    dist = lens.dist[None] if isinstance(lens, OpenCVLens) else None
    fe = lens._fisheye_row(1, "cpu") if isinstance(lens, FisheyeLens) else None
    ref, ref_ok = project_board(pts, K[None], torch.zeros(1, 3, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64),
                                (W, H), dist, None, fe)
    assert torch.equal(ok, ref_ok)
    torch.testing.assert_close(pix[ok], ref[ok], atol=1e-9, rtol=0)
    assert lens_from_json(lens.to_json()).to_json() == lens.to_json()


@pytest.mark.parametrize("name", list(LENSES))
def test_lens_rays_and_derivatives(name):
    lens = LENSES[name]
    rays = lens.rays(K, (W, H))
    assert rays.x.shape == (H, W) and rays.reach.shape == (H, W) and bool(rays.reach[H // 2, W // 2])
    ys, xs = torch.meshgrid(torch.arange(10, H, 53), torch.arange(7, W, 71), indexing="ij")
    pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).double()
    z = rays.z.expand(H, W) if rays.z.dim() == 0 else rays.z
    r = torch.stack([rays.x[ys, xs], rays.y[ys, xs], z[ys, xs]], -1).reshape(-1, 3).double()
    back, ok = lens.project(r[None], lens.camera(K, (W, H)))
    assert bool(ok.all())
    assert float((back[0] - pix).abs().max()) < 2e-3  # float32 rays
    torch.testing.assert_close(lens.unproject(pix, K) / lens.unproject(pix, K).norm(dim=-1, keepdim=True),
                               r / r.norm(dim=-1, keepdim=True), atol=1e-5, rtol=0)
    # derivatives: a pixel to the right minus the pixel, against x_px
    x_px = rays.x_px.expand(H, W) if rays.x_px.dim() == 0 else rays.x_px
    fd = rays.x[ys, xs + 1] - rays.x[ys, xs]
    assert float((fd - x_px[ys, xs]).abs().max()) < 1e-3 * float(x_px.abs().max())


def test_camera_timing_and_errors():
    cam = RecordingCamera(K, (W, H), fps=30.0, exposure=0.01, line_time=40e-6, start=0.005)
    assert cam.readout == pytest.approx(479 * 40e-6)
    n = cam.num_frames(2.0)
    starts = cam.frame_starts(n)
    assert float(starts[-1] + cam.readout + cam.exposure) <= 2.0 < float(starts[-1] + 1 / 30 + cam.readout + cam.exposure)
    torch.testing.assert_close(cam.frame_times(starts) - starts, torch.full_like(starts, (cam.readout + 0.01) / 2))
    with pytest.raises(ValueError, match="readout"):
        RecordingCamera(K, (W, H), fps=30.0, line_time=1e-4)
    with pytest.raises(ValueError, match="K must be"):
        RecordingCamera(K[:2], (W, H))
    with pytest.raises(ValueError, match="fps"):
        RecordingCamera(K, (W, H), exposure=-1.0)
    with pytest.raises(TypeError, match="Lens"):
        RecordingCamera(K, (W, H), lens="opencv")
    with pytest.raises(ValueError, match="k1, k2, p1, p2, k3"):
        OpenCVLens([0.1, 0.2])
    back = RecordingCamera.from_json(cam.to_json())
    assert back.to_json() == cam.to_json()


# ----------------------------------------------------------------------------------------------
# hand-held trajectories
# ----------------------------------------------------------------------------------------------


def test_trajectory_is_seeded_smooth_and_hand_held():
    cam = webcam((W, H), seed=2)
    a = sample_handheld_trajectory([cam], BOARD, duration=20.0, seed=5)
    b = sample_handheld_trajectory([cam], BOARD, duration=20.0, seed=5)
    c = sample_handheld_trajectory([cam], BOARD, duration=20.0, seed=6)
    assert a.duration >= 20.0 and torch.equal(a.state, b.state) and torch.equal(a.times, b.times)
    assert not torch.equal(a.state[:2], c.state[:2])
    t = torch.arange(0.0, 20.0, 1 / 240, dtype=torch.float64)
    R, p = a.pose_at(t)
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(R))
    speed = (p[1:] - p[:-1]).norm(dim=-1) * 240
    # dwells (a few cm/s: tremor and drift) and sweeps up to about a metre per second, no jumps
    assert float(torch.quantile(speed, 0.1)) < 0.05 and 0.1 < float(speed.max()) < 2.0
    turn = (R[1:] @ R[:-1].transpose(-1, -2)).diagonal(dim1=-2, dim2=-1).sum(-1).sub(1).div(2).clamp(-1, 1).acos()
    assert float(turn.max()) * 240 < math.radians(400)
    # the board stays in front of the camera and mostly in view
    truth = exposure_truth(cam, BOARD, a, cam.frame_starts(cam.num_frames(20.0)))
    assert float(truth.tvec[:, 2].min()) > 0.1
    assert float((truth.visible.double().mean(-1) > 0.5).double().mean()) > 0.6
    # JSON round trip
    back = BoardTrajectory.from_json(a.to_json())
    torch.testing.assert_close(back.pose_at(t[::97])[1], a.pose_at(t[::97])[1], atol=0, rtol=0)


def test_uniform_trajectory():
    traj = BoardTrajectory.uniform(*_pose(), 2.0, angular=(0.0, 0.0, 1.0), linear=(0.5, 0.0, -0.1))
    R0, t0 = traj.pose_at(torch.tensor(0.0))
    R1, t1 = traj.pose_at(torch.tensor(0.4))
    torch.testing.assert_close(t1 - t0, torch.tensor([0.2, 0.0, -0.04], dtype=torch.float64))
    torch.testing.assert_close(R0.T @ R1, exp_so3(torch.tensor([0.0, 0.0, 0.4], dtype=torch.float64)))


# ----------------------------------------------------------------------------------------------
# ground truth
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(LENSES))
def test_truth_of_a_still_board_is_its_projection(name):
    cam = RecordingCamera(K, (W, H), LENSES[name], exposure=0.02, line_time=50e-6)
    R, t = _pose()
    traj = BoardTrajectory.uniform(R, t, 2.0)
    truth = exposure_truth(cam, BOARD, traj, cam.frame_starts(3))
    obj = BOARD.object_points()
    ref, ok = cam.project((obj @ R.T + t)[None])
    torch.testing.assert_close(truth.corners, ref.expand(3, -1, -1), atol=1e-9, rtol=0)
    assert bool(truth.visible.all()) and bool(ok.all())
    assert float(truth.motion.abs().max()) < 1e-9 and truth.subframes.tolist() == [1, 1, 1]
    torch.testing.assert_close(exp_so3(truth.rvec), R.expand(3, 3, 3))
    torch.testing.assert_close(truth.tvec, t.expand(3, 3))


def test_rolling_shutter_truth_solves_each_corners_row_time():
    cam = RecordingCamera(K, (W, H), LENSES["opencv"], exposure=0.01, line_time=60e-6)
    traj = _moving()
    starts = cam.frame_starts(4)
    truth = exposure_truth(cam, BOARD, traj, starts)
    # each corner lands on the row whose mid-exposure time it carries, where the board is at that time
    rows = truth.corners[..., 1]
    torch.testing.assert_close(truth.corner_time, starts[:, None] + rows * cam.line_time + cam.exposure / 2,
                               atol=1e-12, rtol=0)
    R, t = traj.pose_at(truth.corner_time)
    pc = (R @ BOARD.object_points()[None, :, :, None]).squeeze(-1) + t
    pix, _ = cam.project(pc)
    torch.testing.assert_close(truth.corners, pix, atol=1e-8, rtol=0)
    # a global shutter at the same frame time sees the moving board elsewhere (by about a pixel here)
    gs = exposure_truth(RecordingCamera(K, (W, H), LENSES["opencv"], exposure=0.01), BOARD, traj,
                        starts + 0.5 * cam.readout)
    torch.testing.assert_close(gs.frame_time, truth.frame_time)
    assert float((gs.corners - truth.corners).norm(dim=-1).max()) > 0.5
    # motion blur: the displacement over the exposure, about speed x exposure
    assert float(truth.motion.norm(dim=-1).max()) > 1.0 and bool((truth.subframes > 1).all())


# ----------------------------------------------------------------------------------------------
# images
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(LENSES))
def test_global_shutter_sharp_frame_is_the_chessboard_renderer(name):
    """Zero readout and no exposure: the frame is :func:`render_chessboard` at the board's pose (another way of
    computing each pixel's footprint), and the corners are the same."""
    lens = LENSES[name]
    cam = RecordingCamera(K, (W, H), lens, exposure=0.0)
    traj = _moving()
    truth = exposure_truth(cam, BOARD, traj, torch.tensor([0.3]))
    img = render_exposure(cam, BOARD, traj, 0.3, torch.full((H, W), 0.5), 1, supersample=3)
    kw = {"dist": lens.dist.float()} if isinstance(lens, OpenCVLens) else {}
    if isinstance(lens, FisheyeLens):
        kw = {"fisheye": lens.k.float(), "fov_deg": lens.fov_deg}
    ref, corners = render_chessboard(K.float(), truth.rvec.float(), truth.tvec.float(), (7, 5), 0.03, (W, H),
                                     supersample=3, background=0.5, **kw)
    assert float((ref[0, 0] - img).abs().max()) < 2e-3
    assert float((ref[0, 0] - img).abs().mean()) < 1e-5
    assert float((corners[0].double() - truth.corners[0]).abs().max()) < 1e-3


@pytest.mark.parametrize("name", ["pinhole", "opencv"])
@pytest.mark.parametrize("line_time", [0.0, 50e-6])
def test_corners_are_where_the_image_shows_them(name, line_time):
    """A sharp frame of a moving board (with and without a rolling shutter): OpenCV finds the board and its
    sub-pixel corners land on the truth (no bias, mean well under 0.05 px)."""
    cam = RecordingCamera(K, (W, H), LENSES[name], exposure=0.0, line_time=line_time)
    errors = []
    for i, (rv, tv) in enumerate((((0.25, -0.3, 0.15), (-0.09, -0.05, 0.55)), ((-0.35, 0.2, -0.4), (-0.1, -0.02, 0.6)))):
        traj = BoardTrajectory.uniform(*_pose(rv, tv), 2.0, angular=(0.2, 0.3, 0.5), linear=(0.3, 0.1, 0.0))
        truth = exposure_truth(cam, BOARD, traj, torch.tensor([0.2]))
        img = render_exposure(cam, BOARD, traj, 0.2, torch.full((H, W), 0.5), 1, supersample=2)
        errors.append(_subpix_error(img, truth.corners[0].float()))
    e = np.concatenate(errors)
    assert np.linalg.norm(e, axis=1).mean() < 0.03
    assert np.abs(e.mean(0)).max() < 0.01


def test_rolling_shutter_image_follows_the_rolling_truth():
    cam = RecordingCamera(K, (W, H), PinholeLens(), exposure=0.0, line_time=60e-6)
    traj = _moving(linear=(0.6, 0.0, 0.0))
    truth = exposure_truth(cam, BOARD, traj, torch.tensor([0.2]))
    img = render_exposure(cam, BOARD, traj, 0.2, torch.full((H, W), 0.5), 1)
    gs_cam = RecordingCamera(K, (W, H), PinholeLens(), exposure=0.0)
    gs = exposure_truth(gs_cam, BOARD, traj, truth.frame_time - gs_cam.readout / 2)
    e_rs = np.linalg.norm(_subpix_error(img, truth.corners[0].float()), axis=1)
    u8 = (img.numpy() * 255).round().astype(np.uint8)
    _, found = cv2.findChessboardCorners(u8, (7, 5))
    found = cv2.cornerSubPix(u8, found, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
    found = found.reshape(-1, 2).astype(np.float64)
    if np.linalg.norm(found[0] - truth.corners[0, 0].numpy()) > np.linalg.norm(found[-1] - truth.corners[0, 0].numpy()):
        found = found[::-1]
    e_gs = np.linalg.norm(found - gs.corners[0].numpy(), axis=1)
    assert e_rs.mean() < 0.05 and e_gs.mean() > 1.0


def test_zero_readout_and_still_boards():
    bg = torch.full((H, W), 0.5)
    still = BoardTrajectory.uniform(*_pose(), 2.0)
    sharp = render_exposure(RecordingCamera(K, (W, H), exposure=0.0), BOARD, still, 0.3, bg, 1)
    # a still board: no blur whatever the exposure and the sub-exposures, no rolling-shutter effect
    for cam in (RecordingCamera(K, (W, H), exposure=0.02), RecordingCamera(K, (W, H), exposure=0.02, line_time=60e-6)):
        blurred = render_exposure(cam, BOARD, still, 0.3, bg, 8)
        assert float((blurred - sharp).abs().max()) < 1e-5
    # a moving board with a zero readout: the rows share the global shutter's time
    moving = _moving()
    a = render_exposure(RecordingCamera(K, (W, H), exposure=0.0, line_time=0.0), BOARD, moving, 0.3, bg, 1)
    b = render_exposure(RecordingCamera(K, (W, H), exposure=0.0, line_time=60e-6), BOARD, moving, 0.3, bg, 1)
    assert float((a - b).abs().max()) > 0.2


def test_motion_blur_integrates_the_exposure():
    """A blurred global-shutter frame is the mean of sharp renders (render_chessboard) over the exposure."""
    cam = RecordingCamera(K, (W, H), PinholeLens(), exposure=0.02)
    traj = _moving(linear=(0.8, 0.0, 0.0))
    truth = exposure_truth(cam, BOARD, traj, torch.tensor([0.3]))
    n = int(truth.subframes[0])
    assert n > 4
    img = render_exposure(cam, BOARD, traj, 0.3, torch.full((H, W), 0.5), n, supersample=2)
    times = 0.3 + (torch.arange(n, dtype=torch.float64) + 0.5) / n * cam.exposure
    R, t = traj.pose_at(times)
    from ccs_kornia.geometry.so3 import log_so3

    ref, _ = render_chessboard(K.float(), log_so3(R).float(), t.float(), (7, 5), 0.03, (W, H), supersample=2,
                               background=0.5)
    assert float((ref.mean(0)[0] - img).abs().max()) < 2e-3
    sharp = render_exposure(cam, BOARD, traj, 0.3, torch.full((H, W), 0.5), 1)
    assert float((sharp - img).abs().max()) > 0.2
    # sub-exposures at most a pixel apart (blur_step) along the corners' motion over the exposure
    motion = truth.motion[0].norm(dim=-1)
    assert 0.5 * n < float(motion.max()) <= n


# ----------------------------------------------------------------------------------------------
# marker boards
# ----------------------------------------------------------------------------------------------


def test_charuco_and_aprilgrid_frames():
    from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard
    from ccs_kornia.modules.detection.markers.aprilgrid import detect_aprilgrid

    cam = RecordingCamera(K, (W, H), LENSES["opencv"], exposure=0.0, line_time=50e-6)
    grid = TexturePattern(AprilGrid(5, 4, 0.03, 0.3))
    assert grid.side == -1.0
    traj = BoardTrajectory.uniform(_pose((0.2, 0.1, 0.0), (-0.1, 0.08, 0.5))[0] @ grid.upright,
                                   torch.tensor([-0.1, 0.08, 0.5], dtype=torch.float64), 2.0, angular=(0.1, 0.2, 0.3),
                                   linear=(0.2, 0.1, 0.0))
    truth = exposure_truth(cam, grid, traj, torch.tensor([0.2]))
    img = render_exposure(cam, grid, traj, 0.2, torch.full((H, W), 0.5), 1, supersample=3)
    out = detect_aprilgrid(img[None, None], grid.board)
    seen = out.valid[0]
    assert int(seen.sum()) > 60 and bool(truth.visible[0][seen].all())
    err = (out.corners[0].double() - truth.corners[0])[seen].norm(dim=-1)
    assert float(err.mean()) < 0.03
    # seen from behind (half a turn less): the print is not visible, no corner is
    back = BoardTrajectory.uniform(_pose((0.2, 0.1, 0.0))[0], torch.tensor([-0.1, 0.08, 0.5], dtype=torch.float64), 2.0)
    assert not bool(exposure_truth(cam, grid, back, torch.tensor([0.2])).visible.any())

    board = CharucoBoard(6, 5, 0.04, 0.03, "DICT_4X4_50")
    charuco = TexturePattern(board)
    traj = BoardTrajectory.uniform(*_pose((0.25, -0.3, 0.15), (-0.1, -0.08, 0.6)), 2.0, linear=(0.2, 0.0, 0.0))
    truth = exposure_truth(cam, charuco, traj, torch.tensor([0.2]))
    img = render_exposure(cam, charuco, traj, 0.2, torch.full((H, W), 0.5), 1, supersample=3)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.cv2_board()).detectBoard((img.numpy() * 255).astype(np.uint8))
    assert ids is not None and len(ids) == board.num_corners
    err = np.linalg.norm(corners.reshape(-1, 2) - truth.corners[0].numpy()[ids.ravel()], axis=1)
    assert err.mean() < 0.1


def test_texture_sampling_agrees_with_the_analytic_chessboard():
    """A chessboard printed as a texture renders like the analytic one (up to the filters' shapes at edges)."""

    class PrintedChessboard:
        board_size = (7, 5)

        def object_points(self):
            return BOARD.object_points()

        def texture(self):
            ppsq = 64  # pixels per square; a one-square margin around the 8 x 6 squares
            ii, jj = np.meshgrid(np.arange(10 * ppsq), np.arange(8 * ppsq))
            u, v = ii // ppsq - 2, jj // ppsq - 2  # square index (the corner (0, 0) at the print's (2, 2) squares)
            checker = ((u + v) % 2 == 1) | (u < -1) | (u > 6) | (v < -1) | (v > 4)
            art = np.where(checker, 255, 0).astype(np.uint8)
            s = ppsq / 0.03
            return art, np.array([[s, 0.0, 2 * ppsq - 0.5], [0.0, s, 2 * ppsq - 0.5]])

    cam = RecordingCamera(K, (W, H), exposure=0.0)
    printed = TexturePattern(PrintedChessboard(), dark=0.1, light=0.9)
    traj = BoardTrajectory.uniform(*_pose(), 2.0)
    a = render_exposure(cam, ChessPattern(7, 5, 0.03, border=1.0), traj, 0.0, torch.full((H, W), 0.5), 1, supersample=3)
    b = render_exposure(cam, printed, traj, 0.0, torch.full((H, W), 0.5), 1, supersample=3)
    assert float((a - b).abs().mean()) < 0.01
    corners = exposure_truth(cam, printed, traj, torch.tensor([0.0])).corners[0].float()
    assert np.linalg.norm(_subpix_error(b, corners), axis=1).mean() < 0.03


# ----------------------------------------------------------------------------------------------
# recordings, rigs, files
# ----------------------------------------------------------------------------------------------


def test_recording_is_lazy_and_deterministic_by_seed():
    cam = webcam((320, 240), seed=1)
    board = ChessPattern(6, 4, 0.03)
    a = handheld_recording(cam, board, duration=2.0, seed=4)
    b = handheld_recording(cam, board, duration=2.0, seed=4)
    c = handheld_recording(cam, board, duration=2.0, seed=5)
    frames = a.frames(5, 8)
    assert inspect.isgenerator(frames)
    got = list(frames)
    assert [i for i, _ in got] == [5, 6, 7] and got[0][1].shape == (240, 320) and got[0][1].dtype == torch.uint8
    assert torch.equal(got[1][1], b.image(6)) and not torch.equal(got[1][1], c.image(6))
    torch.testing.assert_close(a.truth.corners, b.truth.corners, atol=0, rtol=0, equal_nan=True)
    assert len(a) == cam.num_frames(2.0)
    # each row's pose: the frame's pose is the middle row's (between rows 119 and 120)
    R, t = a.row_poses(6)
    assert R.shape == (240, 3, 3) and t.shape == (240, 3) and cam.line_time > 0
    torch.testing.assert_close(0.5 * (t[119] + t[120]), a.truth.tvec[6], atol=1e-7, rtol=0)
    with pytest.raises(ValueError, match="duration"):
        Recording(cam, board, a.trajectory, duration=a.trajectory.duration + 1.0)
    with pytest.raises(IndexError):
        a.image(len(a))
    with pytest.raises(ValueError, match="background"):
        _ = Recording(cam, board, a.trajectory, background="stars").background


def test_rig_extrinsics_and_truth_agree():
    """With one clock for every camera the boards' poses in cameras c and 0 differ by the rig's extrinsics."""
    cams = webcam_rig(3, (320, 240), seed=2, rolling_shutter=False, start_ms=(5.0, 5.0), exposure_ms=(10.0, 10.0))
    rig = handheld_rig_recording(cams, ChessPattern(6, 4, 0.04), duration=2.0, seed=1)
    R, T = rig.extrinsics
    torch.testing.assert_close(R[0], torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(3, 3, 3))
    t0 = rig[0].truth
    for c in (1, 2):
        tc = rig[c].truth
        torch.testing.assert_close(tc.frame_time, t0.frame_time)
        torch.testing.assert_close(exp_so3(tc.rvec), R[c] @ exp_so3(t0.rvec))
        torch.testing.assert_close(tc.tvec, (R[c] @ t0.tvec[..., None])[..., 0] + T[c])
    # partly overlapping views: some frames seen by two cameras
    both = rig[0].truth.visible.sum(-1).gt(5) & rig[1].truth.visible.sum(-1).gt(5)
    assert bool(both.any())


def test_rig_clocks_and_timestamps_table():
    cams = webcam_rig(3, (320, 240), seed=3, fps=[30.0, 30.0, 15.0], jitter_ms=(2.0, 8.0))
    rig = handheld_rig_recording(cams, ChessPattern(6, 4, 0.04), duration=4.0, seed=2)
    assert [len(r) for r in rig.recordings][2] < len(rig[0])
    for rec in rig.recordings:
        lag = rec.timestamp - rec.truth.frame_time - rec.camera.latency
        assert float(lag.abs().max()) < 6 * rec.camera.jitter + 1e-12 and float(lag.std()) > 0.1 * rec.camera.jitter
    rows = rig.sync_table()
    assert rows == sorted(rows, key=lambda r: (r[0], r[1]))
    assert len({(c, f) for _, c, f, _ in rows}) == len(rows)
    ref = {s: t for s, c, f, t in rows if c == 2}  # the slowest camera sets the instants
    assert all(s == f for s, c, f, _ in rows if c == 2)
    for s, c, f, t in rows:
        assert t == float(rig[c].timestamp[f])
        if s in ref:
            assert abs(t - ref[s]) <= 0.5 / 15.0 + 1e-12
    tight = rig.sync_table(tolerance=0.002)
    assert len(tight) < len(rows)


def test_video_round_trip_and_truth_file(tmp_path):
    rec = handheld_recording(webcam((160, 120), seed=0), ChessPattern(5, 4, 0.02), duration=1.0, seed=3)
    paths = write_recording(rec, tmp_path / "rec.mkv")  # FFV1: lossless
    cap = cv2.VideoCapture(str(paths["video"]))
    decoded = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        decoded.append(frame[..., 0])
    assert len(decoded) == len(rec)
    assert all(np.array_equal(d, rec.image(i).numpy()) for i, d in enumerate(decoded[:3]))
    truth = read_truth(paths["truth"])
    torch.testing.assert_close(truth["frames"]["corners"], rec.truth.corners, atol=1e-6, rtol=0, equal_nan=True)
    assert torch.equal(truth["frames"]["visible"], rec.truth.visible)
    assert truth["camera"]["lens"] == rec.camera.lens.to_json()
    # mp4v: the same frames, lossy
    n = write_video((img for _, img in rec.frames()), tmp_path / "rec.mp4", rec.camera.fps, rec.camera.image_size)
    assert n == count_video_frames(tmp_path / "rec.mp4") == len(rec)
    with pytest.raises(ValueError, match="no video codec"):
        write_video(iter(()), tmp_path / "rec.gif", 30.0, (160, 120))
    assert not list(tmp_path.glob(".*partial*"))


def test_rig_files(tmp_path):
    cams = webcam_rig(2, (160, 120), seed=1)
    rig = RigRecording(cams, ChessPattern(5, 4, 0.04),
                       sample_handheld_trajectory(cams, ChessPattern(5, 4, 0.04), 1.0, seed=0), 1.0, seed=0)
    paths = write_rig_recording(rig, tmp_path / "rig_recording", suffix=".avi")
    assert [count_video_frames(p) for p in paths["videos"]] == [len(r) for r in rig.recordings]
    with open(paths["timestamps"], newline="") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0]) == ["sync_index", "cam_id", "frame_index", "frame_time"]
    assert [(int(r["sync_index"]), int(r["cam_id"]), int(r["frame_index"])) for r in table] == \
        [(s, c, f) for s, c, f, _ in rig.sync_table()]
    truth = read_truth(paths["truth"])
    torch.testing.assert_close(truth["R"], rig.extrinsics[0].float())
    assert [e["video"] for e in truth["cameras"]] == ["cam_0.avi", "cam_1.avi"]
