"""Marker boards benchmark: ChArUco and AprilGrid corners against OpenCV's detectors, on renders and real photographs.

* **renders** (:func:`~ccs_kornia.data.marker_views.render_condition`, 640 x 480, k1 = -0.28, seeds from
  :data:`SEED`) per condition (clean, partial: cut by the frame, low light, blur, inverted: white-on-black,
  mirrored: seen from its back):

  - a ChArUco board of 6 x 8 squares (``DICT_6X6_250``; an even number of rows, so OpenCV's legacy layout differs:
    each view is printed in one of the two layouts at random): ours (:func:`~ccs_kornia.modules.detection.markers.charuco.
    detect_charuco`, layout found per view) against ``cv2.aruco.CharucoDetector`` with ``setLegacyPattern(False)``
    and ``(True)`` (default parameters, as its users run it) and the better of the two per view ("told the layout");
  - Kalibr's AprilGrid 6 x 6 (``tagSpacing`` 0.3): ours (:func:`~ccs_kornia.modules.detection.markers.aprilgrid.
    detect_aprilgrid`) against OpenCV's tag corners (``DICT_APRILTAG_36h11``, two border bits) refined by
    ``cv2.cornerSubPix`` (2, 2) as Kalibr refines its tag corners, ids as decoded (no lattice check: Kalibr has
    none).

  Per method: views posed (at least 6 corners with right ids: a pose can be fitted), corners per view, wrong ids (a corner farther
  from its id's true position than half the distance to the nearest other true corner: it is another corner), and
  the corner error (mean and median px over the corners with a right id).
* **calibration from partial views**: sets of views of the ChArUco board, every one cut by the frame; ours
  (:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` on our corners) against ``cv2.calibrateCamera`` on
  CharucoDetector's corners (told the layout), both with the rational model (k1..k6) on the wide-angle lens: the
  error of fx and the RMS.
* **real**: ``charuco_opencv_tutorial`` (4 views and one occluded view) and ``caliscope_4cam_charuco`` (white-on-black,
  cam_1 sees the mirrored back): corners per camera, ours against CharucoDetector (default, and told the print's
  variant), and the corners where both find the same id more than 3 px apart (one of the two ids is wrong).
"""

from __future__ import annotations

import glob
import math
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.data.marker_views import (
    CONDITIONS,
    K,
    random_board_pose,
    render_condition,
    render_marker_view,
)
from ccs_kornia.modules.detection.boards import AprilGrid, CharucoBoard
from ccs_kornia.modules.detection.markers.aprilgrid import (
    detect_aprilgrid,
    tag_detector,
)
from ccs_kornia.modules.detection.markers.charuco import detect_charuco

__all__ = ["APRILGRID", "CHARUCO", "MIN_POSED", "REAL_SETS", "SEED", "markers_md", "run_markers"]

#: first seed of the renders (the tests use seeds below 1000)
SEED = 700_000
#: the rendered ChArUco board (6 x 8 squares: the legacy layout differs) and AprilGrid
CHARUCO = CharucoBoard(6, 8, 0.035, 0.0175, "DICT_6X6_250")
APRILGRID = AprilGrid(6, 6, 0.088, 0.3)
#: a view is posed with at least this many corners
MIN_POSED = 6
#: the real sets: board, files per camera (glob patterns), OpenCV's variants to try when told (inverted, mirrored)
REAL_SETS = {
    "charuco_opencv_tutorial": (CharucoBoard(5, 7, 0.04, 0.02, "DICT_6X6_250"),
                                {"cam": ("img_*.jpg", "partial/chocclusion_original.jpg")}, ((False, False),)),
    "caliscope_4cam_charuco": (CharucoBoard(4, 5, 0.054, 0.0405, "DICT_4X4_1000"),
                               {f"cam_{c}": (f"cam_{c}/*.jpg",) for c in range(4)},
                               ((False, False), (True, False), (False, True), (True, True))),
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
    wrong = seen & (~ok | (err > 0.5 * nearest))
    right = seen & ~wrong
    return {"corners": int(seen.sum()), "wrong": int(wrong.sum()), "errors": err[right].tolist()}


def _summary(scores: list[dict]) -> dict:
    errors = np.array([e for s in scores for e in s["errors"]])
    views = max(len(scores), 1)
    return {
        "views": len(scores),
        "posed": sum(s["corners"] - s["wrong"] >= MIN_POSED for s in scores),
        "corners_per_view": sum(s["corners"] for s in scores) / views,
        "wrong_ids": sum(s["wrong"] for s in scores),
        "corners": sum(s["corners"] for s in scores),
        "mean_error_px": float(errors.mean()) if errors.size else math.nan,
        "median_error_px": float(np.median(errors)) if errors.size else math.nan,
    }


def _tensor(images: list[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(images)).float()[:, None] / 255.0


def _charuco_condition(cfg, condition: str, n: int, seed: int, log) -> dict:
    rng = np.random.default_rng(seed)
    methods = ("ours", "opencv_new", "opencv_legacy", "opencv_told")
    scores = {m: [] for m in methods}
    batch = 8
    for start in range(0, n, batch):
        images, truths, layouts = [], [], []
        for _ in range(min(batch, n - start)):
            legacy = bool(rng.random() < 0.5)
            image, truth = render_condition(CHARUCO, condition, rng, supersample=cfg.supersample, legacy=legacy)
            images.append(image)
            truths.append(truth)
            layouts.append(legacy)
        ours = detect_charuco(_tensor(images), CHARUCO, min_corners=MIN_POSED, num_workers=1)
        for k, (image, truth, legacy) in enumerate(zip(images, truths, layouts)):
            mine = ours.corners[k].double().numpy() if bool(ours.found[k]) else np.full_like(truth, np.nan)
            scores["ours"].append(_score(mine, truth))
            new, old = _opencv_charuco(CHARUCO, image, False), _opencv_charuco(CHARUCO, image, True)
            scores["opencv_new"].append(_score(new, truth))
            scores["opencv_legacy"].append(_score(old, truth))
            scores["opencv_told"].append(_score(old if legacy else new, truth))
    log(f"[bench] markers: charuco {condition}: {n} views, ours {sum(s['corners'] for s in scores['ours'])} corners")
    return {m: _summary(s) for m, s in scores.items()}


def _aprilgrid_condition(cfg, condition: str, n: int, seed: int, log) -> dict:
    rng = np.random.default_rng(seed)
    scores = {"ours": [], "opencv_subpix": []}
    batch = 8
    for start in range(0, n, batch):
        pairs = [render_condition(APRILGRID, condition, rng, supersample=cfg.supersample)
                 for _ in range(min(batch, n - start))]
        ours = detect_aprilgrid(_tensor([p[0] for p in pairs]), APRILGRID, min_corners=MIN_POSED, num_workers=1)
        for k, (image, truth) in enumerate(pairs):
            mine = ours.corners[k].double().numpy() if bool(ours.found[k]) else np.full_like(truth, np.nan)
            scores["ours"].append(_score(mine, truth))
            scores["opencv_subpix"].append(_score(_opencv_aprilgrid(APRILGRID, image), truth))
    log(f"[bench] markers: aprilgrid {condition}: {n} views")
    return {m: _summary(s) for m, s in scores.items()}


def _calibration_trial(cfg, views: int, seed: int) -> dict:
    """One set of partial ChArUco views (new layout), calibrated by ours and by OpenCV (rational model)."""
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
    pipe = CalibrationPipeline(CharucoDetector(board), model="rational", distortion_correction=False,
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
        row = {"images": len(images), "ours": 0, "ours_posed": 0, "opencv": 0, "opencv_posed": 0, "opencv_told": 0,
               "opencv_told_posed": 0, "disagree": 0, "both": 0}
        for shape in sizes:
            group = [im for im in images if im.shape == shape]
            det = detect_charuco(_tensor(group), board, num_workers=1)
            for k, image in enumerate(group):
                mine = det.corners[k].double().numpy() if bool(det.found[k]) else np.full((board.num_corners, 2),
                                                                                           np.nan)
                plain = _opencv_charuco(board, image, False)
                told = max((_opencv_charuco(board, image, False, i, m) for i, m in variants),
                           key=lambda c: int(np.isfinite(c).all(-1).sum()))
                n_mine, n_plain, n_told = (int(np.isfinite(c).all(-1).sum()) for c in (mine, plain, told))
                row["ours"] += n_mine
                row["ours_posed"] += n_mine >= MIN_POSED
                row["opencv"] += n_plain
                row["opencv_posed"] += n_plain >= MIN_POSED
                row["opencv_told"] += n_told
                row["opencv_told_posed"] += n_told >= MIN_POSED
                both = np.isfinite(mine).all(-1) & np.isfinite(told).all(-1)
                row["both"] += int(both.sum())
                row["disagree"] += int((np.linalg.norm(mine[both] - told[both], axis=-1) > 3.0).sum())
        out[cam] = row
    return out


def run_markers(cfg, log=print) -> dict:
    """The section (see the module doc); sizes from ``cfg.markers_views`` (ChArUco views per condition),
    ``cfg.markers_aprilgrid_views``, ``cfg.markers_calib_trials`` x ``cfg.markers_calib_views`` and
    ``cfg.markers_real_sets``."""
    t0 = time.perf_counter()
    sec: dict = {"charuco": {}, "aprilgrid": {}, "calibration": [], "real": {},
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
    from ccs_kornia.bench.real import default_real_dir

    root = Path(cfg.real_dir) if cfg.real_dir else default_real_dir()
    for name in cfg.markers_real_sets:
        got = _real_set(root, name)
        sec["real"][name] = got if got is not None else {"skipped": f"not present under {root}"}
        log(f"[bench] markers: real {name}")
    sec["views_rendered"] = len(CONDITIONS) * (cfg.markers_views + cfg.markers_aprilgrid_views) + \
        cfg.markers_calib_trials * cfg.markers_calib_views
    sec["run_seconds"] = time.perf_counter() - t0
    return sec


_LABELS = {"ours": "ours", "opencv_new": "CharucoDetector (legacy off)", "opencv_legacy": "CharucoDetector (legacy on)",
           "opencv_told": "CharucoDetector (told the layout)", "opencv_subpix": "OpenCV tags + cornerSubPix (Kalibr)"}


def _fmt(x: float, digits: int = 3) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def markers_md(sec: dict) -> list[str]:
    """The section's markdown lines."""
    lines: list[str] = []
    for kind, title in (("charuco", f"ChArUco ({sec['boards']['charuco']})"),
                        ("aprilgrid", f"AprilGrid ({sec['boards']['aprilgrid']})")):
        rows = sec.get(kind) or {}
        if not rows:
            continue
        lines += [f"Renders, {title}: views posed (>= {MIN_POSED} corners), corners per view, wrong ids, corner error "
                  "(px, right ids).", "",
                  "| condition | method | views | posed | corners/view | wrong ids | mean err | median err |",
                  "|---|---|---|---|---|---|---|---|"]
        for condition, methods in rows.items():
            for m, s in methods.items():
                lines.append(f"| {condition} | {_LABELS.get(m, m)} | {s['views']} | {s['posed']} | "
                             f"{s['corners_per_view']:.1f} | {s['wrong_ids']} | {_fmt(s['mean_error_px'])} | "
                             f"{_fmt(s['median_error_px'])} |")
        total = sum(methods["ours"]["views"] for methods in rows.values())
        wrong = sum(methods["ours"]["wrong_ids"] for methods in rows.values())
        lines += ["", f"Ours over all {total} {kind} views: {wrong} wrong ids.", ""]
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
    for name, cams in (sec.get("real") or {}).items():
        if "skipped" in cams:
            lines += [f"Real `{name}`: skipped ({cams['skipped']}).", ""]
            continue
        lines += [f"Real `{name}`: corners (views posed) per camera; 'apart': ids both find more than 3 px apart.", "",
                  "| camera | images | ours | CharucoDetector | CharucoDetector told the variant | apart / both |",
                  "|---|---|---|---|---|---|"]
        for cam, r in cams.items():
            lines.append(f"| {cam} | {r['images']} | {r['ours']} ({r['ours_posed']}) | {r['opencv']} "
                         f"({r['opencv_posed']}) | {r['opencv_told']} ({r['opencv_told_posed']}) | "
                         f"{r['disagree']} / {r['both']} |")
        lines.append("")
    return lines
