"""Banded separable resizes (ccs_kornia/modules/_resize.py)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from ccs_kornia.modules._resize import area_matrix, area_resize, banded_product, halve


@pytest.mark.parametrize("size", [(480, 640, 285, 381), (96, 128, 87, 116), (50, 70, 25, 35), (64, 48, 63, 47)])
def test_area_resize_equals_torch_area_interpolation(size):
    h, w, oh, ow = size
    x = torch.rand(3, 2, h, w, generator=torch.Generator().manual_seed(0))
    got = area_resize(x, (oh, ow))
    assert got.shape == (3, 2, oh, ow) and got.is_contiguous()
    torch.testing.assert_close(got, F.interpolate(x, size=(oh, ow), mode="area"), rtol=0, atol=1e-6)


def test_area_resize_same_size_and_large_factors_and_upscaling_fall_back():
    x = torch.rand(1, 1, 120, 160)
    assert area_resize(x, (120, 160)) is x
    for size in ((20, 30), (240, 320)):  # torch's own: a large factor, and upsampling
        torch.testing.assert_close(area_resize(x, size), F.interpolate(x, size=size, mode="area"), rtol=0, atol=0)


def test_area_resize_of_a_large_image_is_torchs_own(monkeypatch):
    """Above BANDED_MAX_PIXELS the resize is torch's area interpolation itself (the banded blocks and the dense
    matrices grow with the image: 1 s and 0.4 s per new size on a 27 Mpx photograph), below it the banded products."""
    from ccs_kornia.modules import _resize

    x = torch.rand(1, 1, 60, 80)
    calls = []
    monkeypatch.setattr(_resize, "separable_product",
                        lambda *a: calls.append(1) or F.interpolate(x, (41, 55), mode="area"))
    area_resize(x, (41, 55))
    assert calls == [1]
    monkeypatch.setattr(_resize, "BANDED_MAX_PIXELS", 60 * 80 - 1)
    torch.testing.assert_close(area_resize(x, (41, 55)), F.interpolate(x, size=(41, 55), mode="area"), rtol=0, atol=0)
    assert calls == [1]


def test_area_resize_float64_and_exceptions():
    x = torch.rand(2, 1, 30, 40, dtype=torch.float64)
    got = area_resize(x, (21, 29))
    assert got.dtype == torch.float64
    torch.testing.assert_close(got, F.interpolate(x, size=(21, 29), mode="area"))
    with pytest.raises(ValueError, match=r"\(B, C, H, W\)"):
        area_resize(torch.rand(30, 40), (10, 10))


def test_area_matrix_rows_are_means_over_adaptive_pooling_footprints():
    m = area_matrix(10, 4)
    assert m.shape == (4, 10)
    torch.testing.assert_close(m.sum(1), torch.ones(4))
    # adaptive pooling's footprints: [0, 3), [2, 5), [5, 8), [7, 10)
    assert (m > 0).nonzero()[:, 1].tolist() == [0, 1, 2, 2, 3, 4, 5, 6, 7, 7, 8, 9]


def test_banded_product_equals_the_dense_product():
    m = area_matrix(200, 70)
    x = torch.rand(3, 200, 5)
    torch.testing.assert_close(banded_product(m, x, block=8), m @ x)


@pytest.mark.parametrize("shape", [(2, 1, 480, 640), (1, 1, 481, 643), (3, 2, 150, 200), (1, 1, 9, 7)])
def test_halve_equals_avg_pool_and_area_resize_uses_it(shape):
    x = torch.rand(shape, generator=torch.Generator().manual_seed(2))
    assert torch.equal(halve(x), F.avg_pool2d(x, 2))
    if shape[-2] % 2 == 0 and shape[-1] % 2 == 0:
        half = (shape[-2] // 2, shape[-1] // 2)
        assert torch.equal(area_resize(x, half), F.interpolate(x, size=half, mode="area"))
