"""Section 1: corner accuracy on rendered images with exact ground truth (paper Table III).

Per condition and method: detection rate (whole board found with every corner within
``error_threshold`` px of the truth), rate of boards returned with a wrong corner, wrong-corner rate, and
the mean / median / 95th-percentile corner error over correctly detected boards. Corners are compared
with the truth under the best lattice ordering (180-degree reversal, mirrors; transposes for square
boards), since a detector's choice of board origin is a convention, not an error. ``mean_common`` is
the mean error on the images every available method detected correctly, which compares the methods
on the same boards.
"""

from __future__ import annotations

import numpy as np

from ccs_kornia.bench.config import BenchConfig
from ccs_kornia.bench.methods import DetectionMethod
from ccs_kornia.bench.common import Timer, summary
from ccs_kornia.bench.scenes import corner_errors, render_scenes

__all__ = ["run_corners"]


def run_corners(cfg: BenchConfig, methods: dict[str, DetectionMethod], log=print) -> dict:
    """Run the corner-accuracy section; returns ``{"conditions": {cond: {method: metrics}}, ...}``."""
    per_cam = max(1, min(cfg.corner_views_per_camera, cfg.corner_images))
    cameras = -(-cfg.corner_images // per_cam)
    out: dict = {"images_per_condition": cameras * per_cam, "cameras": cameras, "threshold_px": cfg.error_threshold,
                 "image_size": list(cfg.image_size), "board": list(cfg.board), "conditions": {}}
    for cond in cfg.corner_conditions:
        scenes = render_scenes(cfg, cond, cameras, per_cam, "corners")
        images, truth = scenes.flat_images, scenes.flat_corners.numpy()
        n_img = images.shape[0]
        log(f"[corners] {cond}: {n_img} images rendered in {scenes.render_seconds:.1f}s")
        ok_by_method: dict[str, np.ndarray] = {}
        errs_by_method: dict[str, np.ndarray] = {}
        res: dict = {}
        for key, m in methods.items():
            if not m.available:
                continue
            with Timer() as t:
                corners, found = m.detect(images, cfg.board)
            errs = np.full(truth.shape[:2], np.nan)
            for b in np.nonzero(found)[0]:
                errs[b] = corner_errors(corners[b], truth[b], cfg.board)
            worst = np.where(found, np.nanmax(np.where(np.isnan(errs), -1, errs), axis=1), np.inf)
            ok = found & (worst <= cfg.error_threshold)
            wrong_corners = int((errs[found] > cfg.error_threshold).sum())
            stats = summary(errs[ok])
            res[key] = {
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
            ok_by_method[key], errs_by_method[key] = ok, errs
            log(f"[corners] {cond:12s} {m.label:30s} detected {int(ok.sum())}/{n_img} "
                f"mean {stats['mean'] if stats['mean'] is not None else float('nan'):.4f} px ({t.seconds / n_img:.3f} s/img)")
        if ok_by_method:
            common = np.logical_and.reduce(list(ok_by_method.values()))
            for key, errs in errs_by_method.items():
                s = summary(errs[common])
                res[key]["common_images"] = int(common.sum())
                res[key]["mean_common_px"] = s["mean"]
        out["conditions"][cond] = res
    return out
