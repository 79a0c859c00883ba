"""Marks in the light squares, optics scaled to the square, banded (memory-bounded) rendering."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.data.render.marks import MARK_KINDS, make_marks
from ccs_kornia.data.render.optics import (
    apply_optics,
    blur_kernel,
    convolve,
    scaled_blur,
    square_size_px,
)
from ccs_kornia.data.render.renderer import render_chessboard

K = torch.tensor([[400.0, 0.0, 159.5], [0.0, 400.0, 119.5], [0.0, 0.0, 1.0]])
RV, TV = torch.tensor([[0.2, -0.15, 0.1]]), torch.tensor([[-0.07, -0.05, 0.6]])




@pytest.mark.parametrize("kind", ["aruco", "dots", "tiles"])
def test_marks_do_not_move_the_ground_truth_or_the_corners_neighbourhood(kind):
    marks = make_marks(torch.tensor([MARK_KINDS.index(kind)]), torch.tensor([6]), torch.tensor([4]),
                       torch.Generator().manual_seed(0), fill=0.8 if kind == "aruco" else 0.4)
    plain, c0 = render_chessboard(K, RV, TV, (6, 4), 0.02, (320, 240), background=0.5)
    marked, c1 = render_chessboard(K, RV, TV, (6, 4), 0.02, (320, 240), background=0.5, marks=marks)
    assert torch.equal(c0, c1)
    diff = (plain - marked)[0, 0]
    assert float(diff.abs().max()) > 0.3  # the marks are there
    # within a tenth of a square (~1.3 px here) of every corner the image is untouched
    ys, xs = torch.meshgrid(torch.arange(240.0), torch.arange(320.0), indexing="ij")
    d = ((xs[None] - c0[0, :, 0, None, None]) ** 2 + (ys[None] - c0[0, :, 1, None, None]) ** 2).sqrt().amin(0)
    assert float(diff[d < 1.0].abs().max()) < 1e-6
    # ink only darkens light squares
    assert float(diff.min()) > -1e-6


def test_mark_coverage_is_the_exact_box_integral():
    marks = make_marks(torch.tensor([1]), torch.tensor([4]), torch.tensor([3]), torch.Generator().manual_seed(1), fill=0.67)
    g = torch.Generator().manual_seed(2)
    u = torch.rand(1, 1, 50, generator=g) * 4 - 0.5
    v = torch.rand(1, 1, 50, generator=g) * 3 - 0.5
    w = torch.rand(1, 1, 50, generator=g) * 0.6 + 0.02
    cov = marks.coverage(u, v, w, w)
    # brute force: mean of the raster over a fine grid of points inside each box
    res = marks.res
    raster = marks.sat[0].diff(dim=0).diff(dim=1)
    t = (torch.arange(200, dtype=torch.float64) + 0.5) / 200 - 0.5
    for k in range(0, 50, 7):
        x = ((u[0, 0, k].double() + t[:, None] * w[0, 0, k] + 1) * res).floor().long().clamp(0, raster.shape[1] - 1)
        y = ((v[0, 0, k].double() + t[None, :] * w[0, 0, k] + 1) * res).floor().long().clamp(0, raster.shape[0] - 1)
        brute = raster[y.expand(200, 200), x.expand(200, 200)].mean()
        assert float(cov[0, 0, k]) == pytest.approx(float(brute), abs=0.01)


def test_blur_width_scales_with_the_square_size():
    def edge_width(square_px: float, kind: str) -> float:
        img = torch.zeros(1, 1, 64, 800)
        img[..., 400:] = 1.0
        out, width = scaled_blur(img, torch.tensor([square_px]), kind, 0.2, torch.Generator().manual_seed(0))
        assert float(width[0]) == pytest.approx(0.2 * square_px)
        row = out[0, 0, 32]
        return float(((row > 0.1) & (row < 0.9)).sum())

    for kind in ("box", "gaussian", "motion"):
        small, large = edge_width(40.0, kind), edge_width(200.0, kind)
        assert large / small == pytest.approx(5.0, rel=0.25)


def test_separable_and_fft_convolutions_agree_with_conv2d():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(1, 1, 70, 90, generator=g)
    for kern in (blur_kernel("gaussian", 3.0), blur_kernel("box", 41.0), blur_kernel("motion", 30.0, 0.7)):
        out = convolve(img, [kern])
        ph, pw = kern.shape[0] // 2, kern.shape[1] // 2
        mode = "reflect" if ph < 70 and pw < 90 else "replicate"
        ref = torch.nn.functional.conv2d(torch.nn.functional.pad(img, (pw, pw, ph, ph), mode=mode), kern.flip(0, 1)[None, None])
        assert float((out - ref).abs().max()) < 1e-4
        assert float(kern.sum()) == pytest.approx(1.0, abs=1e-5)


def test_square_size_px():
    i, j = torch.meshgrid(torch.arange(5.0), torch.arange(4.0), indexing="xy")
    corners = torch.stack([10 + 12 * i, 20 + 12 * j], -1).reshape(1, -1, 2)
    valid = torch.ones(1, 20, dtype=torch.bool)
    assert float(square_size_px(corners, valid, torch.tensor([[5, 4]]))[0]) == pytest.approx(12.0)


def test_optics_chain_is_seeded_and_in_range():
    img = torch.rand(2, 1, 60, 80, generator=torch.Generator().manual_seed(0))
    kw = dict(square_px=torch.tensor([20.0, 40.0]), board_centre=torch.tensor([[40.0, 30.0]] * 2),
              board_size_px=torch.tensor([50.0, 50.0]), blur=("box", "motion"), glare_prob=1.0, shadow_prob=1.0,
              noise_sigma=(0.01, 0.02), jpeg_quality=(20, 40))
    a = apply_optics(img, torch.Generator().manual_seed(5), **kw)
    b = apply_optics(img, torch.Generator().manual_seed(5), **kw)
    assert torch.equal(a, b) and float(a.min()) >= 0 and float(a.max()) <= 1
    assert float((a == 1.0).float().mean()) > 0  # the glare saturates


def test_banded_render_equals_one_piece():
    K2 = torch.tensor([[300.0, 0.0, 199.5], [0.0, 300.0, 149.5], [0.0, 0.0, 1.0]])
    dist = torch.tensor([-0.3, 0.1, 0.001, -0.001, 0.0])
    bg = torch.rand(1, 1, 300, 400, generator=torch.Generator().manual_seed(0))
    whole, c0 = render_chessboard(K2, RV, TV, (6, 4), 0.02, (400, 300), dist=dist, background=bg)
    banded, c1 = render_chessboard(K2, RV, TV, (6, 4), 0.02, (400, 300), dist=dist, background=bg,
                                   max_band_pixels=400 * 7)
    assert torch.equal(c0, c1)
    # the OpenCV inverse starts from a coarse grid per band: Newton lands within ~1e-6 px, which moves the warped
    # random background by < 1e-3 grey levels (a quarter of an 8-bit step)
    assert float((whole - banded).abs().max()) < 1e-3
    plain_whole, _ = render_chessboard(K2, RV, TV, (6, 4), 0.02, (400, 300), background=0.5)
    plain_banded, _ = render_chessboard(K2, RV, TV, (6, 4), 0.02, (400, 300), background=0.5, max_band_pixels=400 * 7)
    assert torch.equal(plain_whole, plain_banded)


@pytest.mark.slow
def test_big_render_is_memory_bounded():
    """A 6000x4000 render (24 Mpx) grows the peak resident set by far less than rendering it in one piece would."""
    from ccs_kornia.bench.sections.wild import PeakMemory

    K3 = torch.tensor([[5000.0, 0.0, 2999.5], [0.0, 5000.0, 1999.5], [0.0, 0.0, 1.0]])
    with PeakMemory() as mem:
        img, _ = render_chessboard(K3, RV, torch.tensor([[-0.1, -0.07, 0.6]]), (9, 6), 0.025, (6000, 4000), supersample=2)
    assert img.shape == (1, 1, 4000, 6000)
    if math.isfinite(mem.mb):
        assert mem.mb < 800  # the output alone is 92 MiB; one piece would need ~3 GB
