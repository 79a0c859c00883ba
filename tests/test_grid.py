from __future__ import annotations

import math
import time

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.camera import (
    axis_angle_to_rotation_matrix,
    board_object_points,
    intrinsics_matrix,
    project_points,
    rotation_matrix_to_axis_angle,
)
from ccs_kornia.modules.detection.collinearity import CollinearityRefiner, collinearity_refine
from ccs_kornia.modules.detection.grid_organizer import GridOrganizer, is_symmetric_board, organize_grid

F64 = torch.float64
W, H = 640, 480
K = intrinsics_matrix(torch.tensor([600.0, 600.0, (W - 1) / 2, (H - 1) / 2], dtype=F64))


def _pose(tilt_deg: float, azimuth: float, roll: float, dist: float, shift=(0.0, 0.0)):
    rz = axis_angle_to_rotation_matrix(torch.tensor([[0.0, 0.0, roll]], dtype=F64))[0]
    t = math.radians(tilt_deg)
    tilt_axis = torch.tensor([[t * math.cos(azimuth), t * math.sin(azimuth), 0.0]], dtype=F64)
    rt = axis_angle_to_rotation_matrix(tilt_axis)[0]
    rvec = rotation_matrix_to_axis_angle((rt @ rz)[None])[0]
    return rvec, torch.tensor([shift[0] * dist, shift[1] * dist, dist], dtype=F64)


def _views(cols, rows, n, seed, tilt=(0.0, 60.0), roll=None, dist_coeffs=None, square=1.0):
    """Random board views (B, N, 2) fully inside a 640x480 image, plus their (rvec, tvec)."""
    g = torch.Generator().manual_seed(seed)
    rnd = lambda: float(torch.rand(1, generator=g))  # noqa: E731
    obj = board_object_points(cols, rows, square, dtype=F64)
    centre = obj.mean(0) * torch.tensor([1.0, 1.0, 0.0], dtype=F64)
    d = None if dist_coeffs is None else torch.tensor(dist_coeffs, dtype=F64)
    out, poses = [], []
    while len(out) < n:
        r = rnd() * 2 * math.pi if roll is None else roll + (rnd() - 0.5) * 0.2
        depth = max(cols, rows) * square * 600.0 / (250 + 250 * rnd())  # board 250-500 px wide
        shift = ((rnd() - 0.5) * 0.3, (rnd() - 0.5) * 0.3)
        rvec, tvec = _pose(tilt[0] + rnd() * (tilt[1] - tilt[0]), rnd() * 2 * math.pi, r, depth, shift)
        # the board's own frame is centred so that poses are about its middle
        tvec = tvec - (axis_angle_to_rotation_matrix(rvec[None])[0] @ centre)
        uv = project_points(obj, K, d, rvec, tvec)
        if uv[:, 0].min() < 8 or uv[:, 0].max() > W - 9 or uv[:, 1].min() < 8 or uv[:, 1].max() > H - 9:
            continue
        out.append(uv)
        poses.append((rvec, tvec))
    return torch.stack(out), poses


def _shuffle(points, g, noise=0.2):
    b, n, _ = points.shape
    noisy = points + noise * torch.randn(points.shape, generator=g, dtype=points.dtype)
    perm = torch.stack([torch.randperm(n, generator=g) for _ in range(b)])
    return torch.gather(noisy, 1, perm[..., None].expand(-1, -1, 2)), torch.ones(b, n, dtype=torch.bool)


def _corrupt(gt, g, missing=0.0, extra=0.0, noise=0.2):
    """Drop a fraction of corners, add false peaks (half near the board), shuffle, pad."""
    b, n, _ = gt.shape
    m = n + int(extra * n)
    pts = torch.zeros(b, m, 2, dtype=gt.dtype)
    mask = torch.zeros(b, m, dtype=torch.bool)
    kept = torch.zeros(b, n, dtype=torch.bool)
    for k in range(b):
        keep = torch.rand(n, generator=g) >= missing
        real = gt[k][keep] + noise * torch.randn(int(keep.sum()), 2, generator=g, dtype=gt.dtype)
        n_extra = int(extra * n)
        lo, hi = gt[k].min(0).values, gt[k].max(0).values
        near = (lo + hi) / 2 + (torch.rand(n_extra // 2, 2, generator=g, dtype=gt.dtype) * 2 - 1) * (hi - lo) * 0.65
        far = torch.rand(n_extra - n_extra // 2, 2, generator=g, dtype=gt.dtype) * torch.tensor([W, H], dtype=gt.dtype)
        allp = torch.cat([real, near, far])
        allp = allp[torch.randperm(len(allp), generator=g)]
        pts[k, : len(allp)] = allp
        mask[k, : len(allp)] = True
        kept[k] = keep
    return pts, mask, kept


def _labellings(gt, cols, rows):
    """Non-mirrored relabellings of a ground-truth board that keep i along ``cols``."""
    g = gt.reshape(rows, cols, -1)
    out = [g, torch.rot90(g, 2, (0, 1))]
    if cols == rows:
        out += [torch.rot90(g, 1, (0, 1)), torch.rot90(g, 3, (0, 1))]
    return [o.reshape(rows * cols, -1) for o in out]


def _convention(gt, cols, rows):
    """The documented ordering without an image: corner 0 with the smallest x + y."""
    return min(_labellings(gt, cols, rows), key=lambda o: float(o[0].sum()))


# ----------------------------------------------------------------------------------------------
# organize_grid
# ----------------------------------------------------------------------------------------------


def test_smoke_and_module():
    gt, _ = _views(5, 4, 2, seed=0)
    g = torch.Generator().manual_seed(0)
    pts, mask = _shuffle(gt, g)
    org = GridOrganizer((5, 4))
    corners, valid, found = org(pts.float(), mask)
    assert corners.shape == (2, 20, 2) and corners.dtype == torch.float32
    assert valid.shape == (2, 20) and valid.dtype == torch.bool
    assert found.shape == (2,) and found.dtype == torch.bool
    assert found.all() and valid.all()
    assert "board_size=(5, 4)" in repr(org)


def test_symmetric_board_rule():
    assert not is_symmetric_board((9, 6)) and not is_symmetric_board((11, 8)) and not is_symmetric_board((4, 7))
    assert is_symmetric_board((8, 6)) and is_symmetric_board((4, 6)) and is_symmetric_board((7, 7))


@pytest.mark.parametrize("board", [(9, 6), (4, 6), (8, 6), (11, 8), (7, 7)])
def test_ordering_convention(board):
    cols, rows = board
    gt, _ = _views(cols, rows, 12, seed=cols * rows)
    g = torch.Generator().manual_seed(1)
    pts, mask = _shuffle(gt, g)
    corners, valid, found = organize_grid(pts, mask, board)
    assert found.all() and valid.all()
    for b in range(len(gt)):
        expected = _convention(gt[b], cols, rows)
        # same labelling as the convention (noise is 0.2 px; a wrong label is >= one square away)
        assert (corners[b] - expected).norm(dim=-1).max() < 1.5
        # never mirrored: d/di x d/dj > 0 in image coordinates (y down)
        c = corners[b].reshape(rows, cols, 2)
        di, dj = c[0, 1] - c[0, 0], c[1, 0] - c[0, 0]
        assert di[0] * dj[1] - di[1] * dj[0] > 0


@pytest.mark.parametrize("board", [(9, 6), (6, 4)])
def test_board_rotated_90_degrees(board):
    cols, rows = board
    for roll in (math.pi / 2, -math.pi / 2):
        gt, _ = _views(cols, rows, 4, seed=3, tilt=(0.0, 40.0), roll=roll)
        pts, mask = _shuffle(gt, torch.Generator().manual_seed(2))
        corners, valid, found = organize_grid(pts, mask, board)
        assert found.all()
        for b in range(len(gt)):
            assert (corners[b] - _convention(gt[b], cols, rows)).norm(dim=-1).max() < 1.5
            # rows of `cols` corners run (mostly) vertically in the image
            c = corners[b].reshape(rows, cols, 2)
            step = c[:, -1] - c[:, 0]
            assert (step[:, 1].abs() > step[:, 0].abs()).all()


def test_strong_perspective():
    gt, _ = _views(9, 6, 10, seed=11, tilt=(55.0, 62.0))
    pts, mask = _shuffle(gt, torch.Generator().manual_seed(3))
    corners, valid, found = organize_grid(pts, mask, (9, 6))
    assert found.all() and valid.all()
    for b in range(len(gt)):
        assert (corners[b] - _convention(gt[b], 9, 6)).norm(dim=-1).max() < 1.5


def test_barrel_distortion_residue():
    gt, _ = _views(11, 8, 8, seed=12, dist_coeffs=[-0.12, 0.02, 0.0, 0.0, 0.0])
    pts, mask = _shuffle(gt, torch.Generator().manual_seed(4))
    corners, valid, found = organize_grid(pts, mask, (11, 8))
    assert found.all() and valid.all()
    for b in range(len(gt)):
        assert (corners[b] - _convention(gt[b], 11, 8)).norm(dim=-1).max() < 1.5


@pytest.mark.parametrize("board", [(9, 6), (8, 6)])
def test_missing_corners(board):
    cols, rows = board
    gt, _ = _views(cols, rows, 12, seed=5)
    g = torch.Generator().manual_seed(5)
    pts, mask, kept = _corrupt(gt, g, missing=0.12)
    corners, valid, found = organize_grid(pts, mask, board)
    assert found.float().mean() >= 0.9
    for b in torch.nonzero(found)[:, 0].tolist():
        labellings = _labellings(gt[b], cols, rows)
        keeps = _labellings(kept[b].reshape(-1, 1).double(), cols, rows)
        k = min(range(len(labellings)), key=lambda i: float((corners[b] - labellings[i]).norm(dim=-1)[valid[b]].max()))
        assert (corners[b] - labellings[k]).norm(dim=-1)[valid[b]].max() < 1.5
        # exactly the detected corners are marked valid
        assert torch.equal(valid[b], keeps[k][:, 0].bool())
        # holes hold the board homography's prediction
        assert (corners[b] - labellings[k]).norm(dim=-1)[~valid[b]].max() < 3.0


@pytest.mark.parametrize("board", [(9, 6), (11, 8)])
def test_false_peaks(board):
    cols, rows = board
    gt, _ = _views(cols, rows, 12, seed=6)
    g = torch.Generator().manual_seed(6)
    pts, mask, _ = _corrupt(gt, g, extra=0.3)
    # a few false peaks exactly at square centres, the worst place for a lattice
    centres = gt[:, :1] * 0.5 + gt[:, cols + 1 : cols + 2] * 0.5
    pts = torch.cat([pts, centres], 1)
    mask = torch.cat([mask, torch.ones(len(gt), 1, dtype=torch.bool)], 1)
    corners, valid, found = organize_grid(pts, mask, board)
    assert found.all() and valid.all()
    for b in range(len(gt)):
        assert (corners[b] - _convention(gt[b], cols, rows)).norm(dim=-1).max() < 1.5


def test_missing_and_false_peaks_together():
    gt, _ = _views(9, 6, 30, seed=7)
    g = torch.Generator().manual_seed(7)
    pts, mask, _ = _corrupt(gt, g, missing=0.12, extra=0.3)
    corners, valid, found = organize_grid(pts, mask, (9, 6))
    assert found.float().mean() >= 0.85
    n_valid = n_bad = 0
    for b in torch.nonzero(found)[:, 0].tolist():
        labellings = _labellings(gt[b], 9, 6)
        err = min(((corners[b] - lab).norm(dim=-1)[valid[b]] for lab in labellings), key=lambda e: float(e.max()))
        # never a board shifted or relabelled by a square; at most a stray peak near a hole
        assert err.max() < 0.25 * (gt[b, 1] - gt[b, 0]).norm()
        n_valid += int(valid[b].sum())
        n_bad += int((err > 1.0).sum())
    assert n_bad <= 0.01 * n_valid


@pytest.mark.parametrize("asked", [(8, 6), (10, 6), (9, 5), (9, 7), (7, 5), (10, 7)])
def test_wrong_board_size_not_found(asked):
    gt, _ = _views(9, 6, 4, seed=8)
    pts, mask = _shuffle(gt, torch.Generator().manual_seed(8))
    _, valid, found = organize_grid(pts, mask, asked)
    assert not found.any() and not valid.any()


def test_transposed_pattern_size_is_the_same_board():
    gt, _ = _views(9, 6, 3, seed=9)
    pts, mask = _shuffle(gt, torch.Generator().manual_seed(9))
    corners, valid, found = organize_grid(pts, mask, (6, 9))
    assert found.all() and valid.all()
    for b in range(3):
        # as a 6x9 board, rows of 6 corners are the columns of the 9x6 ground truth
        gt69 = gt[b].reshape(6, 9, 2).transpose(0, 1).flip(1).reshape(-1, 2)
        assert (corners[b] - _convention(gt69, 6, 9)).norm(dim=-1).max() < 1.5


def test_sub_board_not_found():
    gt, _ = _views(9, 6, 3, seed=10)
    sub = gt.reshape(3, 6, 9, 2)[:, :, :7].reshape(3, -1, 2)  # the board runs out of the image
    pts, mask = _shuffle(sub, torch.Generator().manual_seed(10))
    assert not organize_grid(pts, mask, (9, 6))[2].any()
    assert organize_grid(pts, mask, (7, 6))[2].all()


def test_nothing_to_find():
    corners, valid, found = organize_grid(torch.zeros(2, 0, 2), torch.zeros(2, 0, dtype=torch.bool), (9, 6))
    assert corners.shape == (2, 54, 2) and not found.any() and not valid.any()
    gt, _ = _views(9, 6, 1, seed=0)
    assert not organize_grid(gt, torch.zeros(1, 54, dtype=torch.bool), (9, 6))[2].any()
    clutter = torch.rand(3, 80, 2, generator=torch.Generator().manual_seed(0)) * torch.tensor([W, H])
    assert not organize_grid(clutter, torch.ones(3, 80, dtype=torch.bool), (9, 6))[2].any()
    # padding values (nan) behind a False mask are ignored
    pts = torch.cat([gt, torch.full((1, 5, 2), float("nan"), dtype=F64)], 1)
    mask = torch.cat([torch.ones(1, 54, dtype=torch.bool), torch.zeros(1, 5, dtype=torch.bool)], 1)
    assert organize_grid(pts, mask, (9, 6))[2].all()


def test_batch_consistency():
    gt, _ = _views(9, 6, 4, seed=13)
    g = torch.Generator().manual_seed(13)
    pts, mask, _ = _corrupt(gt, g, missing=0.1, extra=0.2)
    pts[2], mask[2] = torch.rand(pts.shape[1], 2, dtype=F64) * 400, True  # one image without a board
    corners, valid, found = organize_grid(pts, mask, (9, 6))
    assert found.tolist() == [True, True, False, True]
    for b in range(4):
        c1, v1, f1 = organize_grid(pts[b : b + 1], mask[b : b + 1], (9, 6))
        assert torch.equal(c1[0], corners[b]) and torch.equal(v1[0], valid[b]) and bool(f1[0]) == bool(found[b])


def test_exceptions():
    pts, mask = torch.zeros(1, 5, 2), torch.ones(1, 5, dtype=torch.bool)
    with pytest.raises(ValueError):
        organize_grid(torch.zeros(5, 2), mask, (9, 6))
    with pytest.raises(ValueError):
        organize_grid(pts, torch.ones(1, 4, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        organize_grid(pts, mask, (1, 6))
    with pytest.raises(ValueError):
        organize_grid(pts, mask, (9, 6), image=torch.zeros(2, 1, 10, 10))
    with pytest.raises(ValueError):
        organize_grid(pts, mask, (9, 6), tolerance=0.7)
    with pytest.raises(ValueError):
        GridOrganizer((9,))


def _render(cols, rows, rvec, tvec, square_px=32):
    """Render a board whose outer square at corner 0 (object x, y in (-1, 0)) is black."""
    tex = np.full(((rows + 3) * square_px, (cols + 3) * square_px), 255, np.uint8)
    for qj in range(rows + 1):
        for qi in range(cols + 1):
            if (qi + qj) % 2 == 0:
                tex[(qj + 1) * square_px : (qj + 2) * square_px, (qi + 1) * square_px : (qi + 2) * square_px] = 0
    r = axis_angle_to_rotation_matrix(rvec[None])[0]
    h_obj = K @ torch.stack([r[:, 0], r[:, 1], tvec], 1)  # object plane (unit squares) -> image
    # texture pixel centre (u, v) <-> object ((u + 0.5) / s - 2, (v + 0.5) / s - 2)
    off = 0.5 / square_px - 2
    tex_to_obj = torch.tensor([[1 / square_px, 0, off], [0, 1 / square_px, off], [0, 0, 1]], dtype=F64)
    img = cv2.warpPerspective(tex, (h_obj @ tex_to_obj).numpy(), (W, H), flags=cv2.INTER_AREA, borderValue=200)
    return torch.from_numpy(img).to(torch.float32)[None, None] / 255.0


@pytest.mark.parametrize("board", [(9, 6), (4, 7)])
def test_image_resolves_180_degrees_for_non_symmetric_boards(board):
    cols, rows = board
    gt, poses = _views(cols, rows, 6, seed=14)
    image = torch.cat([_render(cols, rows, *pose) for pose in poses])
    pts, mask = _shuffle(gt, torch.Generator().manual_seed(14))
    corners, valid, found = organize_grid(pts, mask, board, image=image)
    assert found.all()
    # the exact ground-truth labelling, whatever the in-plane rotation
    assert (corners - gt).norm(dim=-1).max() < 1.5
    # and as OpenCV's classic detector orders it
    for b in range(len(gt)):
        ok, cv = cv2.findChessboardCorners((image[b, 0].numpy() * 255).astype(np.uint8), board)
        if ok:
            # (OpenCV's unrefined corners are only good to a couple of pixels; a wrong label is a square off)
            assert (corners[b] - torch.from_numpy(cv.reshape(-1, 2)).double()).norm(dim=-1).max() < 5.0


def test_organize_speed():
    gt, _ = _views(11, 8, 8, seed=15)
    pts, mask, _ = _corrupt(gt, torch.Generator().manual_seed(15), missing=0.05, extra=0.15)
    organize_grid(pts[:1], mask[:1], (11, 8))
    t0 = time.perf_counter()
    found = organize_grid(pts, mask, (11, 8))[2]
    per_image = (time.perf_counter() - t0) / len(gt)
    assert found.all()
    assert per_image < 0.1  # a few ms on an idle core; loose bound for shared CI machines


# ----------------------------------------------------------------------------------------------
# collinearity_refine
# ----------------------------------------------------------------------------------------------


def test_collinearity_exact_on_lines():
    gt, _ = _views(9, 6, 4, seed=20, tilt=(30.0, 60.0))
    valid = torch.ones(4, 54, dtype=torch.bool)
    valid[:, [0, 13, 40]] = False
    refined, ok = collinearity_refine(gt, valid, (9, 6))
    assert ok.all()
    assert (refined - gt).norm(dim=-1).max() < 1e-8


@pytest.mark.parametrize("board", [(9, 6), (11, 8)])
def test_collinearity_reduces_noise(board):
    cols, rows = board
    gt, _ = _views(cols, rows, 20, seed=21)
    g = torch.Generator().manual_seed(21)
    noisy = gt + 0.2 * torch.randn(gt.shape, generator=g, dtype=F64)
    valid = torch.ones(gt.shape[:2], dtype=torch.bool)
    before = (noisy - gt).norm(dim=-1).mean()
    for concurrent in (False, True):
        refined, ok = collinearity_refine(noisy, valid, board, concurrent=concurrent)
        after = (refined - gt).norm(dim=-1).mean()
        assert ok.all()
        assert after < 0.7 * before  # at least a 30 % reduction


def test_collinearity_recovers_missing_corners():
    gt, _ = _views(9, 6, 20, seed=22)
    g = torch.Generator().manual_seed(22)
    noisy = gt + 0.2 * torch.randn(gt.shape, generator=g, dtype=F64)
    valid = torch.rand(gt.shape[:2], generator=g) >= 0.15
    noisy = torch.where(valid[..., None], noisy, torch.full_like(noisy, float("nan")))  # holes hold garbage
    refined, ok = collinearity_refine(noisy, valid, (9, 6))
    grid_valid = valid.reshape(-1, 6, 9)
    lines_ok = (grid_valid.sum(2, keepdim=True) >= 3) & (grid_valid.sum(1, keepdim=True) >= 3)
    assert torch.equal(ok, valid | lines_ok.reshape(-1, 54))
    recovered = ok & ~valid
    assert recovered.sum() > 100 and torch.isfinite(refined[ok]).all()
    err = (refined - gt).norm(dim=-1)[recovered]
    assert err.mean() < 0.2 and err.max() < 0.8
    # the paper's independent lines recover them too, less steadily
    paper, _ = collinearity_refine(noisy, valid, (9, 6), concurrent=False)
    err_paper = (paper - gt).norm(dim=-1)[recovered]
    assert err.mean() < err_paper.mean() < 0.3


def test_collinearity_robust_to_one_bad_corner():
    gt, _ = _views(9, 6, 6, seed=23)
    g = torch.Generator().manual_seed(23)
    noisy = gt + 0.1 * torch.randn(gt.shape, generator=g, dtype=F64)
    noisy[:, 22] += torch.tensor([3.0, -3.0], dtype=F64)  # one corner badly off
    valid = torch.ones(gt.shape[:2], dtype=torch.bool)
    others = torch.ones(54, dtype=torch.bool)
    others[22] = False
    plain = (collinearity_refine(noisy, valid, (9, 6), iterations=1)[0] - gt).norm(dim=-1)[:, others].mean()
    robust = (collinearity_refine(noisy, valid, (9, 6), iterations=3)[0] - gt).norm(dim=-1)[:, others].mean()
    assert robust < 0.6 * plain


def test_collinearity_undefined_lines_and_blend():
    gt, _ = _views(5, 5, 1, seed=24)
    valid = torch.ones(1, 25, dtype=torch.bool)
    valid[0, 5:10] = False  # row 1 empty: its corners cannot be recovered
    valid[0, 0] = False  # column 0 keeps 3 corners: recoverable
    noisy = gt + 0.3
    refined, ok = collinearity_refine(noisy, valid, (5, 5), min_points=3)
    assert not ok[0, 5:10].any() and ok[0, 0] and ok[0, 10:].all()
    assert torch.equal(refined[0, 5:10], noisy[0, 5:10])  # untouched
    assert not collinearity_refine(noisy, valid, (5, 5), min_points=4)[1][0, 0]
    kept, _ = collinearity_refine(noisy, valid, (5, 5), blend=0.0)
    assert torch.allclose(kept[0, valid[0]], noisy[0, valid[0]])
    assert torch.allclose(kept[0, 0], refined[0, 0])  # missing corners always take the intersection


def test_collinearity_batch_and_module():
    gt, _ = _views(8, 6, 3, seed=25)
    noisy = gt + 0.2 * torch.randn(gt.shape, generator=torch.Generator().manual_seed(25), dtype=F64)
    valid = torch.rand(gt.shape[:2], generator=torch.Generator().manual_seed(26)) > 0.1
    refiner = CollinearityRefiner((8, 6))
    batch, ok = refiner(noisy, valid)
    for b in range(3):
        one, ok1 = refiner(noisy[b : b + 1], valid[b : b + 1])
        assert torch.allclose(one[0], batch[b], atol=1e-10) and torch.equal(ok1[0], ok[b])
    assert "board_size=(8, 6)" in repr(refiner)


def test_collinearity_gradcheck():
    gt, _ = _views(4, 3, 1, seed=27)
    noisy = (gt + 0.2 * torch.randn(gt.shape, generator=torch.Generator().manual_seed(27), dtype=F64)).requires_grad_()
    valid = torch.ones(1, 12, dtype=torch.bool)
    valid[0, 5] = False
    for concurrent in (False, True):
        fn = lambda c: collinearity_refine(c, valid, (4, 3), iterations=2, concurrent=concurrent)[0]  # noqa: E731
        assert torch.autograd.gradcheck(fn, (noisy,))


def test_collinearity_exceptions():
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 53, 2), torch.ones(1, 53, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(54, 2), torch.ones(54, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 54, 2), torch.ones(1, 53, dtype=torch.bool), (9, 6))
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 54, 2), torch.ones(1, 54, dtype=torch.bool), (9, 6), min_points=1)
    with pytest.raises(ValueError):
        collinearity_refine(torch.zeros(1, 54, 2), torch.ones(1, 54, dtype=torch.bool), (9, 6), blend=2.0)
