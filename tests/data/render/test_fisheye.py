"""Kannala-Brandt fisheye renders: exact corners (cv2.fisheye), exact inverse, image circle, poses."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.render.fisheye import (
    fisheye_cameras,
    kb_distort_theta,
    kb_reach,
    kb_unproject,
    sample_fisheye_cameras,
    sample_fisheye_poses,
)
from ccs_kornia.data.render.lens import project_board, view_cameras
from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models import FISHEYE, OPENCV5


def _cameras(n=6, size=(640, 480), seed=0):
    return sample_fisheye_cameras(n, size, torch.Generator().manual_seed(seed))


def test_projection_matches_cv2_fisheye_to_1e6_px():
    K, fe = _cameras(6)
    cams = fisheye_cameras(K, fe, (640, 480))
    assert cams.model == FISHEYE and torch.equal(cams.K, K) and cams.image_size == (640, 480)
    g = torch.Generator().manual_seed(1)
    for i in range(6):
        pts = torch.rand(1, 200, 3, generator=g, dtype=torch.float64) * torch.tensor([4.0, 4.0, 2.0]) - torch.tensor([2.0, 2.0, -0.05])
        rvec = torch.rand(1, 3, generator=g, dtype=torch.float64) * 0.6 - 0.3
        tvec = torch.tensor([[0.1, -0.05, 0.2]], dtype=torch.float64)
        cam = camera.transform_points_rt(pts, rvec, tvec)
        front = cam[0, :, 2] > 1e-3  # cv2.fisheye models points in front of the camera only
        pix = cams[i].project(cam)
        Kn = K[i].numpy()
        ref, _ = cv2.fisheye.projectPoints(pts[0].numpy().reshape(-1, 1, 3), rvec[0].numpy(), tvec[0].numpy(), Kn,
                                           fe[i, :4].numpy())
        err = np.abs(ref.reshape(-1, 2) - pix[0].numpy())[front.numpy()]
        assert err.max() < 1e-6


def test_reach_is_the_image_circle_before_the_fold():
    fe = torch.tensor([[0.0, 0.0, 0.0, 0.0, math.radians(80.0)], [-0.2, 0.0, 0.0, 0.0, math.radians(100.0)]],
                      dtype=torch.float64)
    theta = torch.tensor([0.0, 1.0, math.radians(79.0), math.radians(81.0), math.radians(95.0), 3.0],
                         dtype=torch.float64)
    rays = torch.stack([theta.sin(), torch.zeros_like(theta), theta.cos()], -1).expand(2, -1, -1)
    ok = kb_reach(rays, fe)
    assert ok[0].tolist() == [True, True, True, False, False, False]
    # k1 = -0.2: theta_d stops growing near 1.2 rad (slope 1 - 0.6 theta^2), well inside the 200-degree circle
    assert ok[1].tolist() == [True, True, False, False, False, False]


def test_view_cameras_give_each_view_its_model():
    K = torch.tensor([[300.0, 0, 320], [0, 300, 240], [0, 0, 1]], dtype=torch.float64).expand(3, 3, 3)
    dist = torch.tensor([[-0.2, 0.05, 0.0, 0.0, 0.0]] * 3, dtype=torch.float64)
    fe = torch.tensor([[0.0] * 5, [0.02, 0.0, 0.0, 0.0, 1.6], [0.0] * 5], dtype=torch.float64)
    cams = view_cameras(K, dist, fe, (640, 480))
    assert cams.models == (OPENCV5, FISHEYE, OPENCV5) and cams.image_sizes == ((640, 480),) * 3
    pts = torch.tensor([[[0.2, -0.1, 1.0], [1.0, 0.5, -0.2]]], dtype=torch.float64).expand(3, -1, -1)
    pix = cams.project(pts)
    torch.testing.assert_close(pix[1], fisheye_cameras(K[1:2], fe[1:2]).project(pts[1:2])[0])
    torch.testing.assert_close(pix[0, 0], camera.project_points(pts[0, :1], K[0], dist[0])[0], atol=1e-12, rtol=0)
    skewed = K.clone()
    skewed[:, 0, 1] = 0.4
    with pytest.raises(ValueError, match="skew"):
        view_cameras(skewed, dist)


def test_render_ground_truth_is_cv2_fisheye_projection():
    K, fe = _cameras(3, seed=2)
    cols, rows = torch.full((3,), 8), torch.full((3,), 6)
    sq = torch.full((3,), 0.03, dtype=torch.float64)
    rv, tv = sample_fisheye_poses(K, fe, cols, rows, sq, (640, 480), torch.Generator().manual_seed(3))
    _, corners = render_chessboard(K, rv, tv, (8, 6), 0.03, (640, 480), supersample=1, fisheye=fe[:, :4],
                                   fov_deg=torch.rad2deg(2 * fe[:, 4]))
    obj = board_object_points(8, 6, 0.03, dtype=torch.float64).numpy().reshape(-1, 1, 3)
    for i in range(3):
        Kn = K[i].numpy()
        ref, _ = cv2.fisheye.projectPoints(obj, rv[i].numpy(), tv[i].numpy(), Kn, fe[i, :4].numpy())
        assert np.abs(ref.reshape(-1, 2) - corners[i].numpy()).max() < 1e-6


def test_unprojection_inverts_projection_beyond_90_degrees():
    K, fe = _cameras(4, seed=4)
    fe[:, 4] = math.radians(100.0)  # 200 degree lenses
    theta = torch.linspace(0.0, math.radians(99.0), 50, dtype=torch.float64)
    phi = torch.linspace(0.0, 6.0, 50, dtype=torch.float64)
    rays = torch.stack([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], -1)
    for i in range(4):
        if float(fe[i, 4]) <= 0:
            continue
        td, _ = kb_distort_theta(theta, fe[i, :4])
        xd, yd = td * phi.cos(), td * phi.sin()
        dx, dy, dz, reach = kb_unproject(xd[None].float(), yd[None].float(), fe[i:i + 1])
        back = torch.stack([dx, dy, dz], -1)[0].double()
        ok = reach[0]
        assert bool(ok[:45].all())
        assert (back[ok] - rays[ok]).norm(dim=-1).max() < 2e-5  # float32 grid precision


def test_rendered_fisheye_corner_is_where_the_truth_says():
    """A steep, curved board near the edge of a 190-degree view: cornerSubPix on the render lands on the truth."""
    K = torch.tensor([[[170.0, 0.0, 319.5], [0.0, 170.0, 239.5], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    fe = torch.tensor([[0.02, -0.003, 0.0005, 0.0, math.radians(95.0)]], dtype=torch.float64)
    rv, tv = sample_fisheye_poses(K, fe, torch.tensor([6]), torch.tensor([4]), torch.tensor([0.05], dtype=torch.float64),
                                  (640, 480), torch.Generator().manual_seed(7), span_deg=(60.0, 80.0))
    img, corners = render_chessboard(K, rv, tv, (6, 4), 0.05, (640, 480), supersample=4, fisheye=fe[:, :4],
                                     fov_deg=190.0, background=0.5)
    gray = (img[0, 0].numpy() * 255).astype(np.float32)
    c = corners[0].numpy().astype(np.float32).reshape(-1, 1, 2)
    refined = cv2.cornerSubPix(gray, c.copy(), (3, 3), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
    assert np.median(np.linalg.norm(refined - c, axis=-1)) < 0.1


def test_image_circle_and_backward_rays_are_black_or_background():
    K = torch.tensor([[100.0, 0.0, 159.5], [0.0, 100.0, 119.5], [0.0, 0.0, 1.0]])
    # a board behind the camera is never seen; the image circle of a 120-degree lens is black outside
    img, _ = render_chessboard(K, torch.zeros(1, 3), torch.tensor([[0.0, 0.0, -0.5]]), (5, 4), 0.03, (320, 240),
                               fisheye=torch.zeros(4), fov_deg=120.0, background=0.5, supersample=1)
    theta_edge = math.radians(60.0) * 100.0  # equidistant: radius of the image circle in px
    assert float(img[0, 0, 120, 160]) == pytest.approx(0.5, abs=1e-6)
    assert float(img[0, 0, 0, 0]) == 0.0 and math.hypot(160, 120) > theta_edge


def test_fisheye_poses_keep_every_corner_inside_and_favour_the_border():
    K, fe = _cameras(8, seed=5)
    cols, rows = torch.full((8,), 8), torch.full((8,), 6)
    sq = torch.full((8,), 0.03, dtype=torch.float64)
    rv, tv = sample_fisheye_poses(K, fe, cols, rows, sq, (640, 480), torch.Generator().manual_seed(6))
    obj = board_object_points(8, 6, 0.03, dtype=torch.float64).expand(8, -1, -1)
    pix, ok = project_board(obj, K, rv, tv, (640, 480), fisheye=fe)
    assert bool(ok.all())
    assert bool(((pix[..., 0] >= 4) & (pix[..., 0] <= 635) & (pix[..., 1] >= 4) & (pix[..., 1] <= 475)).all())
    # some boards sit far from the centre, where the lens bends them
    centre = K[:, :2, 2]
    assert float((pix.mean(1) - centre).norm(dim=-1).max()) > 120.0
