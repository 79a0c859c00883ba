"""Tests of the ChArUco board and detector: OpenCV's ids and object points, corners against rendered truth and
against ``cv2.aruco.CharucoDetector``, partial / inverted / mirrored views, layouts, real photographs."""

from __future__ import annotations

import glob

import cv2
import numpy as np
import pytest
import torch
from _charuco_views import POSES, render_view
from _real_data import REAL_DATA

from ccs_kornia.modules.detection.base import ChessboardDetector, DetectionResult
from ccs_kornia.modules.detection.boards import (
    CharucoBoard,
    Chessboard,
    aruco_dictionary,
)
from ccs_kornia.modules.detection.markers.charuco import (
    CharucoDetector,
    charuco_markers,
    detect_charuco,
    dictionary_hint,
    marked_radius_factor,
)
from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths

BOARD = CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250")


def _tensor(*images: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.stack(images)).float()[:, None] / 255.0


def _opencv_corners(board: CharucoBoard, image: np.ndarray, inverted: bool = False, mirrored: bool = False
                    ) -> np.ndarray:
    """``cv2.aruco.CharucoDetector``'s corners (N, 2) by id (NaN where missing), told the variant."""
    src = cv2.flip(image, 1) if mirrored else image
    src = 255 - src if inverted else src
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.cv2_board(False)).detectBoard(src)
    out = np.full((board.num_corners, 2), np.nan)
    if ids is not None:
        pts = corners.reshape(-1, 2).astype(np.float64)
        if mirrored:
            pts[:, 0] = image.shape[1] - 1 - pts[:, 0]
        out[ids.reshape(-1)] = pts
    return out


def _wrong_ids(board: CharucoBoard, corners: np.ndarray, valid: np.ndarray) -> int:
    """Corners more than half a square off a homography fitted to all the view's corners (a wrong id lands a square
    or more away)."""
    obj = board.object_points().numpy()[valid, :2]
    pts = corners[valid].astype(np.float64)
    h, _ = cv2.findHomography(obj, pts, 0)
    fit = cv2.perspectiveTransform(obj[None], h)[0]
    step = cv2.perspectiveTransform(obj[None] + np.array([board.square, 0.0]), h)[0]
    square = np.linalg.norm(step - fit, axis=-1)
    return int((np.linalg.norm(fit - pts, axis=-1) > 0.5 * square).sum())


# ------------------------------------------------------------------------------------------------
# the board
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("squares, legacy", [((5, 7), False), ((4, 5), False), ((5, 6), True), ((6, 6), False)])
def test_object_points_are_opencvs(squares, legacy):
    board = CharucoBoard(*squares, 0.04, 0.03, "DICT_4X4_250", legacy=legacy)
    expected = board.cv2_board().getChessboardCorners()
    assert board.board_size == (squares[0] - 1, squares[1] - 1)
    assert board.object_points().shape == (board.num_corners, 3)
    np.testing.assert_allclose(board.object_points().numpy(), expected, atol=1e-7)


def test_chessboard_object_points():
    b = Chessboard(4, 3, 0.5)
    assert b.board_size == (4, 3)
    assert b.object_points()[5].tolist() == [0.5, 0.5, 0.0]


def test_board_exceptions():
    with pytest.raises(ValueError, match="smaller than the square"):
        CharucoBoard(5, 7, 0.04, 0.05)
    with pytest.raises(ValueError, match="at least 3x3"):
        CharucoBoard(2, 7, 0.04, 0.02)
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        aruco_dictionary("DICT_9X9_1")


def test_window_stays_clear_of_the_markers():
    # the polish window (1.5 x the saddle window) inside the band between the corner and the marker
    for marker in (0.02, 0.03, 0.0405):
        board = CharucoBoard(5, 7, 0.054 if marker == 0.0405 else 0.04, marker)
        band = 0.5 * (board.square - board.marker) / board.square
        assert 1.5 * marked_radius_factor(board) < band


# ------------------------------------------------------------------------------------------------
# the detector: interface, shapes, batch, exceptions
# ------------------------------------------------------------------------------------------------


def test_smoke_and_shapes():
    det = CharucoDetector(BOARD)
    assert isinstance(det, ChessboardDetector)
    out = det(_tensor(BOARD.render(60, margin=30)), BOARD.board_size)
    assert isinstance(out, DetectionResult)
    assert out.corners.shape == (1, 24, 2) and out.found.shape == (1,)
    assert out.found.tolist() == [True] and int(out.valid.sum()) == 24
    assert out.reasons[0].startswith("charuco: 17 DICT_6X6_250 markers")


def test_batch_equals_single_images():
    a, _ = render_view(BOARD, "whole")
    b, _ = render_view(BOARD, "bottom right")
    both = detect_charuco(_tensor(a, b), BOARD, num_workers=2)
    for k, img in enumerate((a, b)):
        one = detect_charuco(_tensor(img), BOARD)
        assert torch.equal(one.valid[0], both.valid[k])
        torch.testing.assert_close(one.corners[0][one.valid[0]], both.corners[k][both.valid[k]])


def test_not_found_and_exceptions():
    out = detect_charuco(torch.zeros(2, 1, 64, 80), BOARD)
    assert out.found.tolist() == [False, False]
    assert out.reasons[0] == "no DICT_6X6_250 marker of the board found"
    with pytest.raises(ValueError, match="inner grid"):
        CharucoDetector(BOARD)(torch.zeros(1, 1, 64, 64), (9, 6))
    with pytest.raises(ValueError, match="grey images"):
        detect_charuco(torch.zeros(1, 3, 64, 64), BOARD)
    with pytest.raises(ValueError, match="min_corners"):
        detect_charuco(torch.zeros(1, 1, 64, 64), BOARD, min_corners=0)


# ------------------------------------------------------------------------------------------------
# rendered views with exact corners
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rendered():
    """(pose, inverted, mirrored) -> (image, true corners, ours (corners, valid), OpenCV's corners)."""
    out = {}
    for pose in POSES:
        for inverted in (False, True):
            for mirrored in (False, True):
                image, truth = render_view(BOARD, pose, inverted=inverted, mirrored=mirrored)
                det = detect_charuco(_tensor(image), BOARD)
                ours = (det.corners[0].numpy().astype(np.float64), det.valid[0].numpy())
                out[pose, inverted, mirrored] = (image, truth, ours, _opencv_corners(BOARD, image, inverted, mirrored))
    return out


def test_rendered_ids_exact_and_partial_views_kept(rendered):
    for (pose, inverted, mirrored), (_, truth, (corners, valid), _) in rendered.items():
        assert valid.sum() >= 6, (pose, inverted, mirrored)
        assert np.isfinite(truth[valid]).all()  # no corner outside the image
        err = np.linalg.norm(corners[valid] - truth[valid], axis=-1)
        assert err.max() < 0.1, (pose, inverted, mirrored, err.max())  # a wrong id is a square (tens of px) off
        assert _wrong_ids(BOARD, corners, valid) == 0


def test_rendered_corners_beat_opencv(rendered):
    ours, theirs, n_ours, n_theirs = [], [], 0, 0
    for _, truth, (corners, valid), opencv in rendered.values():
        ours.append(np.linalg.norm(corners[valid] - truth[valid], axis=-1))
        seen = np.isfinite(opencv).all(-1)
        theirs.append(np.linalg.norm(opencv[seen] - truth[seen], axis=-1))
        n_ours, n_theirs = n_ours + valid.sum(), n_theirs + seen.sum()
    ours, theirs = np.concatenate(ours), np.concatenate(theirs)
    print(f"\nrendered corner error (px) ours mean {ours.mean():.4f} max {ours.max():.3f} on {n_ours} corners; "
          f"CharucoDetector mean {theirs.mean():.4f} max {theirs.max():.3f} on {n_theirs}")
    assert ours.mean() < theirs.mean() and ours.max() < theirs.max()
    assert n_ours >= n_theirs


def test_dark_view_read_on_its_stretched_copy():
    image = BOARD.render(60, margin=30)
    truth = detect_charuco(_tensor(image), BOARD, paths=MarkerPaths.MARKERS).corners[0].numpy()
    rng = np.random.default_rng(0)
    dark = np.clip(np.rint(image * 0.03 + rng.normal(0.0, 0.5, image.shape)), 0, 255).astype(np.uint8)
    plain = cv2.aruco.ArucoDetector(aruco_dictionary(BOARD.dictionary))
    assert len(plain.detectMarkers(dark)[0]) == 0  # a few grey levels: OpenCV's thresholds read no marker
    assert len(charuco_markers(dark, BOARD).ids) == 17
    det = detect_charuco(_tensor(dark), BOARD, paths=MarkerPaths.MARKERS)
    corners, valid = det.corners[0].numpy().astype(np.float64), det.valid[0].numpy()
    assert valid.sum() == 24
    assert np.linalg.norm(corners[valid] - truth[valid], axis=-1).max() < 0.5
    assert _wrong_ids(BOARD, corners, valid) == 0


def test_small_markers_read_on_a_further_enlarged_copy(monkeypatch):
    import ccs_kornia.modules.detection.markers.charuco as charuco

    board = CharucoBoard(5, 7, 0.04, 0.03, "DICT_4X4_50")
    small = cv2.resize(board.render(96, margin=48), None, fx=0.125, fy=0.125, interpolation=cv2.INTER_AREA)
    view = np.full((288, 512), 120, np.uint8)  # a board of 12 px squares in a larger view, a little soft
    view[40:40 + small.shape[0], 100:100 + small.shape[1]] = small
    view = cv2.GaussianBlur(view, (0, 0), 0.6)
    read = max(len(m.ids) for m in charuco.layout_fits(view, board).values())
    det = detect_charuco(_tensor(view), board, paths=MarkerPaths.MARKERS)
    monkeypatch.setattr(charuco, "small_marker_scale", lambda *args: 0.0)
    without = max(len(m.ids) for m in charuco.layout_fits(view, board).values())
    assert read > without > 0
    assert int(det.valid.sum()) > int(detect_charuco(_tensor(view), board, paths=MarkerPaths.MARKERS).valid.sum())
    assert _wrong_ids(board, det.corners[0].numpy().astype(np.float64), det.valid[0].numpy()) == 0


def test_motion_blurred_view_read_with_its_blur_undone(monkeypatch):
    import ccs_kornia.modules.detection.markers.charuco as charuco
    from ccs_kornia.modules.detection.motion_deblur import line_kernel

    image = BOARD.render(40, margin=20)
    truth = detect_charuco(_tensor(image), BOARD, paths=MarkerPaths.MARKERS).corners[0].numpy()
    blurred = cv2.filter2D(image, -1, line_kernel(15, 0.6), borderType=cv2.BORDER_REFLECT)
    markers = charuco_markers(blurred, BOARD)
    assert markers.motion is not None and abs(markers.motion[0] - 15) <= 1
    det = detect_charuco(_tensor(blurred), BOARD, paths=MarkerPaths.MARKERS)
    corners, valid = det.corners[0].numpy().astype(np.float64), det.valid[0].numpy()
    assert valid.sum() >= 20
    assert np.linalg.norm(corners[valid] - truth[valid], axis=-1).max() < 0.5
    assert _wrong_ids(BOARD, corners, valid) == 0
    monkeypatch.setattr(charuco, "motion_blur", lambda *args: None)
    assert len(charuco_markers(blurred, BOARD).ids) < len(markers.ids)
    assert int(detect_charuco(_tensor(blurred), BOARD, paths=MarkerPaths.MARKERS).valid.sum()) < valid.sum()


def test_blurred_view_read_on_copies_sharpened_harder(monkeypatch):
    import ccs_kornia.modules.detection.markers.charuco as charuco

    blurred = cv2.GaussianBlur(BOARD.render(40, margin=20), (0, 0), 1.7)
    read = len(charuco_markers(blurred, BOARD).ids)
    monkeypatch.setattr(charuco, "deblurring_copies", lambda *args: [])
    assert read > len(charuco_markers(blurred, BOARD).ids)


def test_corner_placed_beyond_the_narrow_window_refined_from_a_wider_one():
    from ccs_kornia.modules.detection.markers import marker_board

    img = torch.zeros(1, 1, 80, 80)
    img[..., :40, :40] = img[..., 40:, 40:] = 1.0
    img = torch.from_numpy(cv2.GaussianBlur(img[0, 0].numpy(), (0, 0), 2.0))[None, None]
    start = np.array([[[38.0, 38.5]]])  # 1.8 px off: beyond what the narrow window (2 px) confirms
    out, ok = marker_board.refine_marked_corners(img, start, np.array([[40.0]]), 0.05)
    assert bool(ok[0, 0]) and torch.allclose(out[0, 0], torch.tensor([39.5, 39.5]), atol=0.05)


def test_inverted_and_mirrored_views_name_their_variant():
    image, _ = render_view(BOARD, "whole", inverted=True, mirrored=True)
    markers = charuco_markers(image, BOARD)
    assert markers.variant == "mirrored inverted" and len(markers.ids) == 17


def test_legacy_layout_found_or_refused():
    board = CharucoBoard(5, 6, 0.04, 0.02, "DICT_5X5_100")  # an even number of rows: the layouts differ
    for printed in (False, True):
        image, truth = render_view(board, "whole", legacy=printed)
        auto = detect_charuco(_tensor(image), board)
        valid = auto.valid[0].numpy()
        assert valid.sum() == 20
        assert np.abs(auto.corners[0].numpy()[valid] - truth[valid]).max() < 0.1
        wrong = detect_charuco(_tensor(image), CharucoBoard(5, 6, 0.04, 0.02, "DICT_5X5_100", legacy=not printed))
        assert not bool(wrong.found[0]) and "layout better" in wrong.reasons[0]


def test_ambiguous_layout_takes_the_batchs():
    board = CharucoBoard(5, 6, 0.04, 0.02, "DICT_5X5_100")
    whole = board.render(60, margin=30, legacy=True)
    # the legacy print's first four columns of squares: their markers fit the new layout shifted by one square too
    part = whole.copy()
    part[:, 30 + 60 * 4 - 8:] = 255
    alone = charuco_markers(part, board)
    assert alone.ambiguous and not alone.off_lattice  # on the lattice in both layouts: not a wrong board size
    det = detect_charuco(_tensor(part), board)
    assert not bool(det.found[0]) and "layout alike" in det.reasons[0]
    together = detect_charuco(_tensor(whole, part), board)
    valid = together.valid[1].numpy()
    assert valid.sum() == 15
    cols, rows = board.board_size
    truth = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2) * 60.0 + 89.5
    assert np.abs(together.corners[1].numpy()[valid] - truth[valid]).max() < 0.1


def test_dictionary_hint():
    image, _ = render_view(BOARD, "whole")
    wrong = CharucoBoard(5, 7, 0.04, 0.02, "DICT_4X4_250")
    assert not bool(detect_charuco(_tensor(image), wrong).found[0])
    assert dictionary_hint([image], wrong) == ("no DICT_4X4_250 marker in any image; DICT_6X6_250 markers in 1 of "
                                              "them: wrong --dictionary?")


# ------------------------------------------------------------------------------------------------
# real photographs
# ------------------------------------------------------------------------------------------------


def _real(name: str) -> str:
    folder = REAL_DATA / name
    if not folder.is_dir():
        pytest.skip(f"real data set not present at {folder} (set CCS_REAL_DATA)")
    return str(folder)


def _counts(board: CharucoBoard, files: list[str], variants: tuple[tuple[bool, bool], ...]):
    images = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in files]
    det = detect_charuco(_tensor(*images), board, num_workers=1)
    ours = det.valid.sum(-1).tolist()
    theirs = [max(int(np.isfinite(_opencv_corners(board, img, i, m)).all(-1).sum()) for i, m in variants)
              for img in images]
    wrong = sum(_wrong_ids(board, det.corners[k].numpy(), det.valid[k].numpy())
                for k in range(len(files)) if int(det.valid[k].sum()) >= 4)
    return det, ours, theirs, wrong


def test_real_opencv_tutorial():
    folder = _real("charuco_opencv_tutorial")
    files = sorted(glob.glob(f"{folder}/img_*.jpg")) + [f"{folder}/partial/chocclusion_original.jpg"]
    det, ours, theirs, wrong = _counts(BOARD, files, ((False, False),))
    print(f"\ncharuco_opencv_tutorial corners per image: ours {ours}, CharucoDetector {theirs}; wrong ids {wrong}")
    assert wrong == 0
    assert all(o >= t for o, t in zip(ours, theirs)) and det.found.all()
    # the four whole views: OpenCV's calibration from our corners against the published camera (fx 452.5); the views
    # are nearly parallel (6 degrees apart, the package's solver refuses them), so fx is loosely bound: 457 from
    # CharucoDetector's corners, and with either detector's corners 280-475 as the distortion model changes
    obj = BOARD.object_points().numpy().astype(np.float32)
    rms, K, *_ = cv2.calibrateCamera([obj] * 4, [det.corners[k].numpy() for k in range(4)], (640, 480), None, None)
    print(f"fx from our corners {K[0, 0]:.1f} (reference 452.5), rms {rms:.3f} px")
    assert abs(K[0, 0] - 452.5) < 0.1 * 452.5


@pytest.mark.parametrize("camera", [0, 1, 2, 3])
def test_real_caliscope(camera):
    folder = _real("caliscope_4cam_charuco")
    board = CharucoBoard(4, 5, 0.054, 0.0405, "DICT_4X4_1000")
    files = sorted(glob.glob(f"{folder}/cam_{camera}/*.jpg"))
    # OpenCV told the print's variant: white-on-black, cam_1 sees the mirrored back
    variants = ((True, True),) if camera == 1 else ((True, False), (False, False))
    det, ours, theirs, wrong = _counts(board, files, variants)
    print(f"\ncam_{camera}: corners ours {sum(ours)} in {int(det.found.sum())} views, CharucoDetector {sum(theirs)} "
          f"in {sum(t >= 6 for t in theirs)}; wrong ids {wrong}")
    assert wrong == 0
    assert sum(ours) >= sum(theirs)
    assert sum(o >= t for o, t in zip(ours, theirs) if t >= 6) == sum(t >= 6 for t in theirs)
