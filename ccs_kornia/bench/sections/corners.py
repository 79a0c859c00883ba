"""Section 1: corner accuracy on rendered images with exact ground truth (paper Table III).

Per condition and method: detection rate (whole board found with every corner within
``error_threshold`` px of the truth), rate of boards returned with a wrong corner, wrong-corner rate, and
the mean / median / 95th-percentile corner error over correctly detected boards. Corners are compared
with the truth under the best lattice ordering (180-degree reversal, mirrors; transposes for square
boards), since a detector's choice of board origin is a convention, not an error. ``mean_common`` is
the mean error on the images every available method detected correctly, which compares the methods
on the same boards. Ablation rows (``BenchConfig.corner_ablations``: the paper's collinearity refinement on,
which the learned detector leaves off by default) are scored the same way on the same images and do not enter
that common set.
"""

from __future__ import annotations

import numpy as np

from ccs_kornia.bench.common import Timer, summary
from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods.methods import ABLATIONS, DetectionMethod, make_ablations
from ccs_kornia.bench.scenes.scenes import corner_errors, render_scenes

__all__ = ["run_corners"]


def run_corners(cfg: BenchConfig, methods: dict[str, DetectionMethod], log=print) -> dict:
    """Run the corner-accuracy section; returns ``{"conditions": {cond: {method: metrics}}, ...}``.

    The ablations of ``cfg.corner_ablations`` (e.g. the learned detector with the paper's collinearity refinement
    on) get a row each, marked ``ablation_of``; they are not counted in the images every method detected.
    """
    per_cam = max(1, min(cfg.corner_views_per_camera, cfg.corner_images))
    cameras = -(-cfg.corner_images // per_cam)
    out: dict = {"images_per_condition": cameras * per_cam, "cameras": cameras, "threshold_px": cfg.error_threshold,
                 "image_size": list(cfg.image_size), "board": list(cfg.board), "conditions": {}}
    keys = [key for key in cfg.corner_ablations if ABLATIONS[key][0] in methods]
    ablations = make_ablations(keys, cfg.learned_batch) if keys else {}
    for cond in cfg.corner_conditions:
        scenes = render_scenes(cfg, cond, cameras, per_cam, "corners")
        images, truth = scenes.flat_images, scenes.flat_corners.numpy()
        n_img = images.shape[0]
        log(f"[corners] {cond}: {n_img} images rendered in {scenes.render_seconds:.1f}s")
        ok_by_method: dict[str, np.ndarray] = {}
        errs_by_method: dict[str, np.ndarray] = {}
        res: dict = {}
        for key, m in [*methods.items(), *ablations.items()]:
            if not m.available:
                continue
            res[key], ok_by_method[key], errs_by_method[key] = _score(m, images, truth, cfg, cond, log)
            if key in ablations:
                res[key]["ablation_of"] = ABLATIONS[key][0]
        compared = [key for key in ok_by_method if key not in ablations]
        if compared:
            common = np.logical_and.reduce([ok_by_method[key] for key in compared])
            for key, errs in errs_by_method.items():
                s = summary(errs[common])
                res[key]["common_images"] = int(common.sum())
                res[key]["mean_common_px"] = s["mean"]
        out["conditions"][cond] = res
    return out


def _score(
    m: DetectionMethod, images, truth: np.ndarray, cfg: BenchConfig, cond: str, log
) -> tuple[dict, np.ndarray, np.ndarray]:
    """Detect with ``m`` and score against the truth: (metrics row, correctly detected (B,), errors (B, N))."""
    n_img = images.shape[0]
    with Timer() as t:
        corners, found = m.detect(images, cfg.board)
    errs = np.full(truth.shape[:2], np.nan)
    for b in np.nonzero(found)[0]:
        errs[b] = corner_errors(corners[b], truth[b], cfg.board)
    worst = np.where(found, np.nanmax(np.where(np.isnan(errs), -1, errs), axis=1), np.inf)
    ok = found & (worst <= cfg.error_threshold)
    wrong_corners = int((errs[found] > cfg.error_threshold).sum())
    stats = summary(errs[ok])
    row = {
        "label": m.label,
        "images": n_img,
        "found": int(found.sum()),
        "detected": int(ok.sum()),
        "detection_rate": float(ok.mean()),
        "wrong_board_rate": float((found & ~ok).sum() / max(int(found.sum()), 1)),
        "wrong_corner_rate": float(wrong_corners / max(int(found.sum()) * truth.shape[1], 1)),
        "mean_px": stats["mean"],
        "median_px": stats["median"],
        "p95_px": stats["p95"],
        "max_px": stats["max"],
        "seconds_per_image": t.seconds / n_img,
    }
    log(f"[corners] {cond:12s} {m.label:30s} detected {int(ok.sum())}/{n_img} "
        f"mean {stats['mean'] if stats['mean'] is not None else float('nan'):.4f} px ({t.seconds / n_img:.3f} s/img)")
    return row, ok, errs
