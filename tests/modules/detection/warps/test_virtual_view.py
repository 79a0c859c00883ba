"""Second look with the calibrated lens: virtual pinhole views, corners mapped back exactly."""

from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.warps.virtual_view import (
    VIEWS_PER_ROUND,
    detect_with_calibrated_lens,
    view_directions,
    virtual_view_rays,
)
from ccs_kornia.pipeline.workers import worker_pool

F64 = torch.float64


def test_directions_and_rays():
    assert view_directions(False) == [(0.0, 0.0, 110.0)]
    views = view_directions(True)
    tilts = sorted({round(math.hypot(y, p), 6) for y, p, _ in views[1:]})
    assert len(views) == 19 and tilts == [35.0, 55.0] and {f for *_, f in views} == {110.0, 130.0}
    rays, f, R = virtual_view_rays((0.0, 0.0), 90.0, 5)
    assert rays.shape == (25, 3) and abs(f - 2.5) < 1e-12 and torch.allclose(rays[12], torch.tensor([0.0, 0, 1], dtype=F64))
    tilted, _, R30 = virtual_view_rays((30.0, 0.0), 90.0, 5)
    assert torch.allclose(R, torch.eye(3, dtype=F64)) and torch.allclose(R30 @ R30.T, torch.eye(3, dtype=F64))
    centre = tilted[12] / tilted[12].norm()
    assert abs(math.degrees(math.acos(float(centre[2]))) - 30.0) < 1e-9


def test_corners_are_mapped_back_exactly():
    """A fake detector that 'finds' fixed pixels in the virtual view: they come back where the lens images them."""
    K = torch.tensor([[[160.0, 0, 319.5], [0, 161, 239.5], [0, 0, 1]]], dtype=F64)
    D = torch.tensor([[0.02, -0.01, 0.002, 0.0]], dtype=F64)
    pix = torch.tensor([[[100.0, 120.0], [200.0, 250.0], [300.0, 90.0], [400.0, 400.0]]])

    def fake(images, board):
        return DetectionResult(pix.expand(images.shape[0], -1, -1).clone(), torch.ones(images.shape[0], dtype=torch.bool),
                               ["fake"] * images.shape[0])

    camera = Camera.from_opencv(FISHEYE, K, D)
    out = detect_with_calibrated_lens(fake, lambda i, c, b: c, torch.rand(1, 1, 480, 640), camera, (2, 2))
    assert bool(out.found[0]) and "virtual pinhole view 0" in out.reasons[0]
    # back to the virtual view: the ray of each returned corner, in the virtual camera (axis view, 110 deg, 480 px)
    rays = camera.unproject(out.corners.double())
    f = 240 / math.tan(math.radians(55))
    back = rays[..., :2] / rays[..., 2:] * f + 239.5
    assert torch.allclose(back.float(), pix, atol=1e-3)


FISH_K = torch.tensor([[160.0, 0, 319.5], [0, 161, 239.5], [0, 0, 1]], dtype=F64)
FISH_D = torch.tensor([0.02, -0.01, 0.002, 0.0], dtype=F64)


def _fisheyes(n: int) -> Camera:
    return Camera.from_opencv(FISHEYE, FISH_K.expand(n, 3, 3), FISH_D.expand(n, 4))


def _bright_centre_detector(images, board):
    """'Finds' a fixed 2x2 board on the virtual views whose centre is bright."""
    b = images.shape[0]
    pix = torch.tensor([[[230.0, 230.0], [250.0, 230.0], [230.0, 250.0], [250.0, 250.0]]]).expand(b, -1, -1).clone()
    return DetectionResult(pix, images[:, 0, 240, 240] > 0.5, ["fake"] * b)


def test_views_in_rounds_the_first_view_wins():
    """Each round's views look at the images without a board before the round; the first view in order keeps it."""
    calls = []

    def every_view(images, board):
        calls.append(images.shape[0])
        return _bright_centre_detector(torch.ones_like(images), board)

    out = detect_with_calibrated_lens(every_view, lambda i, c, b: c, torch.rand(2, 1, 480, 640),
                                      _fisheyes(2), (2, 2))
    assert out.found.tolist() == [True, True] and all("virtual pinhole view 0 " in r for r in out.reasons)
    assert calls == [2] * VIEWS_PER_ROUND  # one round, both views on both images; then nothing is left to look for


def test_view_pool_gives_the_same_boards():
    """The views of a round in two forked processes: the same boards, corners and views as in order here."""
    images = torch.zeros(3, 1, 480, 640)
    images[0, :, :, 420:] = 1  # seen at the centre of views turned to the right only
    images[1, :, :120] = 1  # ... turned up only
    rounds = []

    @contextmanager
    def recorded(fn):
        with worker_pool(fn, workers=2) as run:
            yield lambda items: (rounds.append([k[0] for k in items]), run(items))[1]

    args = (_bright_centre_detector, lambda i, c, b: c, images, _fisheyes(3), (2, 2))
    here = detect_with_calibrated_lens(*args)
    pooled = detect_with_calibrated_lens(*args, view_pool=recorded)
    assert here.found.tolist() == [True, True, False]
    assert "view 1 " in here.reasons[0] and "view 5 " in here.reasons[1]  # a round's first and second view
    assert pooled.found.tolist() == here.found.tolist() and pooled.reasons == here.reasons
    assert torch.equal(pooled.corners, here.corners)
    views = view_directions(True)
    # every round but the last has VIEWS_PER_ROUND views, in order (the third image keeps every round going)
    assert [d for r in rounds for d in r] == views and {len(r) for r in rounds[:-1]} == {VIEWS_PER_ROUND}


def test_shape_errors():
    with pytest.raises(ValueError, match=r"images must be \(B, 1, H, W\) with B=1 \(one per camera\), got \(1, 8, 8\)"):
        detect_with_calibrated_lens(None, None, torch.rand(1, 8, 8), _fisheyes(1), (2, 2))


def test_finds_the_rim_boards_of_a_real_fisheye_set():
    """ros_fisheye_mono: the three views the learned detector misses on the originals are found this way."""
    import cv2

    from ccs_kornia.geometry.board_points import board_object_points
    from ccs_kornia.io.images import load_image_gray
    from ccs_kornia.modules.calibration.solver import CalibrationSolver
    from ccs_kornia.modules.detection.factory import make_detector

    folder = REAL_DATA / "ros_fisheye_mono"
    if not folder.is_dir():
        pytest.skip(f"real data set not present at {folder}")
    corners = []
    for f in sorted(folder.glob("*.png")):
        g = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(g, (8, 6), 3)
        corners.append(cv2.cornerSubPix(g, c, (5, 5), (-1, -1), (3, 30, 1e-3)).reshape(-1, 2))
    cal = CalibrationSolver(model=FISHEYE)(torch.tensor(np.stack(corners), dtype=F64), None,
                                             board_object_points(8, 6, 0.108, dtype=F64), (800, 503))
    names = ["left-0019.png", "left-0020.png", "left-0021.png"]
    images = torch.stack([torch.from_numpy(load_image_gray(str(folder / n))[0]) for n in names])[:, None].float()
    out = detect_with_calibrated_lens(make_detector("learned"), lambda i, c, b: c, images,
                                      Camera.cat([cal.camera] * 3), (8, 6))
    assert out.found.tolist() == [True, True, True], out.reasons
    # the mapped-back corners lie on the classic detector's (up to the board's symmetric labelling)
    for k, n in enumerate(names):
        ref = torch.tensor(corners[int(n[5:9])], dtype=torch.float32)
        d = torch.cdist(out.corners[k], ref).amin(-1)
        assert float(d.max()) < 1.5, (n, float(d.max()))
