import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_uncertainty
from ccs_kornia.modules.detection.refine.patch_refine import (
    refine_on_patches,
    resize_to_level,
)
from ccs_kornia.modules.detection.warps.warped_detection import (
    Downscale,
    Level,
    Warp,
    detect_warped,
    map_back,
)

BOARD = (9, 6)


@pytest.fixture(scope="module")
def views():
    K = torch.tensor([[1000.0, 0, 639.5], [0, 1000, 479.5], [0, 0, 1]])
    return make_calibration_set(K, BOARD, 0.025, (1280, 960), num_views=3, seed=2, supersample=1)


def _measure(images, corners, board):
    valid = torch.ones(corners.shape[:2], dtype=torch.bool)
    return corner_uncertainty(images.float(), corners.float(), valid, board)


def test_downscale_maps_pixel_centres_back():
    warp = Downscale.to_side((960, 1280), 640)
    assert warp.size == (480, 640)
    # the centre of small pixel (0, 0) is the centre of its 2x2 footprint; the last one of the last footprint
    back, ok = warp.back(torch.tensor([[[0.0, 0.0], [639.0, 479.0]]], dtype=torch.float64))
    assert back.tolist() == [[[0.5, 0.5], [1278.5, 958.5]]] and ok.tolist() == [True]
    assert warp.apply(torch.rand(2, 1, 960, 1280)).shape == (2, 1, 480, 640)


@pytest.mark.parametrize("factor", [1.0, 2.0, 2.0 ** 1.25, 0.5])
def test_level_is_the_detection_level_and_maps_pixel_centres_back(factor):
    images = torch.rand(2, 1, 96, 130)
    warp = Level(factor, (96, 130))
    level, scale = resize_to_level(images, factor)
    assert torch.equal(warp.apply(images), level) and warp.size == tuple(level.shape[-2:])
    assert warp.resamples == (factor != 1.0) and torch.equal(warp.scale(), scale)
    assert warp.coarseness == float(scale.max())
    pts = torch.rand(2, 5, 2) * 40
    back, ok = warp.back(pts)
    assert back.dtype == pts.dtype and ok.tolist() == [True, True]
    torch.testing.assert_close(back.double(), (pts.double() + 0.5) * scale - 0.5)


def test_detect_warped_finds_the_boards_at_full_resolution(views):
    """Detected on a half-size copy, refined on the images: the corners of the images themselves (cross-check against
    the renderer's truth), with their precision measured there."""
    refine = lambda i, c, b: refine_on_patches(i, c, b)  # noqa: E731
    out = detect_warped(Downscale.to_side((960, 1280), 640), make_detector("opencv"), refine, views.images, BOARD,
                        _measure)
    assert out.corners.shape == (3, 54, 2) and out.found.shape == (3,) and out.sigma.shape == (3, 54)
    assert bool(out.found.all()) and len(out.reasons) == 3
    err = (out.corners.double() - views.corners.double()).norm(dim=-1)
    assert float(err.mean()) < 0.1
    assert bool(out.sigma.isfinite().all())


class _Nowhere(Warp):
    """A warp whose copies map back outside the image for the second image."""

    def apply(self, images):
        return images

    def back(self, points):
        return points, torch.tensor([True, False])


def test_map_back_drops_boards_that_do_not_map_back():
    det = DetectionResult(torch.full((2, 6, 2), 5.0), torch.tensor([True, True]), ["a", "b"])
    seen = []

    def refine(images, corners, board):
        seen.append(images.shape[0])
        return corners + 1.0

    out = map_back(_Nowhere(), det, refine, torch.rand(2, 1, 16, 16), (3, 2), lambda i, c, b: torch.ones(c.shape[:2]))
    assert out.found.tolist() == [True, False] and seen == [1]
    assert bool((out.corners[0] == 6.0).all()) and bool((out.corners[1] == 0).all())
    assert out.sigma[0].tolist() == [1.0] * 6 and bool(out.sigma[1].isnan().all())
    assert out.reasons == ["a", "b"]


def test_map_back_without_a_board_refines_nothing():
    det = DetectionResult(torch.zeros(2, 6, 2), torch.zeros(2, dtype=torch.bool), ["x", "y"])
    out = map_back(Downscale((8, 8), (16, 16)), det, lambda *a: pytest.fail("nothing to refine"),
                   torch.rand(2, 1, 16, 16), (3, 2))
    assert not bool(out.found.any()) and out.sigma is None and not bool(out.corners.any())
