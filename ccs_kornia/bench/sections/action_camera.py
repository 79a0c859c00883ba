"""An action camera's large ChArUco board made poor: rendered photographs of the kind the shared real sets lack.

The shared real ChArUco sets are small boards (5 x 7 and 4 x 5 squares) seen by ordinary lenses; the ``markers``
section's renders are 640 x 480 with a 6 x 8 board. Here an action camera
(:mod:`~ccs_kornia.data.scenes.action_camera`: 1280 x 720, k1 = -0.32 at fx = 600 px, about 120 degrees across the
diagonal) photographs a ChArUco board of :data:`BOARD` (19 x 10 squares, 18 x 9 inner corners, ``DICT_4X4_250``,
marker/square 0.75) that fills 60 to 110 % of the frame's width, tilted and often cut by the frame, with a print's
black and white under uneven light, vignetting, clutter around the board, softness, sensor noise and the camera's JPEG.

* **views**: ``action_camera_views`` renders (seeds from :data:`SEED`), each made poor by the ``real_poor`` section's
  own conditions (:func:`~ccs_kornia.data.render.poor_images.make_poor`: dark, dark sensor, blur, motion, small, jpeg);
* **truth**: the rendered corners in the image (moved with the image on the ``small`` condition);
* **methods**: ours (both marker-board paths merged, the default), its marker path and its lattice path alone, and
  ``cv2.aruco.CharucoDetector`` told the board's layout;
* **figures** per condition (as the ``real_poor`` section's, :func:`~ccs_kornia.bench.sections.real_poor.score_view`):
  truth corners found with their right id, wrong ids, the corner error (mean and median px), views posed.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from ccs_kornia.bench.sections.markers import _opencv_charuco
from ccs_kornia.bench.sections.real_poor import (
    CHARUCO_METHODS,
    _fmt,
    _pct,
    _summary,
    score_view,
)
from ccs_kornia.data.datamodules.datamodule import BENCH_SEED_BASE
from ccs_kornia.data.render.poor_images import make_poor, scale_points
from ccs_kornia.data.scenes.action_camera import (
    ACTION_DIST,
    ACTION_K,
    ACTION_SIZE,
    SPAN,
    render_action_view,
)
from ccs_kornia.modules.detection.boards import CharucoBoard
from ccs_kornia.modules.detection.markers.charuco import charuco_paths
from ccs_kornia.modules.detection.markers.corner_merge import MarkerPaths

__all__ = ["BOARD", "LABELS", "SEED", "action_camera_md", "run_action_camera"]

#: the board: 19 x 10 squares of 4 cm, 3 cm markers of a 4 x 4 dictionary (OpenCV's current layout)
BOARD = CharucoBoard(19, 10, 0.04, 0.03, "DICT_4X4_250", legacy=False)
#: view ``v``'s render is seeded ``SEED + v``; its poor copy under condition ``c`` ``SEED + 100_000 (c + 1) + v``
SEED = BENCH_SEED_BASE + 760_000
#: the rows' labels
LABELS = {**CHARUCO_METHODS, "opencv": "CharucoDetector (told the layout)"}
_PATHS = {"ours": MarkerPaths.BOTH, "marker_path": MarkerPaths.MARKERS, "lattice_path": MarkerPaths.LATTICE}


def _detect(image: np.ndarray) -> dict[str, np.ndarray]:
    """Every method's corners ``(N, 2)`` by id (NaN: none) on one image."""
    nan = np.full((BOARD.num_corners, 2), np.nan)
    x = torch.from_numpy(image).float()[None, None] / 255.0
    ours = charuco_paths(x, BOARD, min_corners=1, num_workers=1, paths=tuple(_PATHS.values()))
    got = {key: ours[path].corners[0].double().numpy() if bool(ours[path].found[0]) else nan
           for key, path in _PATHS.items()}
    got["opencv"] = _opencv_charuco(BOARD, image, False)
    return got


def run_action_camera(cfg, log=print) -> dict:
    """The section (module doc); sizes from ``cfg.action_camera_views`` and ``cfg.real_poor_conditions``."""
    t0 = time.perf_counter()
    conditions = ("clean", *cfg.real_poor_conditions)
    scores: dict[str, dict[str, list]] = {c: {k: [] for k in CHARUCO_METHODS} for c in conditions}
    for v in range(cfg.action_camera_views):
        clean, truth = render_action_view(BOARD, np.random.default_rng(SEED + v), supersample=cfg.supersample)
        for c, condition in enumerate(conditions):
            image, scale = make_poor(clean, condition, np.random.default_rng(SEED + 100_000 * (c + 1) + v))
            t = scale_points(truth, scale)
            for key, corners in _detect(image).items():
                scores[condition][key].append(score_view(corners, t))
        log(f"[action_camera] view {v + 1}/{cfg.action_camera_views}")
    sec = {"views": cfg.action_camera_views, "conditions": list(conditions),
           "camera": {"size": list(ACTION_SIZE), "K": ACTION_K.tolist(), "dist": ACTION_DIST.tolist(),
                      "span": list(SPAN)},
           "board": "19x10 squares (18x9 inner corners), DICT_4X4_250, marker/square 0.75",
           "results": {c: {k: _summary(s) for k, s in m.items()} for c, m in scores.items()},
           "per_view": {c: {k: [[s["truth"], s["right"], s["wrong"]] for s in m[k]] for k in m}
                        for c, m in scores.items()}}
    sec["run_seconds"] = time.perf_counter() - t0
    return sec


def action_camera_md(sec: dict) -> list[str]:
    """The section's markdown lines."""
    lines = [(
        f"{sec['views']} rendered views per condition: an action camera (1280x720, fx 600 px, k1 -0.32, k2 0.09, "
        "k3 -0.006: about 120 degrees across the diagonal) and a ChArUco board of 19x10 squares (18x9 inner corners, "
        "DICT_4X4_250, marker/square 0.75) spanning 60 to 110 % of the frame's width, tilted up to 45 degrees, often "
        "cut by the frame; uneven light, vignetting, clutter, softness, sensor noise and JPEG 70-92; then section 16's "
        "conditions. Truth: the rendered corners in the frame. Found: truth corners with their right id (within 3 px, "
        "or half the distance to the nearest truth corner); wrong ids: farther than that; error over the right ones "
        "(px of the poor image); posed: views with at least 6 right corners."), "",
        "| condition | method | views | truth corners | found | wrong ids | mean err | median err | posed |",
        "|---|---|---|---|---|---|---|---|---|"]
    for condition, methods in sec["results"].items():
        for key, s in methods.items():
            lines.append(f"| {condition} | {LABELS.get(key, key)} | {s['views']} | {s['truth']} | "
                         f"{_pct(s['found_fraction'])} | {s['wrong_ids']} | {_fmt(s['mean_error_px'])} | "
                         f"{_fmt(s['median_error_px'])} | {s['posed']} |")
    worst = min(m["ours"]["found_fraction"] for m in sec["results"].values())
    wrong = sum(m["ours"]["wrong_ids"] for m in sec["results"].values())
    lines += ["", (f"Ours: worst condition {_pct(worst if not math.isnan(worst) else None)} of the truth corners "
                   f"found, {wrong} wrong ids over all conditions."), ""]
    return lines
