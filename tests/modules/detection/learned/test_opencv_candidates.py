"""OpenCV's classic corners as candidates: the learned detector's last source (boards with marks), and the grid check
every board the learned detector returns passes."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.bench.scenes.scenes import quantize
from ccs_kornia.bench.sections.wild import WILD_CONDITIONS, wild_spec
from ccs_kornia.data.scenes.wild import WildChessboards
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.modules.detection.grid.missing_corners import lattice_deviation
from ccs_kornia.modules.detection.learned.learned_detector import (
    MAX_LATTICE_DEVIATION,
    LearnedChessboardDetector,
)
from ccs_kornia.modules.detection.learned.opencv_candidates import (
    OPENCV_MAX_PIXELS,
    opencv_candidates,
    opencv_level_factor,
)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
#: held-out renders: the seeds the detector options were tuned on, disjoint from the benchmark's and training's
TUNE_SEED = 7_777_000


def _checker(square: int = 14, cols: int = 6, rows: int = 4, margin: int = 24) -> tuple[torch.Tensor, torch.Tensor]:
    h, w = 2 * margin + (rows + 1) * square, 2 * margin + (cols + 1) * square
    y, x = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    inside = (x >= margin) & (x < w - margin) & (y >= margin) & (y < h - margin)
    cell = ((x - margin) // square + (y - margin) // square) % 2
    img = torch.where(inside, cell.float(), torch.ones_like(x, dtype=torch.float32))
    jj, ii = torch.meshgrid(torch.arange(1, rows + 1), torch.arange(1, cols + 1), indexing="ij")
    corners = torch.stack([margin + ii * square - 0.5, margin + jj * square - 0.5], -1).reshape(-1, 2).float()
    return img[None, None], corners


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_candidates_are_the_board_corners(device, dtype):
    img, corners = _checker()
    pts, ok = opencv_candidates(img.to(device, dtype), (6, 4))
    assert pts.shape == (1, 24, 2) and ok.shape == (1, 24) and pts.device.type == device
    assert bool(ok.all())
    d = torch.cdist(corners, pts[0].cpu().float())
    assert float(d.min(1).values.max()) <= 1.0, "every corner has a candidate within a pixel (OpenCV's quad corners)"


def test_batch_and_exceptions():
    img, _ = _checker()
    pts, ok = opencv_candidates(torch.cat([img, torch.full_like(img, 0.5), img]), (6, 4), num_workers=2)
    one, _ = opencv_candidates(img, (6, 4), num_workers=0)
    assert ok.tolist() == [[True] * 24, [False] * 24, [True] * 24]
    assert torch.equal(pts[0], one[0]) and torch.equal(pts[2], one[0]) and not bool(pts[1].any())
    with pytest.raises(ValueError, match="grey images"):
        opencv_candidates(torch.rand(1, 3, 32, 32), (6, 4))
    with pytest.raises(ValueError, match="board_size"):
        opencv_candidates(img, (1, 4))


def test_level_factor_bounds_the_pixels():
    assert opencv_level_factor((1280, 960)) == 1.0
    f = opencv_level_factor((6000, 4000))
    assert (6000 / f) * (4000 / f) == pytest.approx(OPENCV_MAX_PIXELS)


def test_charuco_board_found_only_from_opencv_candidates():
    """A held-out ChArUco-like render whose board the network's peaks do not give at any level: found from OpenCV's
    corners, refined to a few hundredths of a pixel with the narrow window (with the usual one a corner converges onto
    a mark's frame and the lattice check refuses the board)."""
    spec, board = wild_spec("aruco")
    index = list(WILD_CONDITIONS).index("aruco")
    batch = WildChessboards(spec).sample(1, torch.Generator().manual_seed(TUNE_SEED + 1000 * index + 10))
    n = board[0] * board[1]
    img, truth = quantize(batch.images), batch.corners[0, :n].double()
    without = LearnedChessboardDetector(opencv_retry=False)(img, board)
    assert not bool(without.found[0])
    out = LearnedChessboardDetector()(img, board)
    assert bool(out.found[0]) and out.reasons[0] == "learned (opencv candidates)"
    err = (out.corners[0].double() - truth).norm(dim=-1)
    assert float(err.mean()) < 0.05 and float(err.max()) < 0.15


def test_lattice_deviation_flags_a_displaced_corner_and_spares_perspective():
    obj = board_object_points(9, 6, 1.0, dtype=torch.float64)
    K = torch.tensor([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    rv = torch.tensor([[1.2, 0.2, 0.1]], dtype=torch.float64)  # about 70 degrees of tilt
    uv = project_points(obj[None], K[None], None, rv, torch.tensor([[-4.0, -2.5, 12.0]], dtype=torch.float64))
    exact = lattice_deviation(uv, (9, 6))
    assert exact.shape == (1, 54) and float(exact.max()) < 0.75 * MAX_LATTICE_DEVIATION
    moved = uv.clone()
    spacing = float((uv[0, 1] - uv[0, 0]).norm())
    moved[0, 20] += torch.tensor([0.15 * spacing, 0.0], dtype=torch.float64)  # onto a mark's junction, say
    dev = lattice_deviation(moved, (9, 6))
    assert int(dev.argmax()) == 20 and float(dev.max()) > MAX_LATTICE_DEVIATION
    with pytest.raises(ValueError, match="corners"):
        lattice_deviation(uv[:, :10], (9, 6))


def test_lattice_deviation_of_a_partial_board():
    """Hidden corners (NaN) are no neighbours and get deviation 0: a partial board is judged on its measured corners
    (a NaN there used to refuse every partial board found from OpenCV's candidates)."""
    obj = board_object_points(9, 6, 1.0, dtype=torch.float64)
    K = torch.tensor([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    uv = project_points(obj[None], K[None], None, torch.tensor([[0.3, 0.2, 0.1]], dtype=torch.float64),
                        torch.tensor([[-4.0, -2.5, 12.0]], dtype=torch.float64))
    partial = uv.clone()
    partial[0, [21, 22, 30, 31]] = float("nan")
    dev, estimate = lattice_deviation(partial, (9, 6), return_estimate=True)
    assert bool(dev.isfinite().all()) and float(dev.max()) < 0.75 * MAX_LATTICE_DEVIATION
    assert float(dev[0, [21, 22, 30, 31]].abs().max()) == 0.0
    spacing = float((uv[0, 1] - uv[0, 0]).norm())
    # the hole's cells from their rows and columns (extrapolated, under perspective): within a few hundredths of a square
    assert float((estimate[0, [21, 22, 30, 31]] - uv[0, [21, 22, 30, 31]]).norm(dim=-1).max()) < 0.05 * spacing
    partial[0, 11] += torch.tensor([0.15 * spacing, 0.0], dtype=torch.float64)
    assert float(lattice_deviation(partial, (9, 6))[0, 11]) > MAX_LATTICE_DEVIATION  # the board is refused


def test_opencv_source_sub_board_is_refused_by_the_final_checks(monkeypatch):
    """OpenCV's classic detector can return a sub-board of a larger board (8x6 on a 9x6 board), a perfect lattice the
    lattice check cannot refuse, and without candidates beyond its sides the organiser cannot either: the image test of
    the board's sides, which every board the detector returns passes, does."""
    import ccs_kornia.modules.detection.learned.learned_detector as learned

    img, corners = _checker(square=14, cols=9, rows=6)
    det = LearnedChessboardDetector()
    whole = det.detect_level(img, (9, 6), source="opencv")
    assert bool(whole.found[0]) and whole.reasons[0] == "learned (opencv candidates)"
    sub = corners.reshape(6, 9, 2)[:, :8].reshape(1, -1, 2)
    monkeypatch.setattr(learned, "opencv_candidates", lambda images, board: (sub, torch.ones(1, 48, dtype=torch.bool)))
    assert bool(det.detect_level(img, (8, 6), source="opencv").found[0]), "a perfect lattice on its own"
    out = det(img, (8, 6))
    assert not bool(out.found[0]) and "continues past its right side" in out.reasons[0]


def test_detector_refuses_a_board_that_skips_every_other_corner(monkeypatch):
    """Every board the learned detector returns passes the skipped-line check (a lattice of every other crossing of a
    grid of lines was the one false board on 126 held-out board-free images)."""
    img, corners = _checker(square=16, cols=8, rows=6)
    every_other = corners.reshape(6, 8, 2)[::2, ::2].reshape(-1, 2)  # a 4x3 lattice, a corner between neighbours
    det = LearnedChessboardDetector()

    def detect(images, board_size, fallbacks):
        return DetectionResult(corners=every_other[None].clone(), found=torch.tensor([True]), reasons=["learned"])

    monkeypatch.setattr(det, "_detect", detect)
    out = det(img, (4, 3))
    assert not bool(out.found[0]) and "skips" in out.reasons[0] and not bool(out.corners.any())
    # the true 4x3 lattice of a 4x3 board passes (a 4x3 corner of the 8x6 board above does not: its pattern
    # continues past two sides)
    small, whole = _checker(square=16, cols=4, rows=3)

    def detect_whole(images, board_size, fallbacks):
        return DetectionResult(corners=whole[None].clone(), found=torch.tensor([True]), reasons=["learned"])

    monkeypatch.setattr(det, "_detect", detect_whole)
    assert bool(det(small, (4, 3)).found[0])
    sub = corners.reshape(6, 8, 2)[:3, :4].reshape(-1, 2)

    def detect_sub(images, board_size, fallbacks):
        return DetectionResult(corners=sub[None].clone(), found=torch.tensor([True]), reasons=["learned"])

    monkeypatch.setattr(det, "_detect", detect_sub)
    assert not bool(det(img, (4, 3)).found[0])
