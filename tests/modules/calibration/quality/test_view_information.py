"""Each view's information about the camera, the image's projection weights and the greedy choice of views:
the sum of the views' information is the solver's (its covariance), the image weights give
``projection_uncertainty``'s mean over the image, and the choice takes new poses before repeats."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import Camera, project_points
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    projection_uncertainty,
)
from ccs_kornia.modules.calibration.quality.view_information import (
    greedy_information,
    image_information,
    view_information,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver

OBJ = board_object_points(9, 6, 0.03, dtype=torch.float64)
K = torch.tensor([[800.0, 0, 640], [0, 800, 360], [0, 0, 1]], dtype=torch.float64)
DIST = torch.tensor([-0.2, 0.05, 0.001, -0.001, 0.0], dtype=torch.float64)
SIZE = (1280, 720)


def _views(num: int = 12, seed: int = 0, noise: float = 0.1):
    g = torch.Generator().manual_seed(seed)
    rvec = (torch.rand(num, 3, generator=g, dtype=torch.float64) - 0.5) * 0.8
    tvec = torch.cat([(torch.rand(num, 2, generator=g, dtype=torch.float64) - 0.5) * 0.3 - 0.12,
                      0.6 + 0.3 * torch.rand(num, 1, generator=g, dtype=torch.float64)], 1)
    uv = project_points(OBJ.expand(num, -1, -1), K.expand(num, 3, 3), DIST.expand(num, 5), rvec, tvec)
    return uv + noise * torch.randn(uv.shape, generator=g, dtype=torch.float64), rvec, tvec


@pytest.fixture(scope="module")
def solved():
    uv, _, _ = _views()
    res = CalibrationSolver(model=OPENCV5, use_ransac=False)(uv[None], torch.ones(1, 12, 54, dtype=torch.bool),
                                                               OBJ, SIZE)
    return res


def test_sum_of_the_views_is_the_solvers_covariance(solved):
    M = view_information(solved.camera, solved.rvec, solved.tvec, OBJ, torch.ones(1, 12, 54, dtype=torch.float64))
    assert M.shape == (1, 12, 9, 9)
    n = 12 * 54
    sigma2 = solved.rms**2 / 2 * (2 * n) / (2 * n - 9 - 6 * 12)  # per coordinate, over the degrees of freedom
    cov = torch.linalg.inv(M.sum(1)) * sigma2[:, None, None]
    torch.testing.assert_close(cov.diagonal(dim1=-2, dim2=-1), solved.cov_camera.diagonal(dim1=-2, dim2=-1),
                               rtol=1e-6, atol=0)


def test_image_weights_give_the_mean_projection_uncertainty(solved):
    A = image_information(solved.camera)
    grid = image_points(SIZE, (16, 12))
    u = projection_uncertainty(solved.camera, solved.cov_camera, grid, worst=False,
                               compensate_rotation=torch.ones(grid.shape[0], dtype=torch.bool))
    mean = (A * solved.cov_camera.transpose(-1, -2)).sum((-1, -2)) / 2
    torch.testing.assert_close(mean, u.pow(2).mean(-1), rtol=1e-9, atol=0)


def test_shapes_of_a_batch_and_of_a_fisheye(device):
    _uv, rvec, tvec = _views(4)
    Kb = K.expand(3, 3, 3).to(device)
    w = torch.ones(3, 4, 54, dtype=torch.float64, device=device)
    w[1, 2] = 0  # a view without corners: no information
    cams = Camera.from_opencv(K1K2, Kb, DIST[:2].expand(3, 2).to(device), SIZE)
    M = view_information(cams, rvec.expand(3, 4, 3).to(device), tvec.expand(3, 4, 3).to(device), OBJ.to(device), w)
    assert M.shape == (3, 4, 6, 6) and M.device.type == device.type
    assert bool((M[1, 2] == 0).all()) and bool(M[0, 0].diagonal().gt(0).all())
    torch.testing.assert_close(M[0], M[2])
    fish = Camera.from_opencv(FISHEYE, K.to(device), None, SIZE)
    Mf = view_information(fish, rvec[None].to(device), tvec[None].to(device), OBJ.to(device), w[:1])
    A = image_information(fish)
    assert Mf.shape == (1, 4, 8, 8) and A.shape == (1, 8, 8)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match=r"rvec must be \(C, V, 3\) with C=1, got \(2, 2, 3\)"):
        view_information(Camera.from_opencv(K1K2, K, DIST[:2]), torch.zeros(2, 2, 3), torch.zeros(2, 2, 3), OBJ,
                         torch.ones(2, 2, 54))
    with pytest.raises(ValueError, match=r"image must be \(C, P, P\) with C=1, P=6, got \(1, 5, 5\)"):
        greedy_information(torch.zeros(1, 3, 6, 6), torch.zeros(1, 5, 5))
    with pytest.raises(ValueError, match="max_count"):
        greedy_information(torch.zeros(1, 3, 6, 6), torch.zeros(1, 6, 6), max_count=0)


def _information(rvec, tvec):
    w = torch.ones(1, rvec.shape[0], 54, dtype=torch.float64)
    cam = Camera.from_opencv(K1K2, K, DIST[:2], SIZE)
    return view_information(cam, rvec[None], tvec[None], OBJ, w), image_information(cam)


def test_greedy_with_copies_ruled_out_takes_every_pose_once():
    _, rvec, tvec = _views(6, seed=3)
    # views 6..11 repeat views 0..5 (a repeat of a strong view can outweigh a weak new one: copies are ruled out)
    M, A = _information(torch.cat([rvec, rvec]), torch.cat([tvec, tvec]))
    plain = greedy_information(M, A, max_count=6)
    assert plain.reason.count("cap") == 6 and plain.uncertainty.shape == (1, 7)
    assert bool((plain.uncertainty[0, 1:] <= plain.uncertainty[0, :-1]).all())  # each view lowers it
    copies = torch.zeros(12, 12, dtype=torch.bool)
    for v in range(6):
        copies[v, v + 6] = copies[v + 6, v] = True
    choice = greedy_information(M, A, conflicts=copies)
    assert sorted(v % 6 for v in choice.order) == list(range(6)) and choice.reason.count("copy") == 6
    # copies last: every pose once first, then the repeats, each judged again (taken ones lose their reason)
    last = greedy_information(M, A, conflicts=copies, copies_last=True)
    assert sorted(v % 6 for v in last.order[:6]) == list(range(6)) and sorted(last.order) == list(range(12))
    assert last.reason == [""] * 12 and last.copy_of == [-1] * 12
    capped = greedy_information(M, A, conflicts=copies, copies_last=True, max_count=8)
    assert capped.order[:6] == last.order[:6] and len(capped.order) == 8
    assert capped.reason.count("copy") == 4 and capped.reason.count("cap") == 0
    assert all(capped.copy_of[v] >= 0 for v in range(12) if capped.reason[v] == "copy")
    stopped = greedy_information(M, A, conflicts=copies, copies_last=True, min_gain=1.0)  # nothing adds that much
    assert stopped.order == [] and stopped.reason.count("adds nothing") == 12


def test_greedy_stops_when_a_view_adds_nothing_and_rules_out_copies():
    _, rvec, tvec = _views(10, seed=4)
    M, A = _information(rvec, tvec)
    every = greedy_information(M, A)
    assert len(every.order) == 10 and every.gains[0] == max(every.gains)
    threshold = min(every.gains[:6])
    stop = greedy_information(M, A, min_gain=threshold)
    n = len(stop.order)
    assert n >= 6 and stop.order == every.order[:n] and min(stop.gains) >= threshold
    assert stop.reason.count("adds nothing") == 10 - n
    conflicts = torch.zeros(10, 10, dtype=torch.bool)
    first = every.order[0]
    conflicts[(first + 1) % 10, first] = True  # that view nearly copies the first one taken
    copies = greedy_information(M, A, conflicts=conflicts)
    assert copies.reason[(first + 1) % 10] == "copy" and copies.copy_of[(first + 1) % 10] == first


def test_links_bring_the_frames_two_cameras_share():
    _, rvec, tvec = _views(8, seed=5)
    M1, A = _information(rvec, tvec)
    M = torch.cat([M1, M1])  # two cameras; camera 1 sees frames 0-3 only, camera 0 all of them
    M[1, 4:] = 0
    A2 = torch.cat([A, A])
    alone = greedy_information(M, A2, max_count=2)
    linked = greedy_information(M, A2, max_count=2, links=True,
                                link_weights=torch.ones(2, 8, dtype=torch.float64))
    assert all(v < 4 for v in linked.order)  # both frames taken tie the cameras together
    assert len(alone.order) == 2
