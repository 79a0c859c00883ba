"""A chessboard photographed in the dark: corners whose saddle fit fails in the noise, and corners the level calls
hidden inside the image, fitted again with the smoothing doubled (only those), and the real dark fisheye views whole."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.data.render.poor_images import make_poor
from ccs_kornia.modules.detection.learned import learned_detector as ld

BOARD = (7, 5)
FISHEYE = REAL_DATA / "ros_fisheye_mono"


@pytest.fixture(scope="module")
def detector():
    return ld.LearnedChessboardDetector()


def _checker(noise: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A dark checker (squares 16 px, contrast 0.1) with Gaussian noise, and its inner corners (1, 35, 2)."""
    yy, xx = torch.meshgrid(torch.arange(96), torch.arange(128), indexing="ij")
    img = torch.where(((xx // 16 + yy // 16) % 2) == 0, 0.05, 0.15).float()
    img = img + noise * torch.randn(img.shape, generator=torch.Generator().manual_seed(0))
    pts = torch.tensor([[16.0 * (i + 1) - 0.5, 16.0 * (j + 1) - 0.5] for j in range(5) for i in range(7)])
    return img[None, None], pts[None]


@pytest.mark.parametrize("noise", [0.0, 0.02])
def test_only_a_noisy_boards_failed_corners_take_the_smoother_fit(detector, monkeypatch, noise):
    img, truth = _checker(noise)
    monkeypatch.setattr(ld, "motion_blur", lambda gray8: None)
    real, calls = ld.refine_from_level, []

    def staged(images, pts, board_size, factor, rf, max_radius, method, iterations, smooth, *rest, **kw):
        out, ok = real(images, pts, board_size, factor, rf, max_radius, method, iterations, smooth, *rest, **kw)
        calls.append(smooth)
        if len(calls) == 1:  # the first fit fails at corner 8 (inside the image: no border retry)
            out, ok = out.clone(), ok.clone()
            out[0, 8] += 3.0
            ok[0, 8] = False
        return out, ok

    monkeypatch.setattr(ld, "refine_from_level", staged)
    first = real(img, truth + 0.3, BOARD, 1.0, return_ok=True, neighbours=False,
                 smooth_sigma=detector.refiner.smooth_sigma)[0]
    out = detector._refine_at_full_size(img, truth + 0.3, BOARD, 1.0)
    others = torch.arange(35) != 8
    assert torch.equal(out[0, others], first[0, others])  # the corners that found their saddle keep their first fit
    if noise == 0.0:  # in good light: no second fit, the failed corner left out
        assert calls == [detector.refiner.smooth_sigma] and bool(out[0, 8].isnan().all())
    else:  # noise 0.2 of the contrast: fitted again with the smoothing doubled
        assert calls == [detector.refiner.smooth_sigma, 2.0 * detector.refiner.smooth_sigma]
        assert float((out[0, 8] - truth[0, 8]).norm()) < 0.5


@pytest.mark.parametrize("noise", [0.0, 0.02])
def test_a_noisy_boards_hidden_corners_inside_the_image_are_fitted_again(detector, monkeypatch, noise):
    img, truth = _checker(noise)
    img, truth = img[..., 8:, 8:], truth - 8.0  # the first corner 7.5 px from the image's border
    monkeypatch.setattr(ld, "motion_blur", lambda gray8: None)
    start = truth + 0.3
    start[0, [8, 9, 0]] = float("nan")  # the level called two corners inside the image hidden, and one at its border
    out = detector._refine_at_full_size(img, start, BOARD, 1.0)
    err = (out[0] - truth[0]).norm(dim=-1)
    seen = torch.ones(35, dtype=torch.bool)
    seen[[8, 9, 0]] = False
    assert bool((err[seen] < 0.5).all())
    assert bool(out[0, 0].isnan().all())  # within the fit's largest window of the border: left alone
    if noise == 0.0:  # in good light the level's verdict stands
        assert bool(out[0, [8, 9]].isnan().all())
    else:  # in the noise: fitted from where their neighbours put them
        assert bool((err[[8, 9]] < 0.5).all())


@pytest.mark.skipif(not FISHEYE.is_dir(), reason=f"real photographs not found: {FISHEYE}")
def test_dark_fisheye_views_give_their_whole_board(detector):
    """``ros_fisheye_mono`` views darkened x0.12 as Poisson photo-electrons (the real-poor bench's dark sensor):
    whole boards (a corner at the board's dim rim failed its fit before), every corner within 3 px of
    ``findChessboardCornersSB``'s on the photograph as taken (in that noise the dim rim's corners are off by up to
    1.5 px), their median within 0.4 px."""
    whole = 0
    for name, seeds in (("left-0000.png", range(3)), ("left-0021.png", (0, 2))):
        gray = cv2.imread(str(FISHEYE / name), cv2.IMREAD_GRAYSCALE)
        ok, sb = cv2.findChessboardCornersSB(gray, (8, 6), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        assert ok
        sb = sb.reshape(-1, 2).astype(np.float64)
        for seed in seeds:
            dark, _ = make_poor(gray, "dark sensor", np.random.default_rng(seed))
            out = detector(torch.from_numpy(dark).float()[None, None] / 255.0, (8, 6))
            assert bool(out.found[0])
            corners = out.corners[0].double().numpy()
            found = np.isfinite(corners).all(-1)
            whole += bool(found.all())
            # the same corners whichever end the grid starts from: no wrong id (the bench's 3 px), most within 0.4 px
            d = min((np.linalg.norm(corners - s, axis=-1) for s in (sb, sb[::-1])), key=lambda x: np.nanmax(x))
            assert np.nanmax(d) < 3.0 and np.nanmedian(d) < 0.4
    assert whole == 5


@pytest.mark.skipif(not FISHEYE.is_dir(), reason=f"real photographs not found: {FISHEYE}")
def test_a_lone_corner_is_dropped_not_guessed(detector):
    """A darker draw of the grazing fisheye view: the board's dim corner loses its three neighbours, and its own fit
    went to the next row's corner (8.4 px off); nothing confirms it, so it is left out."""
    gray = cv2.imread(str(FISHEYE / "left-0021.png"), cv2.IMREAD_GRAYSCALE)
    ok, sb = cv2.findChessboardCornersSB(gray, (8, 6), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    assert ok
    sb = sb.reshape(-1, 2).astype(np.float64)
    dark, _ = make_poor(gray, "dark sensor", np.random.default_rng([500, 10]))
    out = detector(torch.from_numpy(dark).float()[None, None] / 255.0, (8, 6))
    assert bool(out.found[0])
    corners = out.corners[0].double().numpy()
    d = min((np.linalg.norm(corners - s, axis=-1) for s in (sb, sb[::-1])), key=lambda x: np.nanmax(x))
    assert np.nanmax(d) < 3.0 and int(np.isfinite(corners).all(-1).sum()) >= 40
