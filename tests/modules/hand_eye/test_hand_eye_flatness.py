"""The board's sag in the hand-eye fit: recovered with its 1-sigma on a rendered bent board and kept by the
leave-one-pose-out RMS; on a flat board not kept, and ``X``, ``Z`` and the figures exactly the flat fit's."""

from __future__ import annotations

import torch
from _hand_eye_scenes import camera, scene

from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.hand_eye.solver import calibrate_hand_eye

VIEWS = 6


def _scene():
    return scene("eye_in_hand", views=10, seed=1, noise_px=0.2, joint_noise_deg=0.01)  # the scene other tests use


def _bent_corners(s, warp: torch.Tensor) -> torch.Tensor:
    """The scene's views of its board bent by ``warp``, 0.1 px noise."""
    cam = torch.linalg.inv(s.true_poses @ s.X) @ s.Z
    board = warped_board(s.object_points, warp)
    uv = camera(s).project(board.expand(1, *s.corners.shape[:2], 3), log_so3(cam[:, :3, :3])[None], cam[None, :, :3, 3])
    g = torch.Generator().manual_seed(0)
    return uv[0] + 0.1 * torch.randn(uv.shape[1:], generator=g, dtype=uv.dtype)


def _solve(s, corners, board_flatness):
    return calibrate_hand_eye(corners[None, :VIEWS], s.valid[None, :VIEWS], s.object_points, s.robot_poses[None, :VIEWS],
                              camera(s), "eye_in_hand", robot_noise=None, board_flatness=board_flatness)


def test_bent_board_is_recovered_and_kept():
    s = _scene()
    truth = torch.tensor([-0.002, 0.001], dtype=torch.float64)
    res = _solve(s, _bent_corners(s, truth), True)
    record = res.board_flatness[0]
    assert bool(res.success[0]) and record["kept"]
    assert ((res.board_warp[0] - truth).abs() < 4 * res.board_warp_std[0]).all()
    assert (res.board_warp_std[0] < 2e-4).all()
    assert record["warp_m"] == res.board_warp[0].tolist()
    held = record["heldout_rms_px"]
    assert held["warp"] < 0.95 * held["flat"] and abs(held["warp"] - float(res.heldout_rms[0])) < 1e-12


def test_flat_board_is_not_kept_and_changes_nothing():
    s = _scene()
    flat = _solve(s, s.corners, False)
    res = _solve(s, s.corners, True)
    assert flat.board_flatness is None and flat.board_warp is None
    assert not res.board_flatness[0]["kept"] and (res.board_warp == 0).all()
    for name in ("X", "Z", "rms", "heldout_rms_px", "x_covariance", "covariance"):
        assert torch.equal(getattr(res, name), getattr(flat, name)), name
