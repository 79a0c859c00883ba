"""The next best pose: the candidates fit the image, the ranking is the uncertainty each would leave (checked against
the covariance a solve on that view gives), the best lowers the figure, and the instruction says where it is."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.quality.next_pose import (
    MIN_SEEN,
    NextBestPose,
    candidate_poses,
    next_poses,
    pose_instruction,
    uncertainty_map,
    worst_uncertainty,
)
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    image_rays,
    projection_uncertainty,
)
from ccs_kornia.modules.calibration.quality.view_information import view_information

OBJ = board_object_points(9, 6, 0.03, dtype=torch.float64)
SIZE = (640, 480)


def _camera(model=OPENCV5):
    params = {OPENCV5: [600.0, 600, 320, 240, -0.2, 0.05, 0.001, -0.001, 0.0], K1K2: [600.0, 600, 320, 240, -0.2, 0.05],
              FISHEYE: [300.0, 300, 320, 240, 0.02, -0.01, 0.0, 0.0]}[model]
    return Camera(model, torch.tensor(params, dtype=torch.float64), SIZE)


def _information(cam, rvec, tvec, seen=None):
    w = torch.ones(1, rvec.shape[0], OBJ.shape[0], dtype=torch.float64) if seen is None else seen[None].double()
    return view_information(cam, rvec[None], tvec[None], OBJ, w)[0]


@pytest.mark.parametrize("model", [OPENCV5, FISHEYE])
def test_candidates_fit_the_image_and_face_the_camera(model):
    cam = _camera(model)
    poses = candidate_poses(cam, OBJ, (9, 6))
    assert len(poses) > 50
    pts = torch.einsum("kij,nj->kni", exp_so3(poses.rvec), OBJ) + poses.tvec[:, None]
    uv = cam.project(pts.reshape(1, -1, 3))[0].reshape(len(poses), -1, 2)
    inside = ((uv[..., 0] >= 0) & (uv[..., 0] <= SIZE[0] - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= SIZE[1] - 1))
    assert bool((inside | ~poses.seen).all())  # the corners seen are inside the image
    assert float(poses.seen.double().mean(-1).min()) >= MIN_SEEN  # each pose shows enough of the board
    assert bool((pts[..., 2] > 0).all())
    # whole boards and boards partly beyond the image's edge; with min_seen=1 the whole boards only
    whole = poses.seen.all(-1)
    assert bool(whole.any()) and bool((~whole).any())
    only_whole = candidate_poses(cam, OBJ, (9, 6), min_seen=1.0)
    assert len(only_whole) == int(whole.sum()) and bool(only_whole.seen.all())
    assert float(poses.tilt_deg.norm(dim=-1).max()) <= 50.0 + 1e-9
    # the outline is the board's four extreme corners where they project
    torch.testing.assert_close(poses.outline, uv[:, [0, 8, 53, 45]])
    # tilts about both axes, and the position grid spans the image
    assert bool((poses.tilt_deg[:, 0] != 0).any() and (poses.tilt_deg[:, 1] != 0).any())
    assert float(poses.position[:, 0].min()) < 0.3 and float(poses.position[:, 0].max()) > 0.7


def test_the_figure_is_the_solvers_projection_uncertainty():
    """The worst-direction 1-sigma map from the information is projection_uncertainty's from the covariance."""
    cam = _camera(K1K2)
    g = torch.Generator().manual_seed(0)
    rvec = (torch.rand(8, 3, generator=g, dtype=torch.float64) - 0.5) * 0.8
    tvec = torch.cat([torch.full((8, 2), -0.1, dtype=torch.float64), torch.full((8, 1), 0.6, dtype=torch.float64)], 1)
    H = _information(cam, rvec, tvec).sum(0)
    sigma = 0.3
    u = uncertainty_map(cam, H, sigma, grid=(8, 6), prior=0.0)
    pixels = image_points(SIZE, (8, 6))
    cov = sigma**2 * torch.linalg.inv(H)  # the model's parameters are OpenCV's storage for k1k2 but for the padding
    storage = torch.zeros(1, 9, 9, dtype=torch.float64)
    storage[0, :6, :6] = cov
    ref = projection_uncertainty(cam, storage, pixels, worst=True,
                                 compensate_rotation=torch.ones(pixels.shape[0], dtype=torch.bool))
    torch.testing.assert_close(u.flatten(), ref[0], rtol=1e-6, atol=1e-9)
    assert float(worst_uncertainty(cam, H, sigma, (8, 6), prior=0.0)) == pytest.approx(float(ref.max()), rel=1e-6)


def test_ranked_by_the_uncertainty_each_leaves():
    cam = _camera()
    rvec = torch.zeros(1, 3, dtype=torch.float64)
    tvec = torch.tensor([[-0.12, -0.075, 0.6]], dtype=torch.float64)
    H = _information(cam, rvec, tvec).sum(0)
    s = next_poses(cam, H, OBJ, sigma=0.2, board_size=(9, 6))
    assert len(s.poses) > 50
    assert bool((s.score_px[1:] >= s.score_px[:-1]).all())  # best first, by the 4th-power mean over the image
    assert float(s.worst_px[0]) < s.current_px and bool((s.score_px <= s.worst_px).all())
    # each rank is what adding that view's information gives
    M = _information(cam, s.poses.rvec[:3], s.poses.tvec[:3], s.poses.seen[:3])
    every = candidate_poses(cam, OBJ, (9, 6))
    typical = _information(cam, every.rvec, every.tvec, every.seen).mean(0)
    direct = worst_uncertainty(cam, H + M, 0.2, typical=typical)
    torch.testing.assert_close(direct, s.worst_px[:3])
    after = uncertainty_map(cam, H + M, 0.2, typical=typical).flatten(-2)
    torch.testing.assert_close(after.pow(4).mean(-1).pow(0.25), s.score_px[:3])
    # a second flat view at the centre is a poor suggestion: the best is tilted, and far better than it
    flat = (s.poses.tilt_deg.norm(dim=-1) == 0) & ((s.poses.position - 0.5).norm(dim=-1) < 0.01)
    assert float(s.poses.tilt_deg[0].norm()) > 0
    assert float(s.score_px[flat].min()) > 1.5 * float(s.score_px[0])
    assert s.instruction == pose_instruction(s.poses.position[0], float(s.poses.fill[0]), s.poses.tilt_deg[0])


def test_following_the_suggestions_beats_repeating_a_view():
    """Five suggested views leave a lower worst uncertainty than five views at a fixed tilt."""
    cam = _camera()
    nbp = NextBestPose(cam, OBJ, (9, 6))
    H = torch.zeros(9, 9, dtype=torch.float64)
    for _ in range(5):
        s = nbp(H, sigma=0.2, top=1)
        H = H + _information(cam, s.poses.rvec, s.poses.tvec, s.poses.seen)[0]
    fixed = nbp.candidates.take(torch.tensor([0]))
    Hf = 5 * _information(cam, fixed.rvec, fixed.tvec, fixed.seen)[0]
    typical = _information(cam, nbp.candidates.rvec, nbp.candidates.tvec, nbp.candidates.seen).mean(0)
    assert float(worst_uncertainty(cam, H, 0.2, typical=typical)) < 0.5 * float(
        worst_uncertainty(cam, Hf, 0.2, typical=typical))


def test_a_cameras_candidates_are_remembered_not_changed():
    """Asked again for the same camera, the ranking reuses its candidates and their information: the same answer as
    with the candidates given; another camera gets its own."""
    cam = _camera()
    H = _information(cam, torch.zeros(1, 3, dtype=torch.float64),
                     torch.tensor([[-0.12, -0.075, 0.6]], dtype=torch.float64)).sum(0)
    first = next_poses(cam, H, OBJ, sigma=0.2, board_size=(9, 6), top=5)
    again = next_poses(cam, H, OBJ, sigma=0.2, board_size=(9, 6), top=5)
    given = next_poses(cam, H, OBJ, sigma=0.2, board_size=(9, 6), candidates=candidate_poses(cam, OBJ, (9, 6)), top=5)
    for s in (again, given):
        torch.testing.assert_close(s.score_px, first.score_px, rtol=0, atol=0)
        torch.testing.assert_close(s.poses.rvec, first.poses.rvec, rtol=0, atol=0)
    other = Camera(OPENCV5, cam.params * torch.tensor([1.3, 1.3, 1, 1, 1, 1, 1, 1, 1], dtype=torch.float64), SIZE)
    mine = next_poses(other, H, OBJ, sigma=0.2, board_size=(9, 6), top=5)
    own = next_poses(other, H, OBJ, sigma=0.2, board_size=(9, 6), candidates=candidate_poses(other, OBJ, (9, 6)), top=5)
    torch.testing.assert_close(mine.score_px, own.score_px, rtol=0, atol=0)
    assert not torch.equal(mine.score_px, first.score_px)


def test_a_fisheyes_pixels_behind_the_camera_do_not_rank():
    """A fisheye of 212 degrees on the diagonal: the image corners' rays point behind the camera, where no board is
    seen; the ranking's mean is over the other pixels (the worst still over the whole image)."""
    cam = Camera(FISHEYE, torch.tensor([215.0, 215, 320, 240, 0.03, -0.01, 0.0, 0.0], dtype=torch.float64), SIZE)
    rays = image_rays(cam, image_points(SIZE, (16, 12)))[0]
    behind = rays[:, 2] <= 0
    assert 0 < int(behind.sum()) < 40 and bool(behind.reshape(12, 16)[0, 0])  # the image's corners
    H = _information(cam, torch.zeros(1, 3, dtype=torch.float64),
                     torch.tensor([[-0.12, -0.075, 0.3]], dtype=torch.float64)).sum(0)
    s = next_poses(cam, H, OBJ, sigma=0.2, board_size=(9, 6), top=3)
    every = candidate_poses(cam, OBJ, (9, 6))
    typical = _information(cam, every.rvec, every.tvec, every.seen).mean(0)
    M = _information(cam, s.poses.rvec, s.poses.tvec, s.poses.seen)
    after = uncertainty_map(cam, H + M, 0.2, typical=typical).flatten(-2)
    torch.testing.assert_close(after[:, ~behind].pow(4).mean(-1).pow(0.25), s.score_px)
    torch.testing.assert_close(after.amax(-1), s.worst_px)


def test_instruction_words():
    assert pose_instruction(torch.tensor([0.2, 0.2]), 0.7, torch.tensor([-30.0, 0.0]), 0.4) == (
        "top left, closer, top edge tilted about 30 degrees away")
    assert pose_instruction(torch.tensor([0.8, 0.5]), 0.35, torch.tensor([20.0, 40.0]), 0.5) == (
        "right, farther, bottom edge tilted about 20 degrees away and left edge tilted about 40 degrees away")
    assert pose_instruction(torch.tensor([0.5, 0.9]), 0.5, torch.tensor([0.0, -4.0]), 0.5) == (
        "bottom, at this distance, held flat")


def test_shapes_checked():
    cam = _camera()
    with pytest.raises(ValueError, match="information"):
        next_poses(cam, torch.zeros(4, 4, dtype=torch.float64), OBJ)
    with pytest.raises(ValueError, match="one camera"):
        candidate_poses(Camera.cat([cam, cam]), OBJ)
