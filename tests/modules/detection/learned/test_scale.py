"""Scale selection of the learned detector (ccs_kornia/modules/detection/learned/scale.py)."""

from __future__ import annotations

import doctest

import pytest
import torch
import torch.nn.functional as F

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.learned import scale as scale_module
from ccs_kornia.modules.detection.learned.scale import (
    ScaleSelector,
    detect_at_scale,
    detection_factor,
    estimate_square_size,
    saddle_scale_response,
)
from ccs_kornia.modules.detection.refine import patch_refine as patch_refine_module
from ccs_kornia.modules.detection.refine.patch_refine import (
    edge_blur,
    refine_from_level,
    refine_on_patches,
    resize_to_level,
)

K = torch.tensor([[800.0, 0, 319.5], [0, 800, 239.5], [0, 0, 1]])


@pytest.fixture(scope="module")
def views():
    return make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=2, seed=3, supersample=2)


def _square(corners: torch.Tensor, board=(9, 6)) -> torch.Tensor:
    g = corners.reshape(corners.shape[0], board[1], board[0], 2)
    d = torch.cat([(g[:, :, 1:] - g[:, :, :-1]).norm(dim=-1).flatten(1), (g[:, 1:] - g[:, :-1]).norm(dim=-1).flatten(1)], 1)
    return d.median(1).values


def _upscaled(views, factor: float, blur: int = 0):
    big = F.interpolate(views.images, scale_factor=factor, mode="bilinear", align_corners=False)
    if blur > 1:
        big = F.avg_pool2d(F.pad(big, (blur // 2,) * 4, mode="replicate"), blur, stride=1)
    return big, (views.corners + 0.5) * factor - 0.5


@pytest.mark.parametrize("module", [scale_module, patch_refine_module])
def test_doctests(module):
    assert doctest.testmod(module).failed == 0


def test_shapes(views):
    b = views.images.shape[0]
    assert saddle_scale_response(views.images, torch.tensor([2.0, 4.0, 8.0])).shape == (b, 3)
    assert estimate_square_size(views.images).shape == (b,)
    square, factor = ScaleSelector()(views.images)
    assert square.shape == (b,) and factor.shape == (b,) and factor.dtype == torch.float64
    level, s = resize_to_level(views.images, 2.0)
    assert level.shape == (b, 1, 240, 320) and torch.allclose(s, torch.tensor([2.0, 2.0], dtype=torch.float64))
    up, s_up = resize_to_level(views.images, 0.5)
    assert up.shape == (b, 1, 960, 1280) and float(s_up[0]) == 0.5
    assert edge_blur(views.images, views.corners, (9, 6)).shape == (b,)
    refined, ok = refine_on_patches(views.images, views.corners, (9, 6), return_ok=True)
    assert refined.shape == views.corners.shape and ok.shape == views.corners.shape[:2]


@pytest.mark.parametrize("factor", [1.0, 3.0, 6.0])
def test_square_size_estimate_follows_the_board(views, factor):
    images, corners = _upscaled(views, factor)
    ratio = estimate_square_size(images) / _square(corners)
    assert ((ratio > 0.7) & (ratio < 1.4)).all(), ratio


def test_batch_matches_single_images(views):
    both = estimate_square_size(views.images)
    one = torch.cat([estimate_square_size(views.images[i : i + 1]) for i in range(views.images.shape[0])])
    assert torch.allclose(both, one)


def test_detection_factor_quantised_and_bounded():
    f = detection_factor(torch.tensor([6.0, 12.0, 13.0, 48.0]), (640, 480), target_square=12.0)
    assert f.tolist()[:2] == [1.0, 1.0]  # never upsampled by default
    assert torch.allclose(torch.log2(f) * 4, torch.round(torch.log2(f) * 4))  # quarter octaves
    assert float(f[3]) == 4.0
    # a 24 Mpx photo is never detected at more than max_pixels
    big = detection_factor(torch.tensor([8.0]), (6000, 4000), max_pixels=3.2e6)
    assert 6000 * 4000 / float(big) ** 2 <= 3.2e6
    # upsampling only when allowed, and only up to ~10 px squares
    up = detection_factor(torch.tensor([6.0, 11.0]), (640, 480), target_square=12.0, min_factor=0.5)
    assert abs(6.0 / float(up[0]) - 10.0) < 1.5 and float(up[1]) == 1.0
    assert float(detection_factor(torch.tensor([3.0]), (640, 480), min_factor=0.5)) == 0.5


def test_edge_blur_measures_the_blur(views):
    sharp = edge_blur(views.images, views.corners, (9, 6))
    images = F.avg_pool2d(F.pad(views.images, (3, 3, 3, 3), mode="replicate"), 7, stride=1)  # box 7 px: sigma 2
    soft = edge_blur(images, views.corners, (9, 6))
    assert (sharp < 1.2).all() and ((soft > 1.6) & (soft < 3.2)).all(), (sharp, soft)


def test_refine_from_level_converges_from_a_coarse_level(views):
    images, corners = _upscaled(views, 8.0)
    start = corners + torch.tensor([2.5, -2.0])  # ~0.4 px of a level 8x smaller
    refined = refine_from_level(images, start, (9, 6), 8.0)
    # the same saddles as refined from the truth (the 8x bilinear upsampling itself moves them by ~0.4 px)
    ideal = refine_on_patches(images, corners, (9, 6), blur=edge_blur(images, corners, (9, 6)))
    assert (refined - ideal).norm(dim=-1).max() < 0.05


def test_refine_from_level_says_which_corners_found_no_saddle(views):
    """``return_ok``: False where the full-resolution window shows no saddle (there the corner keeps the position it
    came with) and at hidden corners; True elsewhere."""
    images, corners = _upscaled(views, 8.0)
    start = corners + torch.tensor([2.5, -2.0])
    x, y = corners[0, 20].round().long().tolist()
    images = images.clone()
    images[0, 0, y - 40:y + 41, x - 40:x + 41] = 0.5  # corner 20 of view 0 painted over
    start[1, 3] = float("nan")
    refined, ok = refine_from_level(images, start, (9, 6), 8.0, return_ok=True)
    expected = torch.ones_like(ok)
    expected[0, 20] = expected[1, 3] = False
    assert torch.equal(ok, expected)
    assert bool(refined[1, 3].isnan().all())


def test_refine_on_patches_matches_whole_image_refinement(views):
    from ccs_kornia.modules.detection.refine.saddle_refine import CornerRefiner

    start = views.corners + torch.tensor([0.6, -0.4])
    cells = torch.ones(views.corners.shape[:2], dtype=torch.bool)
    whole = CornerRefiner()(views.images, start, cells, (9, 6))
    patches = refine_on_patches(views.images, start, (9, 6))
    assert (patches - whole).norm(dim=-1).max() < 1e-3
    assert (patches - views.corners).norm(dim=-1).mean() < 0.05


def test_detect_at_scale_groups_levels_and_falls_back():
    calls = []

    def detect(x, board, full, scale):
        calls.append((tuple(x.shape), None if full is None else tuple(full.shape)))
        found = torch.full((x.shape[0],), x.shape[-1] == 80)  # "finds" boards only on the 4x level
        corners = torch.full((x.shape[0], board[0] * board[1], 2), 10.0)
        return DetectionResult(corners, found, ["learned" if f else "board not found" for f in found.tolist()])

    images = torch.rand(3, 1, 240, 320)
    out = detect_at_scale(detect, images, (3, 2), torch.tensor([4.0, 2.0, 2.0]), fallback=(2.0,),
                          refine=lambda full, pts, f: pts)
    corners, found, reasons = out.corners, out.found, out.reasons
    assert found.tolist() == [True, True, True] and reasons == ["learned"] * 3
    # one batched call per level: 4x for image 0, 2x for images 1-2, then their fallback at 4x
    assert calls == [((2, 1, 120, 160), (2, 1, 240, 320)), ((1, 1, 60, 80), (1, 1, 240, 320)),
                     ((2, 1, 60, 80), (2, 1, 240, 320))]
    # level corners are mapped to full-resolution pixel centres
    assert torch.allclose(corners, torch.full_like(corners, 10.5 * 4 - 0.5))


def test_detect_at_scale_skips_levels_over_the_pixel_budget():
    calls = []

    def detect(x, board, full, scale):
        calls.append(tuple(x.shape[-2:]))
        return DetectionResult(torch.zeros(x.shape[0], 6, 2), torch.zeros(x.shape[0], dtype=torch.bool))

    detect_at_scale(detect, torch.rand(1, 1, 200, 200), (3, 2), torch.tensor([2.0]), fallback=(0.5, 0.25, 2.0),
                    max_pixels=20_000)
    # factors 1 (40k px) and 0.5 are over the budget: clamped to the finest allowed level (1.41), tried once
    assert calls == [(100, 100), (141, 141), (50, 50)]
    # never an upsampled fallback
    calls.clear()
    detect_at_scale(detect, torch.rand(1, 1, 64, 64), (3, 2), torch.tensor([1.0]), fallback=(0.5,))
    assert calls == [(64, 64)]


def test_invalid_inputs():
    with pytest.raises(ValueError):
        estimate_square_size(torch.rand(2, 3, 32, 32))
    with pytest.raises(ValueError):
        estimate_square_size(torch.rand(1, 1, 4, 4))
    with pytest.raises(ValueError):
        estimate_square_size(torch.rand(1, 1, 64, 64), min_square=30, max_square=20)
    with pytest.raises(ValueError):
        saddle_scale_response(torch.rand(1, 1, 64, 64), torch.tensor([4.0, 2.0]))
    with pytest.raises(ValueError):
        detection_factor(torch.tensor([10.0]), (64, 64), target_square=0)
    with pytest.raises(ValueError):
        ScaleSelector(max_pixels=-1)
    with pytest.raises(ValueError):
        refine_on_patches(torch.rand(1, 1, 32, 32), torch.rand(2, 6, 2), (3, 2))
    with pytest.raises(ValueError):
        detect_at_scale(lambda *a: None, torch.rand(2, 1, 32, 32), (3, 2), torch.tensor([1.0]))
    with pytest.raises(ValueError):
        detect_at_scale(lambda *a: None, torch.rand(1, 1, 32, 32), (3, 2), torch.tensor([0.0]))


def test_learned_detector_scale_option():
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )

    with pytest.raises(ValueError):
        LearnedChessboardDetector(scale="sometimes")
    assert LearnedChessboardDetector().selects_scale
    assert not LearnedChessboardDetector(scale="off").selects_scale


@pytest.mark.slow
def test_learned_detector_finds_rescaled_soft_boards(views):
    """Squares of ~60 px with a 9 px box blur: missed at full resolution (scale="off"), found on the selected level."""
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )

    images, corners = _upscaled(views, 4.0, blur=9)
    out = LearnedChessboardDetector()(images, (9, 6))
    assert out.found.all(), out.reasons
    e1 = (out.corners - corners).norm(dim=-1).mean(-1)
    e2 = (out.corners.flip(-2) - corners).norm(dim=-1).mean(-1)
    assert (torch.minimum(e1, e2) < 0.15).all(), torch.minimum(e1, e2)


def test_detect_at_scale_without_the_primary_levels():
    # a second pass (primary=False): only the fallback levels, and none that equals an image's primary level
    calls = []

    def detect(x, board, full, scale):
        calls.append(tuple(x.shape[-2:]))
        return DetectionResult(torch.zeros(x.shape[0], 6, 2), torch.zeros(x.shape[0], dtype=torch.bool))

    out = detect_at_scale(detect, torch.rand(2, 1, 200, 200), (3, 2), torch.tensor([2.0, 1.0]), fallback=(0.5,),
                          finest=False, primary=False)
    f, r = out.found, out.reasons
    # image 0: its fallback (factor 1, the image itself); image 1's fallback clamps to its primary (1): skipped
    assert calls == [(200, 200)] and f.tolist() == [False, False] and r == ["board not found"] * 2
    calls.clear()
    detect_at_scale(detect, torch.rand(2, 1, 200, 200), (3, 2), torch.tensor([2.0, 1.0]), fallback=(0.5,),
                    finest=False)
    assert calls == [(200, 200), (100, 100), (200, 200)]


def test_detect_at_scale_tries_the_image_itself_last():
    # a wrong square-size estimate (factor 8) must not hide a board only the image itself shows
    tried = []

    def detect(x, board, full, scale):
        tried.append(tuple(x.shape[-2:]))
        hit = x.shape[-1] == 128
        n = board[0] * board[1]
        return DetectionResult(torch.zeros(x.shape[0], n, 2), torch.full((x.shape[0],), hit),
                               ["found" if hit else "no"] * x.shape[0])

    f = detect_at_scale(detect, torch.rand(1, 1, 96, 128), (4, 3), torch.tensor([8.0]), (0.5, 2.0, 0.25)).found
    assert bool(f[0]) and tried[-1] == (96, 128)


def test_refine_from_level_keeps_hidden_corners_hidden(views):
    """The hidden (NaN) corners of a partial board ride along at their predicted place and come back NaN; the others
    converge as on a whole board."""
    images, corners = _upscaled(views, 8.0)
    start = corners + torch.tensor([2.5, -2.0])
    start[0, 10] = float("nan")
    start[1, [0, 1, 9]] = float("nan")
    refined = refine_from_level(images, start, (9, 6), 8.0)
    hidden = start.isnan().any(-1)
    assert bool(refined[hidden].isnan().all()) and bool(refined[~hidden].isfinite().all())
    ideal = refine_on_patches(images, corners, (9, 6), blur=edge_blur(images, corners, (9, 6)))
    assert (refined - ideal)[~hidden].norm(dim=-1).max() < 0.05


def test_detect_at_scale_steps_down_by_octaves_before_the_image_itself():
    """Below the finest relative fallback the levels go down an octave at a time (each costs a quarter of the next
    finer one), so a board the estimate put 8x too coarse is found at 4x, not at full size; ``finest=False`` stops at
    the relative fallbacks."""
    tried = []

    def detect(x, board, full, scale):
        tried.append(x.shape[-1])
        hit = x.shape[-1] == 128  # only the 4x level shows the board
        n = board[0] * board[1]
        return DetectionResult(torch.zeros(x.shape[0], n, 2), torch.full((x.shape[0],), hit),
                               ["found" if hit else "no"] * x.shape[0])

    images = torch.rand(1, 1, 384, 512)
    f = detect_at_scale(detect, images, (4, 3), torch.tensor([32.0]), (0.5, 2.0, 0.25),
                        refine=lambda full, pts, fac: pts).found
    assert bool(f[0]) and tried == [16, 32, 8, 64, 128]  # 32x, 16x, 64x, 8x, then 4x: full size never needed
    tried.clear()
    f = detect_at_scale(detect, images, (4, 3), torch.tensor([32.0]), (0.5, 2.0, 0.25), finest=False).found
    assert not bool(f[0]) and tried == [16, 32, 8, 64]
    tried.clear()
    detect_at_scale(detect, images[..., :256, :320], (4, 3), torch.tensor([8.0]), (0.5, 2.0, 0.25))
    assert tried == [40, 80, 20, 160, 320]  # 8x, 4x, 16x, 2x, and at 1x the image itself (no octave in between)


def test_image_rows_is_indexing_without_a_copy_for_a_run():
    from ccs_kornia.modules.detection.base import image_rows

    x = torch.rand(5, 1, 4, 6)
    for idx in ([1, 2, 3], [0, 2, 4], [3], [0, 1, 2, 3, 4]):
        i = torch.tensor(idx)
        assert torch.equal(image_rows(x, i), x[i])
    assert image_rows(x, torch.tensor([1, 2, 3])).data_ptr() == x[1].data_ptr()  # a view: no copy of the images
