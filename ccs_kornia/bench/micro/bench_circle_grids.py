"""Circle grids on rendered views: the dots' centres and the calibration against OpenCV's ``findCirclesGrid``.

Views of each grid (OpenCV's symmetric 7x5 and asymmetric 4x11, ROS-Industrial's marked-origin 10x10) are rendered
(:func:`~ccs_kornia.data.scenes.marker_views.render_marker_view`: exact centres, 640x480, f 520 px, the renderer's
strong barrel lens ``k1 = -0.28, k2 = 0.09``) with the board tilted up to 20, 40, 60 and 70 degrees, a Gaussian blur
of 0.7 px and sensor noise of 2 grey levels. Per grid and tilt, ``--views`` views:

* centres: RMS px from the true projection of each dot's centre, of OpenCV's ``findCirclesGrid`` (its blob centres),
  of this package's measured centres (the dots' images' centres) and of its corrected centres (after the
  calibration, :mod:`~ccs_kornia.modules.detection.circles.centre_bias`);
* calibration: focal length (%) and principal point (px) errors of ``cv2.calibrateCamera`` (k1, k2, p1, p2, k3) on
  OpenCV's centres (matched to the right dots, so OpenCV is never charged for its grid's order) and of this package's
  ``calibrate`` (the same model) on its own.

    python -m ccs_kornia.bench.micro.bench_circle_grids             # 12 views per grid and tilt
    python -m ccs_kornia.bench.micro.bench_circle_grids --views 6
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse

import cv2
import numpy as np
import torch

from ccs_kornia.data.scenes.marker_views import DIST, K, random_board_pose, render_marker_view
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.modules.detection.boards import CircleGrid
from ccs_kornia.modules.detection.circles.circle_grid import CircleGridDetector
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

BOARDS = {"symmetric 7x5": CircleGrid(7, 5, 0.03), "asymmetric 4x11": CircleGrid(4, 11, 0.02, asymmetric=True),
          "marked origin 10x10": CircleGrid(10, 10, 0.02, marked_origin=True)}
TILTS = (20.0, 40.0, 60.0, 70.0)


def _rms(e: list[np.ndarray]) -> float:
    x = np.concatenate(e) if e else np.array([np.nan])
    return float(np.sqrt(np.nanmean(x ** 2)))


def _match(points: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Each point's nearest true centre (OpenCV's order may be the grid's half-turn)."""
    return np.linalg.norm(points[:, None] - truth[None], axis=-1).argmin(1)


def run_case(board: CircleGrid, tilt: float, views: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    images, truths = [], []
    while len(images) < views:
        rvec, tvec = random_board_pose(board, rng, tilt_deg=tilt, span=(0.5, 0.85))
        image, truth = render_marker_view(board, rvec, tvec, supersample=3)
        img = cv2.GaussianBlur(image.astype(np.float64), (0, 0), 0.7) + rng.normal(0.0, 2.0, image.shape)
        images.append(np.clip(np.round(img), 0, 255).astype(np.uint8))
        truths.append(truth)
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if board.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    obj = board.object_points().numpy().astype(np.float32)
    cv_err, cv_obj, cv_img = [], [], []
    for image, truth in zip(images, truths):
        ok, pts = cv2.findCirclesGrid(image, board.board_size, flags=flags)
        if not ok:
            continue
        pts = pts.reshape(-1, 2).astype(np.float64)
        m = _match(pts, truth)
        cv_err.append(np.linalg.norm(pts - truth[m], axis=-1))
        cv_obj.append(obj[m])
        cv_img.append(pts.astype(np.float32))
    out = {"views": views, "opencv_found": len(cv_img), "opencv_centres_px": _rms(cv_err)}
    if len(cv_img) >= 3:
        _, k, _, _, _ = cv2.calibrateCamera(cv_obj, cv_img, (640, 480), None, None)
        out["opencv_f_pct"] = 100 * abs(k[0, 0] - K[0, 0]) / K[0, 0]
        out["opencv_pp_px"] = float(np.hypot(k[0, 2] - K[0, 2], k[1, 2] - K[1, 2]))
    batch = torch.from_numpy(np.stack(images)).float()[:, None] / 255
    pipe = CalibrationPipeline(CircleGridDetector(board), model=OPENCV5, distortion_correction=False,
                               diagnostics=False)
    with torch.inference_mode():
        res = pipe(batch, board.board_size, board.spacing)
    det = res.detections
    measured = det.corners if res.centre_bias is None else det.corners + res.centre_bias
    raw, fixed = [], []
    for v, truth in enumerate(truths):
        if not bool(det.found[v]):
            continue
        c, mc = det.corners[v].numpy(), measured[v].numpy()
        ok = np.isfinite(c).all(-1)
        m = _match(np.where(ok[:, None], mc, 0.0), truth)  # a grid seen as its half-turn is still the same dots
        raw.append(np.linalg.norm(mc[ok] - truth[m][ok], axis=-1))
        fixed.append(np.linalg.norm(c[ok] - truth[m][ok], axis=-1))
    out.update(ours_found=int(det.found.sum()), ours_measured_px=_rms(raw), ours_corrected_px=_rms(fixed))
    if bool(res.success):
        k = res.K.numpy()
        out["ours_f_pct"] = 100 * abs(k[0, 0] - K[0, 0]) / K[0, 0]
        out["ours_pp_px"] = float(np.hypot(k[0, 2] - K[0, 2], k[1, 2] - K[1, 2]))
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=12)
    p.add_argument("--seed", type=int, default=640_000)
    args = p.parse_args(argv)
    print(f"lens k1, k2 = {DIST[0]}, {DIST[1]}; {args.views} views per grid and tilt")
    print("| grid | tilt up to | found OpenCV / ours | centres px: OpenCV / ours measured / ours corrected | "
          "f error %: OpenCV / ours | principal point px: OpenCV / ours |")
    print("|---|---|---|---|---|---|")
    for b, (name, board) in enumerate(BOARDS.items()):
        for t, tilt in enumerate(TILTS):
            r = run_case(board, tilt, args.views, args.seed + 100 * b + t)
            print(f"| {name} | {tilt:g} deg | {r['opencv_found']} / {r['ours_found']} of {r['views']} | "
                  f"{r['opencv_centres_px']:.3f} / {r['ours_measured_px']:.3f} / {r['ours_corrected_px']:.3f} | "
                  f"{r.get('opencv_f_pct', float('nan')):.3f} / {r.get('ours_f_pct', float('nan')):.3f} | "
                  f"{r.get('opencv_pp_px', float('nan')):.2f} / {r.get('ours_pp_px', float('nan')):.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
