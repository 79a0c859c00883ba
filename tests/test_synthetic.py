from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia import camera
from ccs_kornia.data import augment
from ccs_kornia.data.lens import _opencv_fold, _undistort_opencv
from ccs_kornia.data.scenes import SyntheticBatch, SyntheticChessboards, make_calibration_set
from ccs_kornia.data.lens import board_coordinates, project_board
from ccs_kornia.data.targets import gaussian_heatmaps
from ccs_kornia.data.renderer import render_chessboard
from ccs_kornia.data.sampling import sample_opencv_distortion, sample_poses, sample_radial_distortion

W, H = 160, 120


@pytest.fixture(autouse=True)
def _one_thread():
    # the test machine is shared: one thread avoids barrier stalls between oversubscribed workers
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _K(fx=200.0, fy=205.0, cx=80.3, cy=59.2, dtype=torch.float32):
    return torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)


def _poses(n, K=None, board=(5, 4), square=0.03, size=(W, H), seed=0, **kw):
    K = _K() if K is None else K
    return sample_poses(K, board, square, size, n, torch.Generator().manual_seed(seed), **kw)


# ----------------------------------------------------------------------------------------------
# renderer: shapes, batching, exceptions
# ----------------------------------------------------------------------------------------------


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


# ----------------------------------------------------------------------------------------------
# geometry: ground truth and the inverse mapping
# ----------------------------------------------------------------------------------------------


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
    obj = camera.board_object_points(5, 4, 0.03, dtype=torch.float64).numpy()
    for i in range(4):
        ref, _ = cv2.projectPoints(obj, r[i].numpy(), t[i].numpy(), K.numpy(), dist.numpy())
        np.testing.assert_allclose(corners[i].numpy(), ref.reshape(-1, 2), atol=1e-8)


def test_radial_corners_follow_paper_model():
    K = _K(dtype=torch.float64)
    radial = torch.tensor([1.02, -0.3, -0.08], dtype=torch.float64)
    r, t = _poses(2, K=K, radial=radial, seed=4)
    _, corners = render_chessboard(K, r, t, (5, 4), 0.03, (W, H), radial=radial, supersample=1)
    ideal = camera.project_points(camera.board_object_points(5, 4, 0.03, dtype=torch.float64), K, None, r, t).numpy()
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
    obj = camera.board_object_points(5, 4, 0.03, dtype=torch.float64).expand(3, -1, -1)
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


# ----------------------------------------------------------------------------------------------
# sampling
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("model", ["none", "opencv", "radial"])
def test_sample_poses_keep_corners_inside(model):
    K = _K()
    gen = torch.Generator().manual_seed(8)
    dist = sample_opencv_distortion(K, (W, H), 1, gen)[0] if model == "opencv" else None
    radial = sample_radial_distortion(1, "severe", (W, H), gen)[0] if model == "radial" else None
    margin = 6.0
    r, t = sample_poses(K, (5, 4), 0.03, (W, H), 24, gen, dist=dist, radial=radial, margin=margin)
    obj = camera.board_object_points(5, 4, 0.03).expand(24, -1, -1).double()
    pix, ok = project_board(obj, K.double().expand(24, 3, 3), r.double(), t.double(), (W, H),
                            None if dist is None else dist.double().expand(24, 5),
                            None if radial is None else radial.double().expand(24, 3))
    assert bool(ok.all())
    assert float(pix[..., 0].min()) >= margin and float(pix[..., 0].max()) <= W - 1 - margin
    assert float(pix[..., 1].min()) >= margin and float(pix[..., 1].max()) <= H - 1 - margin
    # varied poses: tilts up to 50 degrees about both axes, varied in-plane rotations and distances
    R = camera.axis_angle_to_rotation_matrix(r)
    tilt = torch.rad2deg(torch.acos(R[:, 2, 2].clamp(-1, 1)))
    assert float(tilt.max()) > 25 and float(tilt.max()) <= 50.5
    assert float(R[:, 0, 2].abs().max()) > 0.2 and float(R[:, 1, 2].abs().max()) > 0.2
    roll = torch.rad2deg(torch.atan2(R[:, 1, 0], R[:, 0, 0]))
    assert float(roll.max() - roll.min()) > 90
    assert float(t[:, 2].max() / t[:, 2].min()) > 1.3


def test_sample_poses_deterministic_and_raises():
    a = _poses(5, seed=11)
    b = _poses(5, seed=11)
    c = _poses(5, seed=12)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[0], c[0])
    with pytest.raises(RuntimeError):
        _poses(2, margin=70.0)  # impossible: margin larger than half the image height
    with pytest.raises(ValueError):
        _poses(2, fill_range=(0.0, 0.5))


def test_radial_levels():
    gen = torch.Generator().manual_seed(9)
    l1 = sample_radial_distortion(200, "level1", (640, 480), gen)
    assert bool((l1[:, 0] == 1).all()) and bool(((l1[:, 1] >= -0.35) & (l1[:, 1] <= -0.2)).all())
    assert bool(((l1[:, 2] >= -0.1) & (l1[:, 2] <= 0)).all())
    l2 = sample_radial_distortion(200, "level2", (640, 480), gen)
    assert bool(((l2[:, 0] >= 0.8) & (l2[:, 0] <= 1.2)).all()) and bool(((l2[:, 1] >= -0.5) & (l2[:, 1] <= -0.35)).all())
    assert bool(((l2[:, 2] >= -0.3) & (l2[:, 2] <= -0.1)).all())
    assert torch.equal(sample_radial_distortion(3, "none", (640, 480), gen), torch.tensor([[1.0, 0, 0]] * 3))
    sev = sample_radial_distortion(200, "severe", (640, 480), gen).double()
    # displacement of the farthest image corner: 15-25 % of its ideal radius, monotonic up to it
    rd = 0.5 * math.hypot(639, 479) / 640
    corner = torch.tensor([[[639.0, 479.0]]], dtype=torch.float64).expand(200, 1, 2)
    ideal = camera.radial_undistort_points(corner, sev, (640, 480))
    rc = (ideal[:, 0] - torch.tensor([319.5, 239.5], dtype=torch.float64)).norm(dim=-1) / 640
    disp = 1 - rd / rc
    assert float(disp.min()) > 0.149 and float(disp.max()) < 0.251
    slope = sev[:, 0] + 3 * sev[:, 1] * rc**2 + 5 * sev[:, 2] * rc**4
    assert float(slope.min()) > 0
    anyl = sample_radial_distortion(300, "any", (640, 480), gen)
    assert bool((anyl[:, 1] < 0).all())
    with pytest.raises(ValueError):
        sample_radial_distortion(2, "extreme", (640, 480), gen)


def test_opencv_distortion_sampling_is_invertible_over_the_image():
    gen = torch.Generator().manual_seed(10)
    K = camera.intrinsics_matrix(torch.tensor([[300.0, 300.0, 319.5, 239.5], [800.0, 800.0, 319.5, 239.5]])).repeat(50, 1, 1)
    d = sample_opencv_distortion(K, (640, 480), 100, gen).double()
    assert bool(((d[:, 0] >= -0.4) & (d[:, 0] <= 0.1)).all()) and bool((d[:, 2:4].abs() <= 2e-3).all())
    # the farthest image corner must be reached before the radial factor folds
    corners = torch.tensor([[[0.0, 0.0], [639.0, 479.0]]], dtype=torch.float64).expand(100, 2, 2)
    ideal, residual = _undistort_opencv(corners, K.double(), d)  # fixed point + Newton
    assert float(residual.max()) < 1e-6
    r_fold, _ = _opencv_fold(d)
    xn = (ideal - K[:, None, :2, 2].double()) / torch.stack([K[:, 0, 0], K[:, 1, 1]], -1)[:, None].double()
    assert bool((xn.norm(dim=-1) < r_fold[:, None]).all())


# ----------------------------------------------------------------------------------------------
# data sets
# ----------------------------------------------------------------------------------------------


def test_make_calibration_set():
    K = torch.tensor([[250.0, 0.0, 99.5], [0.0, 250.0, 74.5], [0.0, 0.0, 1.0]])
    b = make_calibration_set(K, (6, 4), 0.025, (200, 150), num_views=3, condition="blur_noise", seed=3, supersample=1)
    assert isinstance(b, SyntheticBatch) and len(b) == 3
    assert b.images.shape == (3, 1, 150, 200) and b.corners.shape == (3, 24, 2)
    assert bool(b.corner_valid.all()) and b.image_size == (200, 150)
    assert torch.equal(b.K, K.expand(3, 3, 3)) and torch.equal(b.board_size, torch.tensor([[6, 4]] * 3))
    assert bool((b.dist == 0).all()) and torch.equal(b.radial, torch.tensor([[1.0, 0, 0]] * 3))
    assert bool((b.condition == augment.CONDITIONS.index("blur_noise")).all())
    again = make_calibration_set(K, (6, 4), 0.025, (200, 150), num_views=3, condition="blur_noise", seed=3, supersample=1)
    assert torch.equal(b.images, again.images) and torch.equal(b.corners, again.corners)
    other = make_calibration_set(K, (6, 4), 0.025, (200, 150), num_views=3, condition="blur_noise", seed=4, supersample=1)
    assert not torch.equal(b.corners, other.corners)
    # ground truth is the forward projection of the stored parameters
    obj = camera.board_object_points(6, 4, 0.025).expand(3, -1, -1)
    proj = camera.project_points(obj, b.K, b.dist, b.rvec, b.tvec)
    assert float((proj - b.corners).abs().max()) < 1e-3
    moved = b.to("cpu")
    assert torch.equal(moved.images, b.images) and moved.image_size == b.image_size
    with pytest.raises(ValueError):
        make_calibration_set(K, condition="foggy")
    with pytest.raises(ValueError):
        make_calibration_set(K.expand(2, 3, 3))


def test_synthetic_chessboards_sample():
    data = SyntheticChessboards(image_size=(128, 96), board_cols=(4, 6), board_rows=(3, 5), fx_range=(120, 200),
                                partial_prob=0.5, supersample=2)
    gen = torch.Generator().manual_seed(0)
    b = data.sample(6, gen)
    assert b.images.shape == (6, 1, 96, 128) and b.corners.shape == (6, 30, 2) == (6, data.max_corners, 2)
    assert float(b.images.min()) >= 0 and float(b.images.max()) <= 1
    cols, rows = b.board_size[:, 0], b.board_size[:, 1]
    assert bool(((cols >= 4) & (cols <= 6) & (rows >= 3) & (rows <= 5)).all())
    n = torch.arange(30)
    exists = n[None] < (cols * rows)[:, None]
    assert not bool((b.corner_valid & ~exists).any())
    v = b.corners[b.corner_valid]
    assert float(v[:, 0].min()) >= data.margin and float(v[:, 0].max()) <= 127 - data.margin
    # each view keeps at least 30 % of its corners
    assert bool((b.corner_valid.sum(1) >= 0.3 * (cols * rows)).all())
    # radial views carry (k0, k1, k2), OpenCV views k1.., the rest identity coefficients
    assert b.dist.shape == (6, 5) and b.radial.shape == (6, 3) and b.condition.shape == (6,)
    # same generator seed, same batch
    b2 = data.sample(6, torch.Generator().manual_seed(0))
    assert torch.equal(b.images, b2.images) and torch.equal(b.corners, b2.corners)


def test_synthetic_chessboards_ground_truth_matches_render():
    """Ground truth of random scenes (all distortion modes) agrees with cornerSubPix on the rendered image."""
    data = SyntheticChessboards(image_size=(200, 150), board_cols=(5, 6), board_rows=(4, 5), fx_range=(180, 260),
                                conditions=("clean",), supersample=3, max_roll_deg=30.0, fill_range=(0.6, 0.9))
    b = data.sample(6, torch.Generator().manual_seed(2))
    errs = []
    for i in range(6):
        im = cv2.GaussianBlur(b.images[i, 0].numpy(), (0, 0), 1.0)
        c = b.corners[i][b.corner_valid[i]].numpy()
        out = cv2.cornerSubPix(im, c.reshape(-1, 1, 2).copy() + 0.4, (3, 3), (-1, -1), (3, 50, 1e-5))
        errs.append(np.linalg.norm(out.reshape(-1, 2) - c, axis=1))
    assert np.concatenate(errs).mean() < 0.06


def test_synthetic_chessboards_options():
    with pytest.raises(ValueError):
        SyntheticChessboards(distortion="fisheye")
    with pytest.raises(ValueError):
        SyntheticChessboards(conditions=("rain",))
    with pytest.raises(ValueError):
        SyntheticChessboards(board_cols=(5, 3))
    data = SyntheticChessboards(image_size=(96, 72), board_cols=(3, 4), board_rows=(3, 3), fx_range=(90, 120),
                                distortion="radial", radial_level="severe", supersample=1)
    b = data.sample(3, torch.Generator().manual_seed(1))
    assert bool((b.radial[:, 1] < 0).all()) and bool((b.dist == 0).all())
    data = SyntheticChessboards(image_size=(96, 72), board_cols=(3, 4), board_rows=(3, 3), fx_range=(90, 120),
                                distortion=("none",), supersample=1)
    b = data.sample(2, torch.Generator().manual_seed(1))
    assert bool((b.dist == 0).all()) and torch.equal(b.radial, torch.tensor([[1.0, 0, 0]] * 2))


# ----------------------------------------------------------------------------------------------
# heatmaps
# ----------------------------------------------------------------------------------------------


def test_gaussian_heatmaps():
    corners = torch.tensor([[[10.0, 8.0], [30.3, 20.6], [50.0, 5.0]], [[0.0, 0.0], [63.0, 47.0], [5.0, 5.0]]])
    valid = torch.tensor([[True, True, False], [True, True, False]])
    hm = gaussian_heatmaps(corners, valid, (64, 48), sigma=1.5)
    assert hm.shape == (2, 1, 48, 64)
    assert float(hm[0, 0, 8, 10]) == 1.0 and float(hm[1, 0, 0, 0]) == 1.0 and float(hm[1, 0, 47, 63]) == 1.0
    expected = math.exp(-(0.3**2 + 0.4**2) / (2 * 1.5**2))
    assert abs(float(hm[0, 0, 21, 30]) - expected) < 1e-6
    assert float(hm[0, 0].max()) == 1.0 and float(hm[0, 0, 5, 50]) == 0.0  # invalid corner ignored
    # equals a dense max over Gaussians (within the 3-sigma window)
    ys, xs = torch.meshgrid(torch.arange(48.0), torch.arange(64.0), indexing="ij")
    d2 = (xs[None] - corners[0, :2, 0, None, None]) ** 2 + (ys[None] - corners[0, :2, 1, None, None]) ** 2
    dense = torch.exp(-d2 / (2 * 1.5**2)).amax(0)
    window = hm[0, 0] > 0
    assert torch.allclose(hm[0, 0][window], dense[window], atol=1e-6)
    assert float(dense[~window].max()) < 0.02
    with pytest.raises(ValueError):
        gaussian_heatmaps(corners, valid[:, :2], (64, 48))
