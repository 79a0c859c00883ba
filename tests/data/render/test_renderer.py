"""Tests of the renderer: shapes, batching, exact ground truth, area sampling, distortion models."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from _render_helpers import _K, _poses

from ccs_kornia.data.render.lens import board_coordinates, project_board
from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.data.scenes.sampling import (
    sample_opencv_distortion,
    sample_poses,
    sample_radial_distortion,
)
from ccs_kornia.geometry import camera
from ccs_kornia.geometry.board_points import board_object_points

W, H = 160, 120


def test_render_smoke_shapes():
    r, t = _poses(3)
    img, corners = render_chessboard(_K(), r, t, (5, 4), 0.03, (W, H), supersample=2)
    assert img.shape == (3, 1, H, W) and img.dtype == torch.float32
    assert corners.shape == (3, 20, 2)
    assert float(img.min()) >= 0.0 and float(img.max()) <= 1.0
    # dark squares, light squares and the background are all present
    assert float(img.min()) < 0.15 and float(img.max()) > 0.85 and bool(((img - 0.5).abs() < 1e-6).any())


def test_render_batch_matches_single():
    r, t = _poses(3, seed=1)
    dist = torch.tensor([[-0.2, 0.05, 0.001, -0.001, 0.0], [0.0] * 5, [0.05, 0.0, 0.0, 0.0, 0.0]])
    radial = torch.tensor([[1.0, 0.0, 0.0], [1.0, -0.25, -0.05], [1.0, 0.0, 0.0]])
    K = _K().expand(3, 3, 3)
    img, corners = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), dist, radial, supersample=2)
    for i in range(3):
        one, c1 = render_chessboard(K[i : i + 1], r[i : i + 1], t[i : i + 1], (5, 4), 0.03, (W, H),
                                    dist[i : i + 1], radial[i : i + 1], supersample=2)
        assert torch.allclose(one, img[i : i + 1], atol=1e-5)
        assert torch.allclose(c1, corners[i : i + 1], atol=1e-4)


def test_render_per_view_boards_are_padded():
    r, t = _poses(2, board=(5, 4), seed=2)
    boards = torch.tensor([[5, 4], [3, 2]])
    img, corners = render_chessboard(_K(), r, t, boards, 0.03, (W, H), supersample=1)
    assert corners.shape == (2, 20, 2)
    assert bool((corners[1, 6:] == 0).all()) and bool((corners[1, :6] != 0).any())


def test_render_exceptions():
    r, t = _poses(2)
    with pytest.raises(ValueError):
        render_chessboard(_K(), r, t[:1], (5, 4), 0.03, (W, H))
    with pytest.raises(ValueError):
        render_chessboard(_K(), r, t, (1, 4), 0.03, (W, H))
    with pytest.raises(ValueError):
        render_chessboard(_K(), r, t, (5, 4), 0.03, (W, H), dist=torch.zeros(3, 5))
    with pytest.raises(ValueError):
        render_chessboard(_K(), r, t, (5, 4), 0.03, (W, H), supersample=0)
    with pytest.raises(ValueError):
        render_chessboard(_K(), r, t, (5, 4), 0.03, (W, H), background=torch.zeros(2, 1, 10, 10))


def _coverage(centres: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Exact overlap of unit pixels centred at ``centres`` with ``[lo, hi]``."""
    return np.clip(np.minimum(centres + 0.5, hi) - np.maximum(centres - 0.5, lo), 0.0, None)


def test_pixel_convention_analytic_board():
    """Fronto-parallel axis-aligned board, 10 px squares, corner (0, 0) at (30.3, 25.7): the render equals
    an independent exact area-coverage image, so the top-left pixel centre is (0, 0) and nothing is
    shifted by half a pixel."""
    x0, y0, p, cols, rows = 30.3, 25.7, 10.0, 5, 4
    K = torch.tensor([[400.0, 0.0, x0], [0.0, 400.0, y0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    img, corners = render_chessboard(K, torch.zeros(1, 3, dtype=torch.float64), torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64),
                                     (cols, rows), 0.025, (W, H), supersample=1, background=0.5, dark=0.1, light=0.9)
    i, j = np.meshgrid(np.arange(cols), np.arange(rows))
    expected_corners = np.stack([x0 + p * i.ravel(), y0 + p * j.ravel()], -1)
    np.testing.assert_allclose(corners[0].numpy(), expected_corners, atol=1e-9)
    xs, ys = np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64)
    # board: [-2, cols+1] squares (one-square border), checker area [-1, cols]; dark where floor(u)+floor(v) even
    board = np.outer(_coverage(ys, y0 - 2 * p, y0 + (rows + 1) * p), _coverage(xs, x0 - 2 * p, x0 + (cols + 1) * p))
    dark = np.zeros((H, W))
    for a in range(-1, cols):
        for b in range(-1, rows):
            if (a + b) % 2 == 0:
                dark += np.outer(_coverage(ys, y0 + b * p, y0 + (b + 1) * p), _coverage(xs, x0 + a * p, x0 + (a + 1) * p))
    expected = 0.5 * (1 - board) + 0.9 * board - 0.8 * dark
    assert np.abs(img[0, 0].double().numpy() - expected).max() < 1e-5
    # and the intensity profile across the vertical edge at x = x0 is the exact coverage (0.3 / 0.7 split)
    row = img[0, 0, int(y0 + 5)].double().numpy()  # square row v in [0, 1]: square (-1, 0) light, (0, 0) dark
    assert abs(row[30] - (0.9 * 0.8 + 0.1 * 0.2)) < 1e-5  # pixel 30 covers [29.5, 30.5]: 0.8 light, 0.2 dark
    assert abs(row[29] - 0.9) < 1e-6 and abs(row[31] - 0.1) < 1e-6


def test_corners_match_cv2_projection():
    K = _K(dtype=torch.float64)
    dist = torch.tensor([-0.25, 0.08, 0.001, -0.0015, 0.01], dtype=torch.float64)
    r, t = _poses(4, K=K, dist=dist, seed=3)
    _, corners = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), dist=dist, supersample=1)
    obj = board_object_points(5, 4, 0.03, dtype=torch.float64).numpy()
    for i in range(4):
        ref, _ = cv2.projectPoints(obj, r[i].numpy(), t[i].numpy(), K.numpy(), dist.numpy())
        np.testing.assert_allclose(corners[i].numpy(), ref.reshape(-1, 2), atol=1e-8)


def test_radial_corners_follow_paper_model():
    K = _K(dtype=torch.float64)
    radial = torch.tensor([1.02, -0.3, -0.08], dtype=torch.float64)
    r, t = _poses(2, K=K, radial=radial, seed=4)
    _, corners = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), radial=radial, supersample=1)
    ideal = camera.project_points(board_object_points(5, 4, 0.03, dtype=torch.float64), K, None, r, t).numpy()
    centre, scale = np.array([(W - 1) / 2, (H - 1) / 2]), max(W, H)
    q = (ideal - centre) / scale
    rc = np.linalg.norm(q, axis=-1, keepdims=True)
    expected = q * (1.02 - 0.3 * rc**2 - 0.08 * rc**4) * scale + centre
    np.testing.assert_allclose(corners.numpy(), expected, atol=1e-9)


@pytest.mark.parametrize("model", ["none", "opencv", "radial", "both"])
def test_inverse_mapping_returns_grid_coordinates(model):
    """board_coordinates(ground-truth corner) == (i, j): the renderer's inverse chain is the exact inverse
    of the forward model that produces the ground truth."""
    K = _K(dtype=torch.float64)
    dist = torch.tensor([-0.3, 0.1, 0.0015, -0.001, 0.0], dtype=torch.float64) if model in ("opencv", "both") else None
    radial = torch.tensor([0.97, -0.3, -0.1], dtype=torch.float64) if model in ("radial", "both") else None
    r, t = _poses(3, K=K, dist=dist, radial=radial, seed=5)
    obj = board_object_points(5, 4, 0.03, dtype=torch.float64).expand(3, -1, -1)
    pix, ok = project_board(obj, K.expand(3, 3, 3), r, t, (W, H),
                            None if dist is None else dist.expand(3, 5), None if radial is None else radial.expand(3, 3))
    assert bool(ok.all())
    uv, reach, front = board_coordinates(pix, K.expand(3, 3, 3), r, t, torch.full((3,), 0.03, dtype=torch.float64), (W, H),
                                         None if dist is None else dist.expand(3, 5), None if radial is None else radial.expand(3, 3))
    assert bool(reach.all()) and bool(front.all())
    expected = obj[..., :2] / 0.03
    assert float((uv - expected).abs().max()) < 1e-7


def _point_sampled(K, r, t, board, square, pixels, dist=None, radial=None, n=48, border=1.0):
    """Reference: n x n point samples per pixel through the exact per-point inverse (float64)."""
    cols, rows = board
    offs = (torch.arange(n, dtype=torch.float64) + 0.5) / n - 0.5
    oy, ox = torch.meshgrid(offs, offs, indexing="ij")
    pts = (pixels[:, None, :] + torch.stack([ox.reshape(-1), oy.reshape(-1)], -1)[None]).reshape(1, -1, 2)
    uv, reach, front = board_coordinates(pts, K[None], r[None], t[None], torch.tensor([square], dtype=torch.float64), (W, H),
                                         None if dist is None else dist[None], None if radial is None else radial[None])
    u, v = uv[0, :, 0], uv[0, :, 1]
    on_board = (u >= -1 - border) & (u <= cols + border) & (v >= -1 - border) & (v <= rows + border) & front[0]
    in_checker = (u >= -1) & (u <= cols) & (v >= -1) & (v <= rows)
    dark = in_checker & (torch.remainder(torch.floor(u) + torch.floor(v), 2) == 0)
    val = torch.where(on_board, torch.where(dark, 0.1, 0.9), torch.tensor(0.5, dtype=torch.float64))
    val = torch.where(reach[0], val, torch.zeros_like(val))
    return val.view(len(pixels), -1).mean(-1)


@pytest.mark.parametrize("model", ["tilted", "opencv", "radial"])
def test_area_sampling_matches_dense_point_sampling(model):
    """The analytic box-filtered render equals brute-force area sampling (48x48 points per pixel) on the
    pixels where it matters: edges and corners, under tilt and distortion."""
    K = _K(dtype=torch.float64)
    dist = torch.tensor([-0.3, 0.1, 0.001, 0.001, 0.0], dtype=torch.float64) if model == "opencv" else None
    radial = torch.tensor([1.0, -0.3, -0.1], dtype=torch.float64) if model == "radial" else None
    r, t = _poses(1, K=K, dist=dist, radial=radial, seed=6, fill_range=(0.6, 0.8))
    img, _ = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), dist, radial, supersample=4, background=0.5)
    img = img[0, 0].double()
    # pixels next to edges: where the rendered image is not flat
    gy, gx = torch.gradient(img)
    edge = (gx.abs() + gy.abs()) > 0.02
    idx = edge.reshape(-1).nonzero().squeeze(1)
    idx = idx[torch.randperm(idx.numel(), generator=torch.Generator().manual_seed(0))[:300]]
    pixels = torch.stack([(idx % W).double(), (idx // W).double()], -1)
    ref = _point_sampled(K, r[0], t[0], (5, 4), 0.03, pixels, dist, radial)
    err = (img.reshape(-1)[idx] - ref).abs()
    # reference quantisation with 48 samples is ~0.8/96 per axis for straight edges
    assert float(err.max()) < 0.02, float(err.max())
    assert float(err.mean()) < 0.003, float(err.mean())


def _subpix_errors(img, corners, board, blur=0.0, seed=0):
    rng = np.random.RandomState(seed)
    errs = []
    for i in range(img.shape[0]):
        im = img[i, 0].numpy().astype(np.float32)
        if blur > 0:
            im = cv2.GaussianBlur(im, (0, 0), blur)
        cc = corners[i].numpy().astype(np.float64)
        grid = cc.reshape(board[1], board[0], 2)
        spacing = min(np.linalg.norm(np.diff(grid, axis=1), axis=-1).min(), np.linalg.norm(np.diff(grid, axis=0), axis=-1).min())
        win = max(2, int(round(spacing / 4)))  # window of about half a square
        start = (cc + rng.uniform(-0.7, 0.7, cc.shape)).astype(np.float32).reshape(-1, 1, 2)
        out = cv2.cornerSubPix(im, start, (win, win), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5))
        errs.append(out.reshape(-1, 2) - cc)
    return np.concatenate(errs)


def test_cornersubpix_agrees_with_ground_truth():
    """cv2.cornerSubPix on clean renders lands on the analytic corners: mean error < 0.05 px and no
    half-pixel (or any) bias. (cornerSubPix itself locks to the pixel grid by up to ~0.08 px on sharp
    axis-aligned corners, which is why varied poses are used.)"""
    K = torch.tensor([[300.0, 0.0, 161.3], [0.0, 310.0, 118.2], [0.0, 0.0, 1.0]])
    board = (7, 5)
    r, t = sample_poses(K, board, 0.03, (320, 240), 8, torch.Generator().manual_seed(0), fill_range=(0.5, 0.9))
    img, corners = render_chessboard(K, r, t, board, 0.03, (320, 240), supersample=4)
    e = _subpix_errors(img, corners, board)
    assert np.linalg.norm(e, axis=1).mean() < 0.05
    assert np.abs(e.mean(0)).max() < 0.01
    # with a little optical blur cornerSubPix stops pixel-locking: the render is far more precise
    e = _subpix_errors(img, corners, board, blur=1.0)
    assert np.linalg.norm(e, axis=1).mean() < 0.03
    assert np.abs(e.mean(0)).max() < 0.01


@pytest.mark.parametrize("model", ["opencv", "severe"])
def test_cornersubpix_on_distorted_renders(model):
    K = torch.tensor([[300.0, 0.0, 161.3], [0.0, 310.0, 118.2], [0.0, 0.0, 1.0]])
    board = (7, 5)
    gen = torch.Generator().manual_seed(1)
    dist = torch.tensor([-0.3, 0.1, 0.001, -0.001, 0.0]) if model == "opencv" else None
    radial = sample_radial_distortion(1, "severe", (320, 240), gen)[0] if model == "severe" else None
    r, t = sample_poses(K, board, 0.03, (320, 240), 8, gen, dist=dist, radial=radial, fill_range=(0.5, 0.9))
    img, corners = render_chessboard(K, r, t, board, 0.03, (320, 240), dist, radial, supersample=4)
    e = _subpix_errors(img, corners, board, blur=1.0)
    assert np.linalg.norm(e, axis=1).mean() < 0.035
    assert np.abs(e.mean(0)).max() < 0.01


def test_wide_angle_opencv_distortion_renders_without_holes():
    """Strong barrel distortion on a wide-angle camera: every pixel has a preimage (no black holes where
    kornia's fixed-point inverse alone would cycle), and the board is found where the exact path puts it."""
    gen = torch.Generator().manual_seed(12)
    K = camera.intrinsics_matrix(torch.tensor([75.0, 75.0, 79.5, 59.5])).expand(8, 3, 3)
    dist = sample_opencv_distortion(K, (W, H), 8, gen)
    assert float(dist[:, 0].min()) < -0.2
    r, t = sample_poses(K, (5, 4), 0.03, (W, H), 8, gen, dist=dist, margin=4.0)
    img, _ = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), dist, supersample=1, background=0.5)
    assert float(img.min()) > 0.05


def test_unreachable_pixels_are_black():
    """level2 coefficients can fold before the image corner: those pixels have no preimage."""
    radial = torch.tensor([0.8, -0.5, -0.3])
    K = _K()
    r, t = _poses(1, K=K, radial=radial, seed=7, fill_range=(0.3, 0.4))
    img, _ = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), radial=radial, supersample=1, background=0.5)
    assert float(img[0, 0, 0, 0]) == 0.0 and float(img[0, 0, -1, -1]) == 0.0
    assert float(img[0, 0, H // 2, W // 2]) > 0.05


def test_per_view_border_keeps_the_corners_and_the_checker_area():
    r, t = _poses(3, seed=4)
    K = _K().expand(3, 3, 3)
    border = torch.tensor([0.05, 0.6, 1.5])
    img, corners = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), supersample=2, background=0.0, border=border)
    wide, c_wide = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), supersample=2, background=0.0, border=1.5)
    assert torch.equal(corners, c_wide)  # the margin never moves the ground truth
    for i in range(3):  # a tensor border renders each view as the same scalar border does
        one, _ = render_chessboard(K[i : i + 1], r[i : i + 1], t[i : i + 1], (5, 4), 0.03, (W, H), supersample=2,
                                   background=0.0, border=float(border[i]))
        assert torch.allclose(one, img[i : i + 1], atol=1e-5)
    # pixels whose footprint lies inside the checker area are identical; only the margin and surround change
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    pix = torch.stack([xs, ys], -1).reshape(1, -1, 2).expand(3, -1, -1)
    uv, reach, front = board_coordinates(pix, K.double(), r.double(), t.double(), torch.full((3,), 0.03, dtype=torch.float64),
                                         (W, H))
    inside = ((uv[..., 0] > -0.8) & (uv[..., 0] < 4.8) & (uv[..., 1] > -0.8) & (uv[..., 1] < 3.8) & reach & front)
    inside = inside.view(3, 1, H, W)
    assert bool(inside.any())
    assert float((img - wide).abs()[inside].max()) < 1e-5
    assert float((img[0] - wide[0]).abs().max()) > 0.3  # the thin margin shows the dark surround
