"""The camera a guided capture assumes before its first solve: the focal length and the barrel from the frames kept so
far."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, OPENCV5
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.radial_guess import radial_from_views
from ccs_kornia.modules.detection.screening import Sighting
from ccs_kornia.pipeline.guided_capture import GuidedCapture, guess_camera

OBJ = board_object_points(9, 6, 0.025, dtype=torch.float64)
SIZE = (640, 480)
WIDE = Camera(OPENCV5, torch.tensor([330.0, 331, 318, 243, -0.25, 0.06, 0, 0, 0], dtype=torch.float64), SIZE)


def _view(tilt_deg: tuple[float, float], shift: tuple[float, float] = (0.0, 0.0)) -> torch.Tensor:
    R = exp_so3(torch.deg2rad(torch.tensor([tilt_deg[0], tilt_deg[1], 0.0], dtype=torch.float64)))
    centre = OBJ.mean(0)
    pts = (OBJ - centre) @ R.T + torch.tensor([shift[0], shift[1], 0.35], dtype=torch.float64)
    return WIDE.project(pts[None])[0]


def test_guess_takes_the_focal_length_of_the_views_kept():
    assert float(guess_camera(OPENCV5, SIZE).params[0, 0]) == 640.0
    views = torch.stack([_view((35.0, 0.0)), _view((0.0, -30.0), (0.05, 0.0))])
    views[1, :5] = float("nan")  # corners not seen
    cam = guess_camera(OPENCV5, SIZE, views, OBJ)
    assert float(cam.params[0, 0]) == pytest.approx(330.0, rel=0.1)  # the strong barrel shortens it a little
    assert float(cam.params[0, 0]) == float(cam.params[0, 1]) and bool((cam.params[0, 6:] == 0).all())
    # a board held flat says nothing about the focal length: the default stays; so does a fisheye's
    assert float(guess_camera(OPENCV5, SIZE, _view((0.0, 0.0))[None], OBJ).params[0, 0]) == 640.0
    assert float(guess_camera(FISHEYE, SIZE, views, OBJ).params[0, 0]) == pytest.approx(640.0 / 3)


def test_guess_bends_like_the_lens_seen():
    views = torch.stack([_view((35.0, 0.0)), _view((0.0, -30.0), (0.05, 0.0))])
    assert radial_from_views(views, OBJ, SIZE) < -0.2  # the strong barrel straightens the boards' rows
    cam = guess_camera(OPENCV5, SIZE, views, OBJ)
    assert float(cam.params[0, 4]) < -0.1
    corners = torch.tensor([[[0.0, 0.0], [639.0, 479.0], [639.0, 0.0]]], dtype=torch.float64)
    rays = WIDE.unproject(corners)  # the true lens's rays at the image's corners
    off = (cam.project(rays) - corners).norm(dim=-1)
    flat = Camera(OPENCV5, torch.cat([cam.params[0, :4], torch.zeros(5, dtype=torch.float64)])[None], SIZE)
    assert float(off.amax()) < 60.0 and float((flat.project(rays) - corners).norm(dim=-1).amin()) > 100.0
    # a pinhole's boards stay unbent
    pinhole = Camera(OPENCV5, torch.tensor([330.0, 331, 318, 243, 0, 0, 0, 0, 0], dtype=torch.float64), SIZE)
    R = exp_so3(torch.deg2rad(torch.tensor([30.0, 0.0, 0.0], dtype=torch.float64)))
    straight = pinhole.project(((OBJ - OBJ.mean(0)) @ R.T + torch.tensor([0.0, 0.0, 0.35], dtype=torch.float64))[None])
    assert abs(radial_from_views(straight, OBJ, SIZE)) < 0.01


def test_guided_capture_guesses_again_with_each_frame_before_its_first_solve():
    views = [_view((35.0, 0.0)), _view((0.0, -30.0), (0.05, 0.0))]
    ends = [0, 8, 53, 45]
    gc = GuidedCapture((9, 6), OBJ, SIZE, detect=lambda k: views[k].numpy(), live_model=OPENCV5,
                       screen=lambda k: Sighting(True, views[k][ends].numpy(), 54))
    far = gc.suggestion().poses
    assert gc.keep_now(0, 0, 0.0).kept
    assert float(gc.camera.params[0, 0]) == pytest.approx(330.0, rel=0.1)
    near = gc.suggestion().poses  # laid out for the shorter focal length: the board nearer for the same fill
    assert float((near.tvec[:, 2] * near.fill).median()) < 0.7 * float((far.tvec[:, 2] * far.fill).median())
    assert bool(torch.linalg.eigvalsh(gc.information)[-1] > 0)
    gc.undo()
    assert float(gc.camera.params[0, 0]) == 640.0 and not bool(gc.information.any()) and gc.worst_px == float("inf")


def test_boards_partly_beyond_the_image_are_asked_for_where_the_screen_sees_them():
    from ccs_kornia.modules.detection.boards import CharucoBoard
    from ccs_kornia.modules.detection.screening import BoardScreen

    board = CharucoBoard(10, 7, 0.025, 0.018, "DICT_6X6_250")  # 9x6 inner corners
    obj = board.object_points().double()
    marker = GuidedCapture((9, 6), obj, SIZE, detect=lambda k: None, live_model=OPENCV5,
                           screen=BoardScreen((9, 6), board))
    chess = GuidedCapture((9, 6), OBJ, SIZE, detect=lambda k: None, live_model=OPENCV5)
    assert bool(chess.suggestion().poses.seen.all()) and bool(chess._candidates.seen.all())
    partial = ~marker._candidates.seen.all(-1)
    assert bool(partial.any()) and float(marker._candidates.seen.double().mean(-1).min()) >= 0.75
    # a partial view's information counts the corners inside the image only
    r, t = marker._candidates.rvec[partial][:1, None], marker._candidates.tvec[partial][:1, None]
    pts = obj @ exp_so3(r[0, 0]).T + t[0, 0]
    uv = marker.camera.project(pts[None])[0]
    inside = ((uv >= 0) & (uv <= torch.tensor([SIZE[0] - 1.0, SIZE[1] - 1.0], dtype=torch.float64))).all(-1)[None]
    assert not bool(inside.all())
    torch.testing.assert_close(marker._view_information(r, t), marker._view_information(r, t, inside))
    assert not torch.allclose(marker._view_information(r, t), marker._view_information(r, t, torch.ones_like(inside)))
