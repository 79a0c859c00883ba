"""Marker boards benchmark: ChArUco and AprilGrid corners against OpenCV's detectors, on renders and real photographs.

* **renders** (:func:`~ccs_kornia.data.scenes.marker_views.render_condition`, 640 x 480, k1 = -0.28, seeds from
  :data:`SEED`) per condition (clean, partial: cut by the frame, low light, blur, inverted: white-on-black,
  mirrored: seen from its back, strong blur, small: the board far away, noise):

  - a ChArUco board of 6 x 8 squares (``DICT_6X6_250``; an even number of rows, so OpenCV's legacy layout differs:
    each view is printed in one of the two layouts at random): ours (:func:`~ccs_kornia.modules.detection.markers.
    charuco.charuco_paths`, layout found per view; one call per print, as a user's set holds one print, since a view
    the two layouts tie on takes the layout the call's other views vote for) by its marker path, its lattice path and both merged (ours, the
    default) against ``cv2.aruco.CharucoDetector`` with ``setLegacyPattern(False)`` and ``(True)`` (default
    parameters, as its users run it) and the better of the two per view ("told the layout");
  - Kalibr's AprilGrid 6 x 6 (``tagSpacing`` 0.3): ours (:func:`~ccs_kornia.modules.detection.markers.aprilgrid.
    aprilgrid_paths`), its two paths and both merged, against OpenCV's tag corners (``DICT_APRILTAG_36h11``, two
    border bits) refined by ``cv2.cornerSubPix`` (2, 2) as Kalibr refines its tag corners, ids as decoded (no
    lattice check: Kalibr has none).

  Per method: views posed (at least 6 corners with right ids: a pose can be fitted), the fraction of the visible
  corners found with their right id, wrong ids (a corner farther than :data:`WRONG_PX` from its id's true position, or
  than half the distance to the nearest other true corner where that is less), and the corner error (mean and median
  px over the corners with a right id); and the camera calibrated from the condition's first views by each method's
  corners (``cv2.calibrateCamera``, the renders' own 5-coefficient model, the same solver for every method): the
  error of fx.
* **calibration from partial views**: sets of views of the ChArUco board, every one cut by the frame; ours
  (:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` on our corners) against ``cv2.calibrateCamera`` on
  CharucoDetector's corners (told the layout), both with the rational model (k1..k6) on the wide-angle lens: the
  error of fx and the RMS.
* **timing**: seconds per view of the marker path alone and of both paths (the default) on clean renders.
* **real**: ``charuco_opencv_tutorial`` (4 views and one occluded view) and ``caliscope_4cam_charuco`` (white-on-black,
  cam_1 sees the mirrored back): corners per camera, ours (both paths) and the marker path alone against
  CharucoDetector (default, and told the print's variant); where both find an id, how far apart (mean px, and how
  many more than 3 px apart: one of the two ids is wrong); and our corners off their view's lattice (more than a
  third of a square from a homography of their neighbours: a wrong id).
"""

from __future__ import annotations

import glob
import math
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.data.scenes.marker_views import (
    CONDITIONS,
    K,
    random_board_pose,
    render_condition,
    render_marker_view,
)
from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard
from ccs_kornia.modules.detection.markers.aprilgrid import aprilgrid_paths, tag_detector
from ccs_kornia.modules.detection.markers.charuco import charuco_paths, detect_charuco
from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths

__all__ = ["APRILGRID", "CHARUCO", "CONDITION_CALIB_VIEWS", "MIN_POSED", "REAL_SETS", "SEED", "TIMING_VIEWS",
           "WRONG_PX", "markers_md", "run_markers"]

#: first seed of the renders (the tests use seeds below 1000)
SEED = 700_000
#: the rendered ChArUco board (6 x 8 squares: the legacy layout differs) and AprilGrid
CHARUCO = CharucoBoard(6, 8, 0.035, 0.0175, "DICT_6X6_250")
APRILGRID = AprilGrid(6, 6, 0.088, 0.3)
#: a view is posed with at least this many corners
MIN_POSED = 6
#: a corner farther than this (px) from its id's true position has a wrong id
WRONG_PX = 3.0
#: views of each condition the camera is calibrated from (fewer views: no calibration)
CONDITION_CALIB_VIEWS = 12
#: clean views timed per board (one batch)
TIMING_VIEWS = 8
#: our paths: key in the results -> the path
OUR_PATHS = {"ours": MarkerPaths.BOTH, "marker_path": MarkerPaths.MARKERS, "lattice_path": MarkerPaths.LATTICE}
#: the real sets: board, files per camera (glob patterns), OpenCV's variants to try when told (inverted, mirrored)
REAL_SETS = {
    "charuco_opencv_tutorial": (CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250"),
                                {"cam": ("img_*.jpg", "partial/chocclusion_original.jpg")}, ((False, False),)),
    "caliscope_4cam_charuco": (CharucoBoard(4, 5, 0.054, 0.0405, "DICT_4X4_1000"),
                               {f"cam_{c}": (f"cam_{c}/*.jpg",) for c in range(4)},
                               ((False, False), (True, False), (False, True), (True, True))),
    "ric_charuco_eye_to_hand": (CharucoBoard(5, 7, 0.036195, 0.018256, "DICT_6X6_250"), {"cam": ("images/*.png",)},
                                ((False, False),)),
}


def _opencv_charuco(board: CharucoBoard, image: np.ndarray, legacy: bool, inverted: bool = False,
                    mirrored: bool = False) -> np.ndarray:
    """``cv2.aruco.CharucoDetector``'s corners ``(N, 2)`` by id (NaN where missing) on an image variant."""
    src = cv2.flip(image, 1) if mirrored else image
    src = 255 - src if inverted else src
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.cv2_board(legacy)).detectBoard(src)
    out = np.full((board.num_corners, 2), np.nan)
    if ids is not None and len(ids):
        pts = corners.reshape(-1, 2).astype(np.float64)
        if mirrored:
            pts[:, 0] = image.shape[1] - 1 - pts[:, 0]
        out[ids.reshape(-1)] = pts
    return out


def _opencv_aprilgrid(board: AprilGrid, image: np.ndarray) -> np.ndarray:
    """OpenCV's tag corners refined by ``cornerSubPix`` (2, 2), by Kalibr's corner id (NaN where missing)."""
    corners, ids, _ = tag_detector(board).detectMarkers(image)
    out = np.full((board.num_corners, 2), np.nan)
    if ids is None:
        return out
    for c, t in zip(corners, ids.reshape(-1)):
        if not 0 <= int(t) < board.num_tags:
            continue
        pts = c.reshape(-1, 1, 2).astype(np.float32)
        cv2.cornerSubPix(image, pts, (2, 2), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1))
        bl, br, tr, tl = board.tag_corner_ids(int(t))
        out[[br, bl, tl, tr]] = pts.reshape(4, 2)  # OpenCV's corner order on Kalibr's print
    return out


def _score(found: np.ndarray, truth: np.ndarray) -> dict:
    """Corners ``found`` ``(N, 2)`` (NaN: none) of one view against the ``truth``: counts, wrong ids, errors."""
    seen = np.isfinite(found).all(-1)
    ok = np.isfinite(truth).all(-1)
    t = truth[ok]
    d = np.linalg.norm(t[:, None] - t[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    nearest = np.full(len(truth), np.inf)
    nearest[ok] = d.min(1) if len(t) > 1 else np.inf
    err = np.linalg.norm(found - np.nan_to_num(truth, nan=-1e9), axis=-1)
    wrong = seen & (~ok | (err > np.minimum(WRONG_PX, 0.5 * nearest)))
    right = seen & ~wrong
    return {"corners": int(seen.sum()), "wrong": int(wrong.sum()), "visible": int(ok.sum()),
            "errors": err[right].tolist()}


def _summary(scores: list[dict]) -> dict:
    errors = np.array([e for s in scores for e in s["errors"]])
    views = max(len(scores), 1)
    visible = sum(s.get("visible", 0) for s in scores)
    return {
        "views": len(scores),
        "posed": sum(s["corners"] - s["wrong"] >= MIN_POSED for s in scores),
        "corners_per_view": sum(s["corners"] for s in scores) / views,
        "found_fraction": float(errors.size / visible) if visible else math.nan,
        "wrong_ids": sum(s["wrong"] for s in scores),
        "corners": sum(s["corners"] for s in scores),
        "mean_error_px": float(errors.mean()) if errors.size else math.nan,
        "median_error_px": float(np.median(errors)) if errors.size else math.nan,
    }


def _calibrate(corners: list[np.ndarray], obj: np.ndarray, size: tuple[int, int]) -> float:
    """fx error (%) of ``cv2.calibrateCamera`` (the renders' 5-coefficient model) from each view's corners ``(N, 2)``
    (NaN: none) with the board's object points ``(N, 3)``; NaN with fewer than 4 views posed or where it fails."""
    objs, imgs = [], []
    for c in corners:
        seen = np.isfinite(c).all(-1)
        if seen.sum() >= MIN_POSED:
            objs.append(obj[seen].astype(np.float32))
            imgs.append(c[seen].astype(np.float32))
    if len(objs) < 4:
        return math.nan
    try:
        _, k, *_ = cv2.calibrateCamera(objs, imgs, size, None, None)
    except cv2.error:
        return math.nan
    return abs(float(k[0, 0]) - K[0, 0]) / K[0, 0] * 100.0


def _tensor(images: list[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(images)).float()[:, None] / 255.0


def _charuco_condition(cfg, condition: str, n: int, seed: int, log) -> dict:
    rng = np.random.default_rng(seed)
    methods = (*OUR_PATHS, "opencv_new", "opencv_legacy", "opencv_told")
    scores = {m: [] for m in methods}
    kept = {m: [] for m in methods}  # the first views' corners, for the calibration
    batch = 8
    for start in range(0, n, batch):
        images, truths, layouts = [], [], []
        for _ in range(min(batch, n - start)):
            legacy = bool(rng.random() < 0.5)
            image, truth = render_condition(CHARUCO, condition, rng, supersample=cfg.supersample, legacy=legacy)
            images.append(image)
            truths.append(truth)
            layouts.append(legacy)
        # one call per print: the detector takes a call's views as one board, whose layout the views that tell the
        # two apart vote for (a view the layouts tie on takes it), so views of the two layouts go in separate calls
        ours = {}
        for layout in (False, True):
            idx = [k for k, legacy in enumerate(layouts) if legacy == layout]
            if idx:
                got = charuco_paths(_tensor([images[k] for k in idx]), CHARUCO, min_corners=MIN_POSED, num_workers=1)
                ours.update({k: {path: (res.corners[j], bool(res.found[j])) for path, res in got.items()}
                             for j, k in enumerate(idx)})
        for k, (image, truth, legacy) in enumerate(zip(images, truths, layouts)):
            got = {}
            for key, path in OUR_PATHS.items():
                corners, found = ours[k][path]
                got[key] = corners.double().numpy() if found else np.full_like(truth, np.nan)
            new, old = _opencv_charuco(CHARUCO, image, False), _opencv_charuco(CHARUCO, image, True)
            got.update(opencv_new=new, opencv_legacy=old, opencv_told=old if legacy else new)
            for m in methods:
                scores[m].append(_score(got[m], truth))
                if len(kept[m]) < CONDITION_CALIB_VIEWS:
                    kept[m].append(got[m])
    log(f"[bench] markers: charuco {condition}: {n} views, ours {sum(s['corners'] for s in scores['ours'])} corners")
    obj = CHARUCO.object_points().numpy()
    return {m: {**_summary(s), "fx_error_pct": _calibrate(kept[m], obj, (640, 480))} for m, s in scores.items()}


def _aprilgrid_condition(cfg, condition: str, n: int, seed: int, log) -> dict:
    rng = np.random.default_rng(seed)
    methods = (*OUR_PATHS, "opencv_subpix")
    scores = {m: [] for m in methods}
    kept = {m: [] for m in methods}
    batch = 8
    for start in range(0, n, batch):
        pairs = [render_condition(APRILGRID, condition, rng, supersample=cfg.supersample)
                 for _ in range(min(batch, n - start))]
        ours = aprilgrid_paths(_tensor([p[0] for p in pairs]), APRILGRID, min_corners=MIN_POSED, num_workers=1)
        for k, (image, truth) in enumerate(pairs):
            got = {}
            for key, path in OUR_PATHS.items():
                res = ours[path]
                got[key] = res.corners[k].double().numpy() if bool(res.found[k]) else np.full_like(truth, np.nan)
            got["opencv_subpix"] = _opencv_aprilgrid(APRILGRID, image)
            for m in methods:
                scores[m].append(_score(got[m], truth))
                if len(kept[m]) < CONDITION_CALIB_VIEWS:
                    kept[m].append(got[m])
    log(f"[bench] markers: aprilgrid {condition}: {n} views")
    obj = APRILGRID.object_points().numpy()
    return {m: {**_summary(s), "fx_error_pct": _calibrate(kept[m], obj, (640, 480))} for m, s in scores.items()}


def _calibration_trial(cfg, views: int, seed: int) -> dict:
    """One set of partial ChArUco views (new layout), calibrated by ours and by OpenCV (rational model)."""
    from ccs_kornia.geometry.models import RATIONAL
    from ccs_kornia.modules.detection.markers.charuco import CharucoDetector
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    rng = np.random.default_rng(seed)
    board = CharucoBoard(CHARUCO.squares_x, CHARUCO.squares_y, CHARUCO.square, CHARUCO.marker, CHARUCO.dictionary,
                         legacy=False)
    images = []
    for _ in range(views):
        rvec, tvec = random_board_pose(board, rng, partial=True)
        images.append(render_marker_view(board, rvec, tvec, supersample=cfg.supersample, legacy=False)[0])
    size = (images[0].shape[1], images[0].shape[0])
    out: dict = {}
    det = detect_charuco(_tensor(images), board, num_workers=1)
    pipe = CalibrationPipeline(CharucoDetector(board), model=RATIONAL, distortion_correction=False,
                               diagnostics=False, use_ransac=False)
    try:
        cal = pipe.calibrate(det.corners.double(), det.found, board.board_size, board.square, size)
        ok = bool(torch.as_tensor(cal.success).all())
        fx = float(cal.K.reshape(-1, 3, 3)[0, 0, 0])
        out["ours"] = {"fx": fx if ok else math.nan, "rms": float(torch.as_tensor(cal.rms).reshape(-1)[0]),
                       "views": int(det.found.sum())}
    except (ValueError, RuntimeError) as err:
        out["ours"] = {"fx": math.nan, "rms": math.nan, "views": int(det.found.sum()), "error": str(err)}
    obj_all = board.object_points().numpy().astype(np.float32)
    objs, imgs = [], []
    for image in images:
        c = _opencv_charuco(board, image, False)
        seen = np.isfinite(c).all(-1)
        if seen.sum() >= MIN_POSED:
            objs.append(obj_all[seen])
            imgs.append(c[seen].astype(np.float32))
    try:
        rms, k, *_ = cv2.calibrateCamera(objs, imgs, size, None, None, flags=cv2.CALIB_RATIONAL_MODEL)
        out["opencv"] = {"fx": float(k[0, 0]), "rms": float(rms), "views": len(objs)}
    except cv2.error as err:
        out["opencv"] = {"fx": math.nan, "rms": math.nan, "views": len(objs), "error": str(err).splitlines()[0]}
    for m in out.values():
        m["fx_error_pct"] = abs(m["fx"] - K[0, 0]) / K[0, 0] * 100.0
    return out


def _off_lattice(corners: np.ndarray, board: CharucoBoard) -> int:
    """Corners ``(N, 2)`` (NaN: none) more than a third of a square from where a homography of the found corners
    within two squares of them puts them (at least five): a wrong id moves a corner a whole square."""
    obj = board.object_points().numpy()[:, :2] / float(board.square)
    seen = np.flatnonzero(np.isfinite(corners).all(-1))
    off = 0
    for i in seen:
        near = seen[(np.abs(obj[seen] - obj[i]).max(-1) <= 2.0) & (seen != i)]
        if len(near) < 5:
            continue
        h, _ = cv2.findHomography(obj[near], corners[near], 0)
        if h is None:
            continue
        q = h @ np.append(obj[i], 1.0)
        p = q[:2] / q[2]
        step = np.linalg.norm(cv2.perspectiveTransform(np.array([[obj[i], obj[i] + [1.0, 0.0]]]), h)[0, 1] - p)
        off += int(np.linalg.norm(p - corners[i]) > step / 3.0)
    return off


def _real_set(root: Path, name: str) -> dict | None:
    board, cameras, variants = REAL_SETS[name]
    folder = root / name
    if not folder.is_dir():
        return None
    out = {}
    for cam, patterns in cameras.items():
        files = sorted(f for p in patterns for f in glob.glob(str(folder / p)))
        images = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in files]
        images = [im for im in images if im is not None]
        if not images:
            continue
        sizes = {im.shape for im in images}
        row = {"images": len(images), "opencv": 0, "opencv_posed": 0, "opencv_told": 0, "opencv_told_posed": 0}
        for key in ("ours", "marker_path"):
            row.update({key: 0, f"{key}_posed": 0, f"{key}_disagree": 0, f"{key}_both": 0, f"{key}_apart_px": 0.0,
                        f"{key}_off_lattice": 0})
        for shape in sizes:
            group = [im for im in images if im.shape == shape]
            det = charuco_paths(_tensor(group), board, num_workers=1, paths=(MarkerPaths.BOTH, MarkerPaths.MARKERS))
            for k, image in enumerate(group):
                plain = _opencv_charuco(board, image, False)
                told = max((_opencv_charuco(board, image, False, i, m) for i, m in variants),
                           key=lambda c: int(np.isfinite(c).all(-1).sum()))
                n_plain, n_told = (int(np.isfinite(c).all(-1).sum()) for c in (plain, told))
                row["opencv"] += n_plain
                row["opencv_posed"] += n_plain >= MIN_POSED
                row["opencv_told"] += n_told
                row["opencv_told_posed"] += n_told >= MIN_POSED
                for key, path in (("ours", MarkerPaths.BOTH), ("marker_path", MarkerPaths.MARKERS)):
                    res = det[path]
                    mine = res.corners[k].double().numpy() if bool(res.found[k]) else \
                        np.full((board.num_corners, 2), np.nan)
                    n_mine = int(np.isfinite(mine).all(-1).sum())
                    row[key] += n_mine
                    row[f"{key}_posed"] += n_mine >= MIN_POSED
                    both = np.isfinite(mine).all(-1) & np.isfinite(told).all(-1)
                    apart = np.linalg.norm(mine[both] - told[both], axis=-1)
                    row[f"{key}_both"] += int(both.sum())
                    row[f"{key}_disagree"] += int((apart > 3.0).sum())
                    row[f"{key}_apart_px"] += float(apart[apart <= 3.0].sum())
                    row[f"{key}_off_lattice"] += _off_lattice(mine, board)
        for key in ("ours", "marker_path"):
            agree = row[f"{key}_both"] - row[f"{key}_disagree"]
            row[f"{key}_apart_px"] = row[f"{key}_apart_px"] / agree if agree else math.nan
        out[cam] = row
    return out


def run_markers(cfg, log=print) -> dict:
    """The section (see the module doc); sizes from ``cfg.markers_views`` (ChArUco views per condition),
    ``cfg.markers_aprilgrid_views``, ``cfg.markers_calib_trials`` x ``cfg.markers_calib_views`` and
    ``cfg.markers_real_sets``."""
    t0 = time.perf_counter()
    sec: dict = {"charuco": {}, "aprilgrid": {}, "calibration": [], "real": {}, "conditions": list(CONDITIONS),
                 "boards": {"charuco": "6x8 squares, DICT_6X6_250, marker/square 0.5, layout random per view",
                            "aprilgrid": "6x6 tags 36h11, tagSpacing 0.3"}}
    for k, condition in enumerate(CONDITIONS):
        sec["charuco"][condition] = _charuco_condition(cfg, condition, cfg.markers_views, SEED + 1000 * k, log)
    for k, condition in enumerate(CONDITIONS):
        sec["aprilgrid"][condition] = _aprilgrid_condition(cfg, condition, cfg.markers_aprilgrid_views,
                                                           SEED + 50_000 + 1000 * k, log)
    for t in range(cfg.markers_calib_trials):
        sec["calibration"].append(_calibration_trial(cfg, cfg.markers_calib_views, SEED + 90_000 + t))
        log(f"[bench] markers: calibration trial {t + 1}/{cfg.markers_calib_trials}")
    from ccs_kornia.bench.sections.real import default_real_dir

    root = Path(cfg.real_dir) if cfg.real_dir else default_real_dir()
    for name in cfg.markers_real_sets:
        got = _real_set(root, name)
        sec["real"][name] = got if got is not None else {"skipped": f"not present under {root}"}
        log(f"[bench] markers: real {name}")
    sec["timing"] = _timing(cfg)
    log("[bench] markers: timing")
    sec["views_rendered"] = len(CONDITIONS) * (cfg.markers_views + cfg.markers_aprilgrid_views) + \
        cfg.markers_calib_trials * cfg.markers_calib_views + 2 * sec["timing"]["views"]
    sec["run_seconds"] = time.perf_counter() - t0
    return sec


def _timing(cfg) -> dict:
    """Seconds per view of each board's detection by the marker path alone and by both paths (the default), on
    :data:`TIMING_VIEWS` clean renders in one batch (fewer in small configurations), after one warm-up call."""
    from ccs_kornia.modules.detection.markers.aprilgrid import detect_aprilgrid

    rng = np.random.default_rng(SEED + 95_000)
    views = max(1, min(TIMING_VIEWS, 4 * cfg.markers_views))
    out = {"views": views}
    for name, board, detect in (("charuco", CHARUCO, detect_charuco), ("aprilgrid", APRILGRID, detect_aprilgrid)):
        x = _tensor([render_condition(board, "clean", rng, supersample=cfg.supersample)[0] for _ in range(views)])
        detect(x[:1], board, num_workers=1)
        for path in (MarkerPaths.MARKERS, MarkerPaths.BOTH):
            t = time.perf_counter()
            detect(x, board, num_workers=1, paths=path)
            out[f"{name}_{path.value}_s_per_view"] = (time.perf_counter() - t) / views
    return out


_LABELS = {"ours": "ours", "marker_path": "ours, marker path", "lattice_path": "ours, lattice path",
           "opencv_new": "CharucoDetector (legacy off)", "opencv_legacy": "CharucoDetector (legacy on)",
           "opencv_told": "CharucoDetector (told the layout)", "opencv_subpix": "OpenCV tags + cornerSubPix (Kalibr)"}


def _fmt(x: float, digits: int = 3) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _pct(x: float | None) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100.0 * x:.1f} %"


def markers_md(sec: dict) -> list[str]:
    """The section's markdown lines."""
    lines: list[str] = []
    for kind, title in (("charuco", f"ChArUco ({sec['boards']['charuco']})"),
                        ("aprilgrid", f"AprilGrid ({sec['boards']['aprilgrid']})")):
        rows = sec.get(kind) or {}
        if not rows:
            continue
        lines += [f"Renders, {title}: views posed (>= {MIN_POSED} corners with right ids), visible corners found with "
                  f"their right id, corners per view, wrong ids (> {WRONG_PX:g} px from the id's true corner), corner "
                  f"error (px, right ids), fx error of the camera calibrated from the first {CONDITION_CALIB_VIEWS} "
                  "views (cv2.calibrateCamera on each method's corners).", "",
                  "| condition | method | views | posed | found | corners/view | wrong ids | mean err | median err "
                  "| fx error |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for condition, methods in rows.items():
            for m, s in methods.items():
                fx = s.get("fx_error_pct", math.nan)
                lines.append(f"| {condition} | {_LABELS.get(m, m)} | {s['views']} | {s['posed']} | "
                             f"{_pct(s.get('found_fraction'))} | {s['corners_per_view']:.1f} | {s['wrong_ids']} | "
                             f"{_fmt(s['mean_error_px'])} | {_fmt(s['median_error_px'])} | "
                             f"{'n/a' if math.isnan(fx) else f'{fx:.3f} %'} |")
        total = sum(methods["ours"]["views"] for methods in rows.values())
        wrong = {m: sum(methods[m]["wrong_ids"] for methods in rows.values() if m in methods) for m in OUR_PATHS}
        lines += ["", f"Ours over all {total} {kind} views: {wrong['ours']} wrong ids (marker path "
                      f"{wrong['marker_path']}, lattice path {wrong['lattice_path']}).", ""]
    trials = sec.get("calibration") or []
    if trials:
        lines += ["Calibration from partial views (every view cut by the frame; rational model; true fx 520):", "",
                  "| method | trials | median fx error | worst fx error | median RMS px | views used (mean) |",
                  "|---|---|---|---|---|---|"]
        for m, label in (("ours", "ours"), ("opencv", "cv2.calibrateCamera on CharucoDetector's corners")):
            errs = np.array([t[m]["fx_error_pct"] for t in trials], dtype=float)
            rms = np.array([t[m]["rms"] for t in trials], dtype=float)
            used = np.mean([t[m]["views"] for t in trials])
            worst = "failed" if np.isnan(errs).any() else f"{np.nanmax(errs):.3f} %"
            lines.append(f"| {label} | {len(trials)} | {_fmt(float(np.nanmedian(errs)))} % | {worst} | "
                         f"{_fmt(float(np.nanmedian(rms)))} | {used:.1f} |")
        lines.append("")
    timing = sec.get("timing") or {}
    if timing:
        lines += [f"Time per view ({timing['views']} clean 640x480 renders in one batch): ChArUco "
                  f"{_fmt(timing['charuco_markers_s_per_view'])} s by the marker path alone, "
                  f"{_fmt(timing['charuco_both_s_per_view'])} s by both paths; AprilGrid "
                  f"{_fmt(timing['aprilgrid_markers_s_per_view'])} s and "
                  f"{_fmt(timing['aprilgrid_both_s_per_view'])} s.",
                  ""]
    for name, cams in (sec.get("real") or {}).items():
        if "skipped" in cams:
            lines += [f"Real `{name}`: skipped ({cams['skipped']}).", ""]
            continue
        lines += [f"Real `{name}`: corners (views posed) per camera; where ours and CharucoDetector (told the variant) "
                  "both find an id: the mean distance between the two (px, those within 3 px), and how many are more "
                  "than 3 px apart; ours off the view's lattice (a third of a square from a homography of their "
                  "neighbours).", "",
                  "| camera | images | ours | marker path | CharucoDetector | CharucoDetector told the variant | "
                  "apart: ours | apart: marker path | off lattice: ours / marker path |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for cam, r in cams.items():
            lines.append(f"| {cam} | {r['images']} | {r['ours']} ({r['ours_posed']}) | {r['marker_path']} "
                         f"({r['marker_path_posed']}) | {r['opencv']} ({r['opencv_posed']}) | {r['opencv_told']} "
                         f"({r['opencv_told_posed']}) | {_fmt(r['ours_apart_px'])} px, {r['ours_disagree']} / "
                         f"{r['ours_both']} | {_fmt(r['marker_path_apart_px'])} px, {r['marker_path_disagree']} / "
                         f"{r['marker_path_both']} | {r['ours_off_lattice']} / {r['marker_path_off_lattice']} |")
        lines.append("")
    return lines
