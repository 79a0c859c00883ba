"""Corners detected before as the pipeline's source: the solve on them is the solve on the images, exactly."""

from __future__ import annotations

import math

import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.io.corners_file import CornersFile, CornersView
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.pipeline.corners_input import NO_IMAGE, CornersSource, match_given_views
from ccs_kornia.pipeline.sources import TensorSource

BOARD = (9, 6)
SQUARE = 0.025
K = torch.tensor([[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
DIST = torch.tensor([-0.3, 0.1, 0.0, 0.0, 0.0], dtype=torch.float64)


def _as_file(det, names: list[str]) -> CornersFile:
    """One camera's first-look result as a corners file holds it (corners, sizes, precisions, reasons, correction)."""
    views = []
    n = BOARD[0] * BOARD[1]
    for v, name in enumerate(names):
        found = bool(det.detections.found[v])
        corners = det.detections.corners[v].clone() if found else torch.full((n, 2), math.nan, dtype=torch.float64)
        sigma = None if det.detections.sigma is None else det.detections.sigma[v].double()
        views.append(CornersView(name, found, corners, 0.1 * v, tuple(det.view_sizes[v].tolist()), sigma,
                                 det.detections.reasons[v]))
    return CornersFile("given.json", BOARD, views, tuple(det.image_size), correction=det.correction)


@pytest.fixture(scope="module")
def views():
    return make_calibration_set(K, BOARD, SQUARE, (640, 480), num_views=8, dist=DIST, seed=5, supersample=2)


def test_the_solve_on_given_corners_is_the_solve_on_the_images(views):
    pipe = CalibrationPipeline("opencv", model=ModelChoice(), workers=1, diagnostics=True)
    on_images = pipe.run(TensorSource(views.images), BOARD, SQUARE).select(0)
    detected = pipe.run(TensorSource(views.images), BOARD, SQUARE, calibrate=False).select(0)
    assert detected.correction is not None and detected.detections.sigma is not None
    names = [f"view{v}.png" for v in range(views.images.shape[0])]
    source = CornersSource([_as_file(detected, names)])
    given = pipe.run(source, BOARD, SQUARE).select(0)
    a, b = on_images.calibration, given.calibration
    assert bool(a.success) and bool(b.success)
    # the same numbers up to the float rounding of the network's pooled correction, which differs between two runs
    # on the same images in the last bits (1e-15)
    close = {"rtol": 1e-10, "atol": 1e-12}
    assert torch.allclose(a.K, b.K, **close) and torch.allclose(a.dist, b.dist, **close)
    assert torch.equal(a.used, b.used) and math.isclose(float(a.rms), float(b.rms), rel_tol=1e-10)
    assert on_images.model_selection["chosen"] == given.model_selection["chosen"]
    assert bool(on_images.correction_tried) == bool(given.correction_tried)
    assert torch.allclose(on_images.straightness, given.straightness, **close)
    assert math.isclose(on_images.diagnostics["cv_rms_px"], given.diagnostics["cv_rms_px"], rel_tol=1e-9)


def test_given_corners_without_the_correction_or_precision(views):
    """Corners without precisions are all weighed alike (as --unweighted on the images); a pipeline without the
    distortion correction ignores the file's."""
    pipe = CalibrationPipeline("opencv", workers=1, weigh_corners=False, distortion_correction=False)
    on_images = pipe.run(TensorSource(views.images), BOARD, SQUARE).select(0)
    detected = pipe.run(TensorSource(views.images), BOARD, SQUARE, calibrate=False).select(0)
    cf = _as_file(detected, [f"v{k}" for k in range(8)])
    cf = CornersFile(cf.path, cf.board, cf.views, cf.image_size, correction=torch.tensor([1.0, 0, 0.3, 0, 0]))
    given = pipe.run(CornersSource([cf]), BOARD, SQUARE).select(0)
    assert given.correction is None and given.detections.sigma is None
    assert torch.equal(on_images.calibration.K, given.calibration.K)


def test_the_source_has_no_images_and_checks_the_board():
    n = BOARD[0] * BOARD[1]
    views = [CornersView("a.png", True, torch.zeros(n, 2, dtype=torch.float64)),
             CornersView("b.png", False, torch.full((n, 2), math.nan, dtype=torch.float64), reason="board not found"),
             CornersView("c.png", False, torch.full((n, 2), math.nan, dtype=torch.float64), reason="unreadable: x")]
    source = CornersSource([CornersFile("c.json", BOARD, views)], image_size=(64, 48))
    assert source._load(0, 0) == (None, NO_IMAGE)
    out = source.given_detections(BOARD)
    assert out.present.tolist() == [[True, True, False]] and out.detections.found.tolist() == [[True, False, False]]
    assert out.view_sizes[0].tolist() == [[64, 48], [64, 48], [0, 0]]
    assert out.detections.reasons == ["", "board not found", "unreadable: x"] and out.detections.sigma is None
    with pytest.raises(ValueError, match="holds the corners of a 9x6 board, not 8x6"):
        source.given_detections((8, 6))
    with pytest.raises(ValueError, match="does not say the images' size"):
        CornersSource([CornersFile("c.json", BOARD, views)])


def test_views_match_by_time_else_by_name():
    nan = torch.full((4, 2), math.nan, dtype=torch.float64)

    def cam(c, times, names):
        views = [CornersView(n, False, nan, t) for n, t in zip(names, times)]
        return CornersFile(f"c{c}.json", (2, 2), views, (64, 48))

    # by time: camera 1 starts a frame late, 3 ms behind camera 0
    timed = CornersSource([cam(0, [0.0, 0.1, 0.2, 0.3], ["a", "b", "c", "d"]),
                           cam(1, [0.103, 0.203, 0.303], ["x", "y", "z"])])
    table = match_given_views(timed)
    assert table.by == "time" and table.index == [[0, 1, 2, 3], [None, 0, 1, 2]]
    with pytest.raises(ValueError, match="no two corners files have views within 0.001 s"):
        match_given_views(timed, tolerance=0.001)
    # by name: a view without a timestamp
    named = CornersSource([cam(0, [0.0, None], ["left01.png", "left02.png"]),
                           cam(1, [None, None], ["right02.png", "right01.png"])])
    table = match_given_views(named)
    assert table.by == "number" and table.index == [[0, 1], [1, 0]]
