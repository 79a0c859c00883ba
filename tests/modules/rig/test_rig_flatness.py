"""The board's sag in the rig fit: recovered with its 1-sigma on a rendered bent board, kept by the held-out epipolar
RMS where the board is bent and not where it is flat."""

from __future__ import annotations

import torch

from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.modules.rig.rig_flatness import choose_rig_board_warp
from ccs_kornia.modules.rig.rig_solver import RigSolver


def _scene(warp):
    K = torch.tensor([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.from_opencv(K1K2, K, torch.tensor([-0.1, 0.01], dtype=torch.float64), (640, 480))
    R = torch.eye(3, dtype=torch.float64).expand(2, 3, 3)
    T = torch.tensor([[0.0, 0, 0], [-0.1, 0, 0]], dtype=torch.float64)
    return render_rig(Camera.cat([cam, cam]), R, T, num_frames=12, board_warp=warp, noise_px=0.05, seed=2)


def test_bent_board_is_recovered_and_kept():
    s = _scene((-0.002, 0.001))
    flat = RigSolver(K1K2)(s.corners, s.valid, s.object_points, s.image_sizes)
    bent = RigSolver(K1K2, board_warp=True)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert flat.board_warp is None and bent.success
    err = (bent.board_warp - torch.tensor([-0.002, 0.001], dtype=torch.float64)).abs()
    assert (err < 4 * bent.board_warp_std).all() and (bent.board_warp_std < 5e-5).all()
    assert abs(float(bent.T[1, 0]) + 0.1) < abs(float(flat.T[1, 0]) + 0.1)
    rig, record = choose_rig_board_warp(flat, bent, s.object_points)
    assert record["kept"] and rig is bent
    assert record["heldout_epipolar_px"]["warp"] < record["heldout_epipolar_px"]["flat"]


def test_flat_board_stays_flat():
    s = _scene(None)
    flat = RigSolver(K1K2)(s.corners, s.valid, s.object_points, s.image_sizes)
    bent = RigSolver(K1K2, board_warp=True)(s.corners, s.valid, s.object_points, s.image_sizes)
    rig, record = choose_rig_board_warp(flat, bent, s.object_points)
    assert not record["kept"] and rig is flat
