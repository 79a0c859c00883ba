"""The network's corner peaks at full resolution: on a marker board (nearly every corner, few others), on a small board
whose first level is too coarse (the finer level retried), batched."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.modules.detection.learned.corner_peaks import corner_peaks

BOARD = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")


def _view(scale: float) -> tuple[np.ndarray, np.ndarray]:
    art, a = BOARD.texture(100)
    h = np.array([[scale, 0.02 * scale, 40.0], [-0.02 * scale, scale, 30.0], [0.0, 0.0, 1.0]])
    img = cv2.warpPerspective(cv2.GaussianBlur(art, (0, 0), 0.5 / scale), h, (640, 480), borderValue=128)
    obj = BOARD.object_points().numpy()[:, :2]
    truth = cv2.perspectiveTransform((np.c_[obj, np.ones(len(obj))] @ a.T)[None], h)[0]
    return img, truth


def _recall(peaks: np.ndarray, truth: np.ndarray) -> int:
    if not len(peaks):
        return 0
    d = np.linalg.norm(truth[:, None] - peaks[None], axis=-1)
    return int((d.min(1) < 1.5).sum())


def test_peaks_of_a_marker_board_batched():
    views = [_view(0.55), _view(0.3)]
    x = torch.from_numpy(np.stack([v[0] for v in views])).float()[:, None] / 255
    peaks = corner_peaks(x)
    assert len(peaks) == 2 and all(p.dtype == np.float64 and p.shape[1] == 2 for p in peaks)
    for (img, truth), p in zip(views, peaks):
        assert _recall(p, truth) >= 22
        assert len(p) <= 24 + 8  # few peaks off the corners (the markers' own junctions)
    single = corner_peaks(x[1:])
    assert np.allclose(single[0], peaks[1])


def test_a_coarse_first_level_is_retried_finer():
    img, truth = _view(0.12)  # squares of 12 px
    x = torch.from_numpy(img).float()[None, None] / 255
    assert _recall(corner_peaks(x)[0], truth) >= 22
    assert len(corner_peaks(x, retry=())[0]) <= len(corner_peaks(x)[0])


def test_a_measured_square_size_sets_the_level_without_the_scale_estimate(monkeypatch):
    from ccs_kornia.modules.detection.learned.corner_peaks import shipped_detector

    img, truth = _view(0.55)  # squares of 55 px
    x = torch.from_numpy(img).float()[None, None] / 255
    selector = shipped_detector().scale_selector
    # a misled estimate (a scene's larger texture): far too coarse a level, nothing found on it
    monkeypatch.setattr(selector, "forward", lambda images: (torch.full((images.shape[0],), 900.0),
                                                              torch.full((images.shape[0],), 100.0, dtype=torch.float64)))
    assert _recall(corner_peaks(x, retry=())[0], truth) == 0
    measured = corner_peaks(x, retry=(), square_size=torch.tensor([55.0]))[0]
    assert _recall(measured, truth) >= 22
    # a finer level for the same board (a larger level square) still finds its corners; NaN falls back to the estimate
    assert _recall(corner_peaks(x, retry=(), square_size=torch.tensor([55.0]), level_square=18.0)[0], truth) >= 22
    assert _recall(corner_peaks(x, retry=(), square_size=torch.tensor([float("nan")]))[0], truth) == 0
