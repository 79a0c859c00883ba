"""Tests of the radial correction of points and images (paper Sec. III-A)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.render.renderer import render_chessboard
from ccs_kornia.data.scenes.sampling import sample_radial_distortion
from ccs_kornia.geometry.radial import fit_radial_correction, radial_correct_points
from ccs_kornia.modules.correction.radial_warp import (
    RadialUndistort,
    correct_points,
    corrected_radius,
    correction_zoom,
    distort_points_from_correction,
    invert_correction_radius,
    radial_undistort_image,
)
from ccs_kornia.modules.correction.straightness import straightness_rms

IDENTITY = torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]])


def _random_points(b, n, size, gen, dtype=torch.float64):
    w, h = size
    return torch.rand(b, n, 2, generator=gen, dtype=dtype) * torch.tensor([w - 1.0, h - 1.0], dtype=dtype)


def test_correct_points_is_camera_model():
    gen = torch.Generator().manual_seed(0)
    p = _random_points(3, 20, (640, 480), gen)
    c = torch.tensor([[1.0, 0.1, 0.3, -0.2, 0.1]], dtype=torch.float64).repeat(3, 1)
    torch.testing.assert_close(correct_points(p, c, (640, 480)), radial_correct_points(p, c, (640, 480)))
    # zoom scales about the image centre
    centre = torch.tensor([319.5, 239.5], dtype=torch.float64)
    z = correct_points(p, c, (640, 480), zoom=0.8)
    torch.testing.assert_close(z - centre, 0.8 * (radial_correct_points(p, c, (640, 480)) - centre))


@pytest.mark.parametrize("level", ["level1", "level2", "severe"])
def test_round_trip_points(level, device, dtype):
    size = (640, 480)
    gen = torch.Generator().manual_seed(1)
    k = sample_radial_distortion(16, level, size, gen).double()
    c = fit_radial_correction(k, size).to(device, dtype)
    p = _random_points(16, 400, size, gen, dtype).to(device)
    for zoom in (1.0, 0.7):
        q = correct_points(p, c, size, zoom)
        back, valid = distort_points_from_correction(q, c, size, zoom=zoom, return_valid=True)
        assert valid.float().mean() > 0.99  # fitted level2 corrections may fold at the very corners
        err = (back - p).norm(dim=-1)[valid]
        assert err.max() < 1e-3, float(err.max())


def test_round_trip_other_direction_and_centre():
    size = (64, 48)
    c = torch.tensor([[1.1, -0.05, 0.4, 0.1, 0.2]], dtype=torch.float64)
    q = torch.tensor([[[31.5, 23.5], [0.0, 0.0], [63.0, 47.0], [40.0, 10.0]]], dtype=torch.float64)
    p = distort_points_from_correction(q, c, size)
    torch.testing.assert_close(correct_points(p, c, size), q, atol=1e-9, rtol=0)
    torch.testing.assert_close(p[0, 0], q[0, 0])  # the centre is fixed


def test_invert_radius_marks_fold():
    # g(r) = r (1 - 2 r^2) stops increasing at r = 1/sqrt(6) (g = 0.272): larger radii have no preimage
    c = torch.tensor([[1.0, 0.0, -2.0, 0.0, 0.0]])
    rc = torch.tensor([[0.0, 0.1, 0.25, 0.3, 0.6]])
    rd, valid = invert_correction_radius(rc, c)
    assert valid.tolist() == [[True, True, True, False, False]]
    assert torch.isfinite(rd).all()
    g = rd * (1 - 2 * rd**2)
    torch.testing.assert_close(g[valid], rc[valid], atol=1e-6, rtol=0)


def test_points_gradcheck():
    size = (32, 24)
    c = torch.tensor([[1.05, -0.1, 0.4, 0.0, 0.3]], dtype=torch.float64, requires_grad=True)
    q = torch.tensor([[[3.0, 4.0], [20.0, 17.0], [29.0, 2.0]]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: distort_points_from_correction(a, b, size), (q, c))


def test_identity_warp_and_shapes(device, dtype):
    img = torch.rand(3, 2, 20, 30, device=device, dtype=dtype)
    out = radial_undistort_image(img, IDENTITY.repeat(3, 1).to(device, dtype))
    assert out.device.type == device.type and out.dtype == dtype
    img, out = img.cpu(), out.cpu()
    assert out.shape == img.shape
    torch.testing.assert_close(out, img, atol=1e-5, rtol=0)
    shared, mask = radial_undistort_image(img, torch.tensor([[1.0, 0.0, 0.5, 0.0, 0.0]]), return_mask=True)
    assert shared.shape == img.shape and mask.shape == (3, 1, 20, 30) and mask.dtype == torch.bool
    single = radial_undistort_image(img[1:2], torch.tensor([[1.0, 0.0, 0.5, 0.0, 0.0]]))
    torch.testing.assert_close(shared[1:2], single)


def test_warp_samples_at_inverse_points():
    # a barrel-correcting warp samples the input at distort_points_from_correction of each output pixel
    size = (40, 30)
    c = torch.tensor([[1.0, 0.0, 0.6, 0.0, 0.0]], dtype=torch.float64)
    yy, xx = torch.meshgrid(torch.arange(30.0), torch.arange(40.0), indexing="ij")
    ramp = (xx + 100 * yy).to(torch.float64)[None, None]  # bilinear sampling of a linear image is exact
    out, mask = radial_undistort_image(ramp, c, return_mask=True)
    grid = torch.stack([xx, yy], -1).reshape(1, -1, 2).to(torch.float64)
    src = distort_points_from_correction(grid, c, size)
    expected = (src[..., 0] + 100 * src[..., 1]).reshape(1, 1, 30, 40)
    m = mask & (src[..., 0] <= 39).reshape(1, 1, 30, 40) & (src[..., 1] <= 29).reshape(1, 1, 30, 40)
    assert m.float().mean() > 0.5
    torch.testing.assert_close(out[m], expected[m], atol=1e-6, rtol=0)


@pytest.mark.parametrize("h, w", [(30, 40), (31, 41), (7, 8)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_warp_inverts_one_quadrant_and_gives_every_pixel_the_same_source(h, w, dtype):
    """The warp's Newton runs on a quarter of the pixels (the radius is mirror-symmetric about the centre): the
    sources and the mask are those of ``distort_points_from_correction`` on every pixel, bit for bit."""
    from ccs_kornia.modules.correction.radial_warp import _pixel_sources

    c = torch.tensor([[1.0045, -0.1086, 1.0559, -2.3121, 2.5975], [1.0, 0.0, -3.0, 0.0, 0.0]], dtype=dtype)
    yy, xx = torch.meshgrid(torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij")
    grid = torch.stack([xx, yy], -1).reshape(1, -1, 2).expand(2, -1, -1)
    for zoom in (1.0, 0.8):
        src, valid = _pixel_sources(h, w, c, zoom, 10, dtype, torch.device("cpu"))
        ref, ref_valid = distort_points_from_correction(grid, c, (w, h), zoom=zoom, return_valid=True)
        assert torch.equal(src, ref) and torch.equal(valid, ref_valid) and not bool(valid[1].all())


def test_fold_gives_zeros_not_nans():
    img = torch.ones(1, 1, 24, 32)
    c = torch.tensor([[1.0, 0.0, -3.0, 0.0, 0.0]])
    out, mask = radial_undistort_image(img, c, return_mask=True)
    assert torch.isfinite(out).all()
    assert (~mask).any() and mask.any()
    assert float(out[~mask].abs().max()) == 0.0


def test_warp_gradcheck_wrt_coefficients():
    yy, xx = torch.meshgrid(torch.arange(9.0), torch.arange(12.0), indexing="ij")
    img = (torch.sin(0.7 * xx) * torch.cos(0.5 * yy)).to(torch.float64)[None, None]
    c = torch.tensor([[1.0, 0.02, 0.3, -0.1, 0.05]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda k: radial_undistort_image(img, k), (c,), eps=1e-6, atol=1e-5)


def test_module_matches_function():
    img = torch.rand(2, 1, 24, 32)
    c = torch.tensor([[1.0, 0.0, 0.3, 0.0, 0.0], [0.95, 0.1, 0.0, 0.2, 0.0]])
    warp = RadialUndistort(zoom=0.9)
    torch.testing.assert_close(warp(img, c), radial_undistort_image(img, c, zoom=0.9))
    p = torch.tensor([[[3.0, 5.0]], [[30.0, 20.0]]])
    back = warp.distort_points(warp.correct_points(p, c, (32, 24)), c, (32, 24))
    torch.testing.assert_close(back, p, atol=1e-3, rtol=0)
    assert "zoom=0.9" in repr(warp)


def test_exceptions():
    with pytest.raises(ValueError, match="correction"):
        radial_undistort_image(torch.rand(1, 1, 8, 8), torch.ones(1, 3))
    with pytest.raises(ValueError, match=r"correction must be \(1, 5\) or \(B, 5\) .* with B=3, got \(2, 5\)"):
        radial_undistort_image(torch.rand(3, 1, 8, 8), torch.ones(2, 5))
    with pytest.raises(ValueError, match="images"):
        radial_undistort_image(torch.rand(8, 8), torch.ones(1, 5))
    with pytest.raises(ValueError, match="points"):
        correct_points(torch.rand(4, 2), torch.ones(1, 5), (8, 8))
    with pytest.raises(ValueError, match="zoom"):
        RadialUndistort(zoom=0.0)
    with pytest.raises(ValueError, match="zoom"):
        distort_points_from_correction(torch.rand(1, 4, 2), IDENTITY, (8, 8), zoom=-1.0)


def _detect(image: torch.Tensor, board: tuple[int, int]) -> torch.Tensor:
    u8 = (image[0, 0].clamp(0, 1).numpy() * 255).round().astype(np.uint8)
    found, corners = cv2.findChessboardCorners(u8, board)
    assert found
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(u8, corners, (5, 5), (-1, -1), crit)
    return torch.from_numpy(corners.reshape(1, -1, 2)).double()


def test_undistorting_a_rendered_board_straightens_it():
    size, board = (480, 360), (9, 6)
    K = torch.tensor([[400.0, 0, 239.5], [0, 400, 179.5], [0, 0, 1]])
    rvec, tvec = torch.tensor([[0.1, -0.15, 0.03]]), torch.tensor([[-0.2, -0.125, 0.48]])
    k = torch.tensor([[1.0, -0.3, -0.08]])  # the paper's level1 range
    distorted, _ = render_chessboard(K, rvec, tvec, board, 0.05, size, radial=k, supersample=2, background=0.5)
    ideal, _ = render_chessboard(K, rvec, tvec, board, 0.05, size, supersample=2, background=0.5)
    correction = fit_radial_correction(k.double(), size).float()
    corrected, mask = radial_undistort_image(distorted, correction, return_mask=True)
    ones = torch.ones(1, board[0] * board[1], dtype=torch.bool)
    before, _ = straightness_rms(_detect(distorted, board), ones, board)
    after, _ = straightness_rms(_detect(corrected, board), ones, board)
    assert float(before) > 0.4
    assert float(after) < 0.2 * float(before), (float(before), float(after))
    # photometrically the corrected image is the ideal render (up to resampling blur)
    err_before = (distorted - ideal).abs().mean()
    err_after = ((corrected - ideal).abs() * mask).sum() / mask.sum()
    assert err_after < 0.1 * err_before


def test_correction_zoom_keeps_the_farthest_corner_in_the_frame(device):
    size = (640, 480)
    identity = torch.tensor([[1.0, 0.0, 0.0, 0.0, 0.0]], device=device)
    assert float(correction_zoom(identity, size)) == 1.0
    barrel = torch.tensor([[1.0, 0.0, 0.3, 0.0, 0.0], [1.0, 0.0, 0.1, 0.0, 0.0]], device=device)
    zoom = float(correction_zoom(barrel, size))
    r = 0.5 * (639**2 + 479**2) ** 0.5 / 640
    # the strongest correction sets the zoom: its corrected corner radius, zoomed, is the original one
    g = float(corrected_radius(torch.tensor([[r]], dtype=torch.float64), barrel[:1].cpu().double()))
    assert 0.5 <= zoom < 1.0 and abs(zoom * g - r) < 1e-6
