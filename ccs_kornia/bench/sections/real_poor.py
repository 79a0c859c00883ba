"""Real photographs made poor: the shared real sets' corners found on degraded copies of their images, against OpenCV.

The renders of the ``markers`` and ``corners`` sections do not hold what real photographs of boards hold (a lens
that bends a large board, boards cut by the frame, a real sensor's noise, compression), so the same kinds of poor
images are made here from real ones (:mod:`~ccs_kornia.data.render.poor_images`: dark, dark on a Poisson-Gaussian
sensor, Gaussian blur, motion blur, small, JPEG).

* **views**: ``real_poor_images`` images of each set (of each camera of a multi-camera set, the frames of its
  recording), evenly spaced; the ChArUco sets (:data:`~ccs_kornia.bench.sections.markers.REAL_SETS`) and the
  chessboard sets (:data:`~ccs_kornia.bench.sections.wild.WILD_REAL_SETS`, the fisheye ones included);
* **truth**: the corners this package and OpenCV (``cv2.aruco.CharucoDetector``, told the print's variant:
  inverted, mirrored; ``cv2.findChessboardCornersSB``) both place within :data:`TRUTH_PX` of each other on the clean
  image, at their midpoint (moved with the image on the ``small`` condition);
* **methods**: ours (the default: both marker-board paths merged; the learned chessboard detector), for ChArUco also
  each path alone, against the same OpenCV detector as above;
* **figures** per condition and board kind: truth corners found with their right id (within
  :data:`~ccs_kornia.bench.sections.markers.WRONG_PX`, or half the distance to the nearest other truth corner where
  that is less, in the poor image's pixels), wrong ids (a corner of a truth id farther than that), the corner
  error (mean and median px over the right ones), views with at least
  :data:`~ccs_kornia.bench.sections.markers.MIN_POSED` right corners, and for chessboards the whole boards found;
  over all sets and over the sets held out of the heatmap network's self-training
  (:data:`~ccs_kornia.data.datamodules.real_pairs_datamodule.HELD_OUT_SETS`, ``held_out`` in the JSON).
  A chessboard's corners are compared in the best of the orderings a board's symmetry allows.
"""

from __future__ import annotations

import glob
import math
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.bench.sections.markers import (
    MIN_POSED,
    REAL_SETS,
    WRONG_PX,
    _opencv_charuco,
)
from ccs_kornia.bench.sections.wild import WILD_REAL_SETS
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.data.datamodules.real_pairs_datamodule import HELD_OUT_SETS
from ccs_kornia.data.render.poor_images import make_poor, scale_points
from ccs_kornia.modules.detection.markers.charuco import charuco_paths
from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths

__all__ = ["CHARUCO_METHODS", "CHESS_METHODS", "TRUTH_PX", "real_poor_md", "run_real_poor", "score_view"]

#: ours and OpenCV agree on a truth corner within this distance (px) on the clean image
TRUTH_PX = 1.0
#: ChArUco methods: key -> label
CHARUCO_METHODS = {"ours": "ours", "marker_path": "ours, marker path", "lattice_path": "ours, lattice path",
                   "opencv": "CharucoDetector (told the variant)"}
#: chessboard methods: key -> label
CHESS_METHODS = {"ours": "ours (learned)", "opencv": "findChessboardCornersSB"}
_PATHS = {"ours": MarkerPaths.BOTH, "marker_path": MarkerPaths.MARKERS, "lattice_path": MarkerPaths.LATTICE}


def _files(folder: Path, patterns: tuple[str, ...], count: int) -> list[str]:
    """``count`` files matching ``patterns`` in ``folder``, evenly spaced in name order."""
    files = sorted(f for p in patterns for f in glob.glob(str(folder / p)))
    if len(files) <= count:
        return files
    return [files[int(i)] for i in np.linspace(0, len(files) - 1, count).round()]


def score_view(found: np.ndarray, truth: np.ndarray, errors: np.ndarray | None = None) -> dict:
    """One view's corners ``found`` ``(N, 2)`` by id (NaN: none) against the ``truth`` ``(N, 2)`` (NaN: no truth):
    truth corners, right ones, wrong ids, the right ones' errors (px), and corners of ids without truth (not judged).
    ``errors`` ``(N,)``: the distances already matched (a chessboard's best ordering), instead of by id.

    Example:
        >>> truth = np.array([[0.0, 0.0], [20.0, 0.0], [np.nan, np.nan]])
        >>> s = score_view(np.array([[0.5, 0.0], [0.0, 0.0], [5.0, 5.0]]), truth)
        >>> s["truth"], s["right"], s["wrong"], s["unjudged"], s["errors"]
        (2, 1, 1, 1, [0.5])
    """
    ok = np.isfinite(truth).all(-1)
    t = truth[ok]
    d = np.linalg.norm(t[:, None] - t[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    limit = np.full(len(truth), WRONG_PX)
    if len(t) > 1:
        limit[ok] = np.minimum(WRONG_PX, 0.5 * d.min(1))
    if errors is None:
        seen = np.isfinite(found).all(-1)
        err = np.where(seen & ok, np.linalg.norm(np.nan_to_num(found) - np.nan_to_num(truth), axis=-1), np.nan)
    else:
        err = np.asarray(errors, dtype=np.float64)
        seen = np.isfinite(err)
    judged = seen & ok
    right = judged & (np.nan_to_num(err, nan=np.inf) <= limit)
    return {"truth": int(ok.sum()), "right": int(right.sum()), "wrong": int((judged & ~right).sum()),
            "unjudged": int((seen & ~ok).sum()), "errors": err[right].tolist()}


def _summary(scores: list[dict], boards: list[bool] | None = None) -> dict:
    errors = np.array([e for s in scores for e in s["errors"]])
    truth = sum(s["truth"] for s in scores)
    out = {
        "views": len(scores),
        "truth": truth,
        "right": sum(s["right"] for s in scores),
        "found_fraction": sum(s["right"] for s in scores) / truth if truth else math.nan,
        "wrong_ids": sum(s["wrong"] for s in scores),
        "unjudged": sum(s["unjudged"] for s in scores),
        "posed": sum(s["right"] >= MIN_POSED for s in scores),
        "mean_error_px": float(errors.mean()) if errors.size else math.nan,
        "median_error_px": float(np.median(errors)) if errors.size else math.nan,
    }
    if boards is not None:
        out["boards"] = int(sum(boards))
    return out


def _truth(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """The midpoint of the corners both place within :data:`TRUTH_PX` (NaN elsewhere)."""
    both = np.isfinite(ours).all(-1) & np.isfinite(theirs).all(-1)
    close = both & (np.linalg.norm(np.nan_to_num(ours) - np.nan_to_num(theirs), axis=-1) <= TRUTH_PX)
    return np.where(close[:, None], 0.5 * (ours + theirs), np.nan)


def _poor_copies(images: list[np.ndarray], name: str, conditions: tuple[str, ...]) -> dict[str, list]:
    """``{condition: [(image, scale), ...]}``, the noise seeded by the set and condition."""
    out = {}
    for c, condition in enumerate(conditions):
        rng = np.random.default_rng(BENCH_SEED_BASE + 11 * sum(map(ord, name)) + c)
        out[condition] = [make_poor(im, condition, rng) for im in images]
    return out


def _charuco_camera(name: str, files: list[str], conditions: tuple[str, ...]) -> dict:
    """Every method's per-view scores of one ChArUco camera, per condition."""
    board, _, variants = REAL_SETS[name]
    images = [im for im in (cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in files) if im is not None]

    def detect(batch: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
        got: dict[str, list[np.ndarray]] = {k: [] for k in CHARUCO_METHODS}
        nan = np.full((board.num_corners, 2), np.nan)
        for image in batch:  # one at a time: the sizes of a camera's images may differ
            x = torch.from_numpy(image).float()[None, None] / 255.0
            ours = charuco_paths(x, board, min_corners=1, num_workers=1, paths=tuple(_PATHS.values()))
            for key, path in _PATHS.items():
                res = ours[path]
                got[key].append(res.corners[0].double().numpy() if bool(res.found[0]) else nan)
            got["opencv"].append(max((_opencv_charuco(board, image, False, i, m) for i, m in variants),
                                     key=lambda c: int(np.isfinite(c).all(-1).sum())))
        return got

    clean = detect(images)
    truths = [_truth(o, c) for o, c in zip(clean["ours"], clean["opencv"])]
    out: dict = {"views": len(images), "clean": {k: [score_view(v, t) for v, t in zip(clean[k], truths)]
                                                 for k in CHARUCO_METHODS}}
    for condition, pairs in _poor_copies(images, name, conditions).items():
        got = detect([p for p, _ in pairs])
        scaled = [scale_points(t, s) for t, (_, s) in zip(truths, pairs)]
        out[condition] = {k: [score_view(v, t) for v, t in zip(got[k], scaled)] for k in CHARUCO_METHODS}
    return out


def _chess_set(name: str, folder: Path, count: int, conditions: tuple[str, ...], methods: dict) -> dict:
    """Every method's per-view scores and whole boards of one chessboard set, per condition."""
    from ccs_kornia.bench.scenes.scenes import corner_errors

    board = WILD_REAL_SETS[name]
    exts = ("*.jpg", "*.jpeg", "*.png", "*.bmp", "*.JPG", "*.PNG")
    files = _files(folder, exts, count)
    images = [im for im in (cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in files) if im is not None]
    n = board[0] * board[1]

    def detect(batch: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
        got: dict[str, list[np.ndarray]] = {}
        for key, m in methods.items():
            got[key] = []
            for image in batch:  # one at a time: two Udacity images are a pixel larger
                c, f = m.detect(torch.from_numpy(image).float()[None, None] / 255.0, board)
                got[key].append(c[0] if bool(f[0]) else np.full((n, 2), np.nan))
        return got

    def judge(corners: list[np.ndarray], truths: list[np.ndarray]) -> tuple[list[dict], list[bool]]:
        scores, boards = [], []
        for c, t in zip(corners, truths):
            err = corner_errors(c, t, board) if np.isfinite(c).all(-1).any() and np.isfinite(t).any() else None
            err = np.full(n, np.nan) if err is None else err
            scores.append(score_view(c, t, err))
            boards.append(bool(np.isfinite(c).all()) and np.isfinite(t).any())
        return scores, boards

    clean = detect(images)
    truths = [_truth(o, _align(c, o, board)) for o, c in zip(clean["ours"], clean["opencv"])]
    views = [np.isfinite(t).any() for t in truths]
    out: dict = {"views": len(images), "views_with_truth": int(sum(views))}
    for condition in ("clean", *conditions):
        pairs = [(im, 1.0) for im in images] if condition == "clean" else \
            _poor_copies(images, name, conditions)[condition]
        got = clean if condition == "clean" else detect([p for p, _ in pairs])
        scaled = [scale_points(t, s) for t, (_, s) in zip(truths, pairs)]
        out[condition] = {}
        for key in methods:
            scores, boards = judge(got[key], scaled)
            out[condition][key] = {"scores": [s for s, v in zip(scores, views) if v],
                                   "boards": [b for b, v in zip(boards, views) if v]}
    return out


def _align(pred: np.ndarray, ref: np.ndarray, board: tuple[int, int]) -> np.ndarray:
    """``pred`` ``(N, 2)`` in the ordering of the board's lattice (its symmetries) closest to ``ref`` ``(N, 2)``."""
    from ccs_kornia.bench.scenes.scenes import lattice_orderings

    if not (np.isfinite(pred).all() and np.isfinite(ref).all()):
        return pred
    cols, rows = board
    cands = [g.reshape(-1, 2) for g in lattice_orderings(pred.reshape(rows, cols, 2), cols == rows)]
    return min(cands, key=lambda g: float(np.linalg.norm(g - ref, axis=-1).mean()))


def run_real_poor(cfg, log=print) -> dict:
    """The section (module doc); sizes from ``cfg.real_poor_images``, ``cfg.real_poor_sets`` and
    ``cfg.real_poor_conditions``."""
    from ccs_kornia.bench.methods.methods import make_methods
    from ccs_kornia.bench.sections.real import default_real_dir

    root = Path(cfg.real_dir) if cfg.real_dir else default_real_dir()
    conditions = tuple(cfg.real_poor_conditions)
    sec: dict = {"root": str(root), "conditions": ["clean", *conditions], "images": cfg.real_poor_images,
                 "charuco": {}, "chessboard": {}, "sets": {}, "skipped": {}}
    if not root.is_dir():
        sec["skipped"]["*"] = f"real data folder not found: {root}"
        log(f"[real_poor] skipped: {root} not found")
        return sec
    names = cfg.real_poor_sets if cfg.real_poor_sets is not None else (*REAL_SETS, *WILD_REAL_SETS)
    per_kind: dict[str, dict[str, dict[str, list]]] = {"charuco": {}, "chessboard": {}}
    chess_methods = None
    for name in names:
        folder = root / name
        if name not in REAL_SETS and name not in WILD_REAL_SETS:
            sec["skipped"][name] = "unknown set (board not recorded in the benchmark)"
            continue
        if not folder.is_dir():
            sec["skipped"][name] = f"not found in {root}"
            continue
        if name in REAL_SETS:
            kind, entry = "charuco", {}
            for patterns in REAL_SETS[name][1].values():
                files = _files(folder, patterns, cfg.real_poor_images)
                got = _charuco_camera(name, files, conditions)
                for condition in ("clean", *conditions):
                    for key, scores in got[condition].items():
                        per_kind[kind].setdefault(condition, {}).setdefault(key, []).extend(
                            (s, None, name) for s in scores)
                        entry.setdefault(condition, {}).setdefault(key, []).extend(scores)
            sec["sets"][name] = {"kind": kind, **{c: {k: _summary(v) for k, v in m.items()}
                                                  for c, m in entry.items()}}
        else:
            kind = "chessboard"
            if chess_methods is None:
                made = make_methods(("learned", "opencv_sb"), cfg.learned_batch)
                missing = [m.reason for m in made.values() if not m.available]
                if missing:
                    sec["skipped"]["chessboards"] = "; ".join(missing)
                    log(f"[real_poor] chessboards skipped: {'; '.join(missing)}")
                chess_methods = {} if missing else {"ours": made["learned"], "opencv": made["opencv_sb"]}
            if not chess_methods:
                continue
            got = _chess_set(name, folder, cfg.real_poor_images, conditions, chess_methods)
            entry = {"kind": kind, "views": got["views"], "views_with_truth": got["views_with_truth"]}
            for condition in ("clean", *conditions):
                entry[condition] = {}
                for key, r in got[condition].items():
                    per_kind[kind].setdefault(condition, {}).setdefault(key, []).extend(
                        (s, b, name) for s, b in zip(r["scores"], r["boards"]))
                    entry[condition][key] = _summary(r["scores"], r["boards"])
            sec["sets"][name] = entry
        clean = sec["sets"][name]["clean"]["ours"]
        worst = min(sec["sets"][name][c]["ours"]["found_fraction"] for c in conditions) if conditions else math.nan
        log(f"[real_poor] {name}: {clean['views']} views, {clean['truth']} truth corners; ours clean "
            f"{clean['found_fraction']:.3f}, worst poor condition {worst:.3f}")
    sec["held_out"] = {"sets": [n for n in sec["sets"] if n in HELD_OUT_SETS], "charuco": {}, "chessboard": {}}
    for kind, rows in per_kind.items():
        for condition, methods in rows.items():
            for part, keep in ((sec, None), (sec["held_out"], HELD_OUT_SETS)):
                part[kind][condition] = {}
                for key, rows_ in methods.items():
                    picked = [(s, b) for s, b, n in rows_ if keep is None or n in keep]
                    if not picked:
                        continue
                    boards = None if kind == "charuco" else [b for _, b in picked]
                    part[kind][condition][key] = _summary([s for s, _ in picked], boards)
                if not part[kind][condition]:
                    del part[kind][condition]
    return sec


def _fmt(x, digits: int = 3) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _pct(x) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100.0 * x:.1f} %"


def real_poor_md(sec: dict) -> list[str]:
    """The section's markdown lines."""
    if sec.get("skipped", {}).get("*"):
        return [f"Skipped: {sec['skipped']['*']}.", ""]
    lines: list[str] = [(
        f"Up to {sec['images']} images per set (per camera of a multi-camera set), evenly spaced, made poor "
        "(`ccs_kornia.data.render.poor_images`: dark = x0.12 + Gaussian noise sigma 2; dark sensor = x0.12 as "
        "Poisson photo-electrons at 0.25 grey levels each + read noise 2; blur = Gaussian sigma 2.5 px; motion = "
        "15 px line in a random direction; small = x0.4, area interpolation; jpeg = quality 30). Truth: the "
        f"corners ours and OpenCV both place within {TRUTH_PX:g} px on the clean image. Found: truth corners with "
        f"their right id (within {WRONG_PX:g} px, or half the distance to the nearest truth corner); wrong ids: a "
        "truth id's corner farther than that; error over the right ones (px of the poor image); posed: views with "
        f"at least {MIN_POSED} right corners."), ""]
    held = sec.get("held_out") or {}
    tables = [(held, "held-out sets, never seen in the heatmap network's self-training: "
               + ", ".join(f"`{n}`" for n in held.get("sets", ())))] if held.get("sets") else []
    tables.append((sec, "all sets"))
    for (part, which), (kind, labels, title) in ((t, k) for t in tables for k in (
            ("charuco", CHARUCO_METHODS, "ChArUco boards"), ("chessboard", CHESS_METHODS, "Chessboards"))):
        rows = part.get(kind) or {}
        if not rows:
            continue
        title = f"{title}, {which}"
        boards = kind == "chessboard"
        lines += [f"{title}:", "",
                  "| condition | method | views | truth corners | found | wrong ids | mean err | median err | posed |"
                  + (" whole boards |" if boards else ""),
                  "|---|---|---|---|---|---|---|---|---|" + ("---|" if boards else "")]
        for condition, methods in rows.items():
            for key, s in methods.items():
                lines.append(f"| {condition} | {labels.get(key, key)} | {s['views']} | {s['truth']} | "
                             f"{_pct(s['found_fraction'])} | {s['wrong_ids']} | {_fmt(s['mean_error_px'])} | "
                             f"{_fmt(s['median_error_px'])} | {s['posed']} |" + (f" {s['boards']} |" if boards else ""))
        lines.append("")
    sets = sec.get("sets") or {}
    if sets:
        conditions = sec["conditions"]
        lines += ["Per set: truth corners found, ours / OpenCV (wrong ids of ours where any).", "",
                  "| set | truth corners (clean) | " + " | ".join(conditions) + " |",
                  "|---|---|" + "---|" * len(conditions)]
        for name, e in sets.items():
            cells = []
            for c in conditions:
                o, v = e[c]["ours"], e[c]["opencv"]
                wrong = f" ({o['wrong_ids']} wrong)" if o["wrong_ids"] else ""
                cells.append(f"{_pct(o['found_fraction'])} / {_pct(v['found_fraction'])}{wrong}")
            lines.append(f"| `{name}` | {e['clean']['ours']['truth']} | " + " | ".join(cells) + " |")
        lines.append("")
    for item, why in (sec.get("skipped") or {}).items():
        lines.append(f"- {item}: skipped ({why})")
    return lines
