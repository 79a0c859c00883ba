"""AprilGrid (Kalibr's target): its corner numbering and object points, the detector on rendered views with exact
corners (whole, cut by the frame, white-on-black, seen from its back), no wrong id, and OpenCV's tag corners as the
baseline the refinement must beat."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.marker_views import render_condition
from ccs_kornia.modules.detection.boards import AprilGrid, grid_object_points
from ccs_kornia.modules.detection.markers.aprilgrid import (
    AprilGridDetector,
    aprilgrid_tags,
    detect_aprilgrid,
    tag_detector,
)

GRID = AprilGrid(6, 6, 0.088, 0.3)


def kalibr_points(tag_rows: int, tag_cols: int, size: float, spacing: float) -> np.ndarray:
    """Kalibr's createGridPoints, written out as its loops are."""
    rows, cols = 2 * tag_rows, 2 * tag_cols
    out = np.zeros((rows * cols, 3))
    for r in range(rows):
        for c in range(cols):
            out[r * cols + c] = [(c // 2) * (1 + spacing) * size + (c % 2) * size,
                                 (r // 2) * (1 + spacing) * size + (r % 2) * size, 0.0]
    return out


def views(condition: str, count: int, seed: int):
    rng = np.random.default_rng(seed)
    pairs = [render_condition(GRID, condition, rng, supersample=2) for _ in range(count)]
    images = torch.from_numpy(np.stack([p[0] for p in pairs])).float()[:, None] / 255
    return images, torch.from_numpy(np.stack([p[1] for p in pairs])).float()


class TestBoard:
    def test_object_points_are_kalibrs(self):
        for grid in (GRID, AprilGrid(3, 2, 0.05, 0.25)):
            want = kalibr_points(grid.tag_rows, grid.tag_cols, grid.tag_size, grid.tag_spacing)
            assert np.allclose(grid.object_points().numpy(), want)

    def test_tag_corner_ids(self):
        # Kalibr's 2x2 example: tag 0 has 0, 1, 5, 4; tag 3 has 10, 11, 15, 14
        grid = AprilGrid(2, 2, 1.0, 0.5)
        assert grid.tag_corner_ids(0) == (0, 1, 5, 4) and grid.tag_corner_ids(3) == (10, 11, 15, 14)
        ids = sorted(i for t in range(GRID.num_tags) for i in GRID.tag_corner_ids(t))
        assert ids == list(range(GRID.num_corners))

    def test_from_yaml(self, tmp_path):
        path = tmp_path / "april.yaml"
        path.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n")
        assert AprilGrid.from_yaml(str(path)) == GRID

    @pytest.mark.parametrize("text, match", [
        ("target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7\n", "expected 'aprilgrid'"),
        ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\n", "missing tagSpacing"),
        ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: -1\ntagSpacing: 0.3\n", "tagSize"),
        ("target_type: 'aprilgrid'\ntagCols: 30\ntagRows: 30\ntagSize: 0.01\ntagSpacing: 0.3\n", "more than"),
    ])
    def test_from_yaml_exceptions(self, tmp_path, text, match):
        path = tmp_path / "t.yaml"
        path.write_text(text)
        with pytest.raises(ValueError, match=match):
            AprilGrid.from_yaml(str(path))

    def test_grid_object_points(self):
        assert torch.equal(grid_object_points(GRID, GRID.board_size, 1.0), GRID.object_points())
        with pytest.raises(ValueError, match="is not the AprilGrid.s grid"):
            grid_object_points(GRID, (4, 4), 1.0)

    def test_print_ids_and_corners(self):
        # OpenCV's tag ids on the print, and the map from object points onto it, put every tag corner where its
        # corner id's object point lands
        art, a = GRID.texture(8)
        corners, ids, _ = tag_detector(GRID).detectMarkers(art)
        assert sorted(ids.reshape(-1).tolist()) == list(range(GRID.num_tags))
        pix = GRID.object_points().numpy()[:, :2] @ a[:, :2].T + a[:, 2]
        for c, t in zip(corners, ids.reshape(-1)):
            want = pix[list(GRID.tag_corner_ids(int(t)))]
            got = c.reshape(4, 2)
            assert np.linalg.norm(want[:, None] - got[None], axis=-1).min(1).max() < 3


class TestDetector:
    def test_smoke_and_shapes(self):
        det = AprilGridDetector(GRID)
        out = det(torch.zeros(2, 1, 48, 64), GRID.board_size)
        assert out.corners.shape == (2, 144, 2) and out.found.tolist() == [False, False]
        assert all("no two" in r for r in out.reasons)

    def test_exceptions(self):
        with pytest.raises(ValueError, match="corner grid"):
            AprilGridDetector(GRID)(torch.zeros(1, 1, 32, 32), (4, 4))
        with pytest.raises(ValueError, match="grey images"):
            detect_aprilgrid(torch.zeros(1, 3, 32, 32), GRID)

    @pytest.mark.parametrize("condition", ["clean", "partial", "inverted", "mirrored"])
    def test_renders_exact_ids(self, condition):
        images, truth = views(condition, 3, seed=11)
        out = detect_aprilgrid(images, GRID, num_workers=1)
        assert out.found.all(), out.reasons
        valid = out.valid
        err = (out.corners - truth).norm(dim=-1)[valid]
        assert torch.isfinite(err).all()  # no accepted corner outside the image
        assert (err < 1.0).all(), f"a wrong id: {err.max():.2f} px"  # the next corner id is a tag side away
        assert err.median() < 0.05
        seen = truth.isfinite().all(-1)
        assert valid.sum() >= 0.8 * seen.sum()

    def test_better_than_opencv_tag_corners(self):
        # the baseline: OpenCV's tag corners refined by cornerSubPix (as Kalibr refines its tag corners)
        images, truth = views("clean", 2, seed=3)
        ours = (detect_aprilgrid(images, GRID, num_workers=1).corners - truth).norm(dim=-1)
        theirs = []
        for k in range(images.shape[0]):
            gray = (images[k, 0] * 255).round().byte().numpy()
            tags = aprilgrid_tags(gray, GRID)
            pts = tags.corners.reshape(-1, 1, 2).astype(np.float32)
            cv2.cornerSubPix(gray, pts, (2, 2), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1))
            ids = np.concatenate([np.array(GRID.tag_corner_ids(int(t)))[[1, 0, 3, 2]] for t in tags.ids])
            theirs.append(np.linalg.norm(pts.reshape(-1, 2) - truth[k].numpy()[ids], axis=-1))
        theirs = np.concatenate(theirs)
        assert float(ours[ours.isfinite()].median()) < float(np.nanmedian(theirs))

    def test_batch_matches_single(self):
        images, _ = views("partial", 2, seed=5)
        both = detect_aprilgrid(images, GRID, num_workers=1)
        one = detect_aprilgrid(images[1:], GRID, num_workers=1)
        assert torch.allclose(both.corners[1:].nan_to_num(-1), one.corners.nan_to_num(-1))
