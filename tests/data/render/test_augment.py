from __future__ import annotations

import pytest
import torch

from ccs_kornia.data.render import augment
from ccs_kornia.data.render.augment import (
    CONDITIONS,
    ApplyCondition,
    add_noise,
    apply_condition,
    gamma,
    gaussian_blur,
    jpeg,
    phong_lighting,
    textured_background,
    vignetting,
)


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _board(b=3, h=48, w=64):
    """Small checker pattern with values in [0.1, 0.9]."""
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    pattern = (((xs // 8) + (ys // 8)) % 2).float() * 0.8 + 0.1
    return pattern.expand(b, 1, h, w).clone()


EFFECTS = [
    ("blur", lambda x, g: gaussian_blur(x, g)),
    ("noise", lambda x, g: add_noise(x, g)),
    ("phong", lambda x, g: phong_lighting(x, g)),
    ("vignetting", lambda x, g: vignetting(x, g)),
    ("gamma", lambda x, g: gamma(x, g)),
    ("jpeg", lambda x, g: jpeg(x, g)),
] + [(c, lambda x, g, c=c: apply_condition(x, c, g)) for c in CONDITIONS]


@pytest.mark.parametrize("name,fn", EFFECTS, ids=[e[0] for e in EFFECTS])
def test_effects_shape_range_determinism(name, fn):
    x = _board()
    y = fn(x, _gen(1))
    assert y.shape == x.shape and y.dtype == x.dtype
    assert float(y.min()) >= 0.0 and float(y.max()) <= 1.0
    assert torch.equal(y, fn(x, _gen(1)))
    if name != "clean":
        assert not torch.equal(y, x)
        # the input is left untouched
        assert torch.equal(x, _board())
    else:
        assert torch.equal(y, x)


@pytest.mark.parametrize("name,fn", EFFECTS, ids=[e[0] for e in EFFECTS])
def test_effects_keep_range_on_extremes(name, fn):
    x = torch.cat([torch.zeros(1, 1, 32, 32), torch.ones(1, 1, 32, 32)])
    y = fn(x, _gen(2))
    assert float(y.min()) >= 0.0 and float(y.max()) <= 1.0 and bool(torch.isfinite(y).all())


def test_effects_reject_bad_shapes():
    bad = torch.rand(2, 3, 16, 16)
    for fn in (gaussian_blur, add_noise, phong_lighting, vignetting, gamma, jpeg):
        with pytest.raises(ValueError):
            fn(bad, _gen())
    with pytest.raises(ValueError):
        apply_condition(torch.rand(2, 1, 16, 16), "foggy", _gen())
    with pytest.raises(ValueError):
        ApplyCondition("foggy")
    with pytest.raises(ValueError):
        gaussian_blur(torch.rand(1, 1, 16, 16), _gen(), sigma=1.0, kernel_size=4)


def test_conditions_tuple():
    assert CONDITIONS == ("clean", "blur_noise", "bad_lighting", "combined")


def test_blur_smooths_and_keeps_mean():
    x = _board()
    y = gaussian_blur(x, _gen(), sigma=1.5, kernel_size=3)
    # a 3x3 Gaussian with sigma 1.5 spreads a step over 3 pixels: the edge pixel moves to the middle
    assert 0.3 < float(y[0, 0, 4, 7]) < 0.7 and abs(float(y[0, 0, 4, 3]) - 0.1) < 1e-5
    assert abs(float(y.mean()) - float(x.mean())) < 0.01
    const = torch.full((2, 1, 16, 16), 0.3)
    assert torch.allclose(gaussian_blur(const, _gen()), const, atol=1e-6)


def test_noise_levels():
    x = torch.full((4, 1, 64, 64), 0.5)
    y = add_noise(x, _gen(), sigma=0.02, shot=0.0)
    assert abs(float((y - x).std()) - 0.02) < 0.002
    y = add_noise(x, _gen(), sigma=0.0, shot=0.002)  # variance = shot * I
    assert abs(float((y - x).std()) - (0.002 * 0.5) ** 0.5) < 0.003
    dark = add_noise(torch.full((1, 1, 64, 64), 0.05), _gen(), sigma=0.0, shot=0.002)
    assert float((dark - 0.05).std()) < float((y - x).std())  # shot noise grows with the signal
    assert abs(float(add_noise(x, _gen()).mean()) - 0.5) < 0.01


def test_phong_lighting_shading_and_highlight():
    x = torch.full((8, 1, 48, 64), 0.5)
    y = phong_lighting(x, _gen(3))
    # strong shading: every image has a spatial gradient
    spread = y.amax(dim=(2, 3)) - y.amin(dim=(2, 3))
    assert bool((spread > 0.05).all())
    # a specular highlight can push bright areas above the lit diffuse level
    y = phong_lighting(x, _gen(3), specular=0.8, shininess=10.0, shading=0.0, brightness=1.0)
    assert float(y.max()) > 0.75


def test_vignetting_darkens_corners():
    x = torch.full((2, 1, 48, 64), 0.8)
    y = vignetting(x, _gen(), strength=0.5, power=2.0, centre_jitter=0.0)
    assert float(y[0, 0, 24, 32]) > float(y[0, 0, 0, 0]) + 0.3
    assert abs(float(y[0, 0, 0, 0]) - 0.8 * 0.5) < 0.02


def test_gamma_monotone_with_fixed_ends():
    x = torch.linspace(0, 1, 101).view(1, 1, 1, 101).expand(3, 1, 4, 101).contiguous()
    y = gamma(x, _gen(), value=(0.5, 2.0))
    assert bool((y[..., 1:] >= y[..., :-1]).all())
    assert torch.allclose(y[..., 0], torch.zeros(3, 1, 4)) and torch.allclose(y[..., -1], torch.ones(3, 1, 4))


def test_jpeg_quantises_and_stays_close():
    x = _board()
    y = jpeg(x, _gen(), quality=(60, 90))
    assert float((y - x).abs().mean()) < 0.03
    assert torch.allclose(y * 255, (y * 255).round(), atol=1e-4)
    low = jpeg(x, _gen(), quality=10)
    assert float((low - x).abs().mean()) > float((y - x).abs().mean())


def test_textured_background():
    bg = textured_background(4, (96, 64), _gen(5))
    assert bg.shape == (4, 1, 64, 96) and float(bg.min()) >= 0 and float(bg.max()) <= 1
    assert torch.equal(bg, textured_background(4, (96, 64), _gen(5)))
    assert not torch.equal(bg, textured_background(4, (96, 64), _gen(6)))
    # clutter: every background has structure, and they differ from one another
    assert bool((bg.std(dim=(2, 3)) > 0.01).all())
    assert float((bg[0] - bg[1]).abs().mean()) > 0.02
    # straight edges: strong horizontal or vertical steps exist somewhere in the batch
    assert float((bg[..., 1:] - bg[..., :-1]).abs().max()) > 0.3
    with pytest.raises(ValueError):
        textured_background(0, (96, 64), _gen())


def test_apply_condition_module_and_degradation_strength():
    x = _board(b=4)
    blurred = ApplyCondition("blur_noise")(x, _gen(7))
    lit = apply_condition(x, "bad_lighting", _gen(7))
    combined = apply_condition(x, "combined", _gen(7))
    for y in (blurred, lit, combined):
        assert float((y - x).abs().mean()) > 0.01
    # combined stacks the others: it departs from the clean image at least as much as blur+noise
    assert float((combined - x).abs().mean()) > float((blurred - x).abs().mean())


def test_random_numbers_follow_the_generator_device():
    """Parameters are drawn on the generator's device, so a CPU generator fixes results on any device."""
    x = _board(b=2)
    g = _gen(8)
    a = augment.add_noise(x, g)
    b = augment.add_noise(x, _gen(8))
    assert torch.equal(a, b)
