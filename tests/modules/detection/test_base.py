import pytest
import torch

from ccs_kornia.modules.detection.base import (
    ChessboardDetector,
    DetectionResult,
    Fallbacks,
)


def test_fill_writes_found_boards_only_one_dimension():
    det = DetectionResult(torch.zeros(4, 3, 2), torch.zeros(4, dtype=torch.bool), ["none"] * 4,
                          torch.zeros(4, 3))
    got = DetectionResult(torch.ones(2, 3, 2), torch.tensor([False, True]), ["missed", "found"])
    hit = det.fill(torch.tensor([1, 3]), got)
    assert hit.tolist() == [False, True] and det.found.tolist() == [False, False, False, True]
    assert bool((det.corners[3] == 1).all()) and not bool(det.corners[:3].any())
    assert det.reasons == ["none", "none", "none", "found"]
    # found without a precision: unknown (NaN), the rest untouched
    assert bool(det.sigma[3].isnan().all()) and bool((det.sigma[:3] == 0).all())


def test_fill_cameras_and_views_with_precision():
    det = DetectionResult(torch.zeros(2, 3, 4, 2, dtype=torch.float64), torch.zeros(2, 3, dtype=torch.bool),
                          [""] * 6, torch.full((2, 3, 4), float("nan")))
    got = DetectionResult(torch.full((2, 4, 2), 2.0), torch.tensor([True, True]), ["a", "b"],
                          torch.full((2, 4), 0.5))
    det.fill((torch.tensor([1, 0]), torch.tensor([2, 1])), got)
    assert det.found.tolist() == [[False, True, False], [False, False, True]]
    assert det.reasons == ["", "b", "", "", "", "a"] and det.corners.dtype == torch.float64
    assert bool((det.sigma[1, 2] == 0.5).all()) and bool(det.sigma[0, 0].isnan().all())


def test_fallbacks_changes_and_empty():
    own = Fallbacks(levels=(0.5, 2.0))
    assert own.but(levels=()).levels == () and own.levels == (0.5, 2.0)  # a value: never changed
    assert not own.empty and Fallbacks(primary=False, levels=(), opencv=False, foreshortened=False, copies=False).empty
    assert not Fallbacks(primary=False, levels=(0.5,), opencv=False, foreshortened=False, copies=False).empty
    assert not Fallbacks(primary=False, levels=(), opencv=False, foreshortened=False).empty  # the copies remain
    with pytest.raises(TypeError):
        own.but(scale=2.0)


class _Recorder(ChessboardDetector):
    def __init__(self, fallbacks):
        super().__init__()
        self.fallbacks, self.seen = fallbacks, []

    def forward(self, images, board_size, fallbacks=None):
        self.seen.append(fallbacks)
        b = images.shape[0]
        return DetectionResult(torch.zeros(b, 6, 2), torch.zeros(b, dtype=torch.bool))


def test_detect_passes_fallbacks_only_to_a_detector_with_its_own():
    images = torch.rand(1, 1, 8, 8)
    det = _Recorder(Fallbacks())
    det.detect(images, (3, 2))
    det.detect(images, (3, 2), Fallbacks(opencv=False))
    assert det.seen == [None, Fallbacks(opencv=False)] and det.fallbacks == Fallbacks()
    plain = _Recorder(None)
    plain.detect(images, (3, 2), Fallbacks(opencv=False))
    assert plain.seen == [None]


def test_a_plain_detector_declares_what_it_cannot_do():
    plain = _Recorder(None)
    assert plain.fallbacks is None and not plain.selects_scale and plain.board is None
    assert plain.heatmap_net is None and plain.refines_on_image and plain.fit_window == 7
    assert plain.detection_factor(torch.rand(2, 1, 8, 8)) == 1.0
    with pytest.raises(NotImplementedError, match="grazing"):
        plain.foreshortened(torch.rand(1, 1, 8, 8), (3, 2))

