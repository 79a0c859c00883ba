"""Real fisheye sets: ccs_kornia's calibrate_fisheye against cv2.fisheye.calibrate on the same OpenCV classic corners.

Corners: cv2.findChessboardCorners (ADAPTIVE_THRESH + NORMALIZE_IMAGE) + cornerSubPix with an 11x11 px window
(``winSize=(5, 5)``; EPS+COUNT, 30, 0.001), the setting that reproduces SOURCE.md's cv2.fisheye figures on
``boofcv_fisheye_chessboard``; ``--subpix-half-window 11`` gives ``verify_opencv.py``'s 23x23 px window, too large
for these small, curved squares. cv2.fisheye.calibrate as ``fisheye_opencv.py`` (ROS flags, views it
rejects dropped and rerun); for ``boofcv_fisheye_chessboard`` also from the intrinsic guess SOURCE.md used.
Prints K, D, RMS and views used for both, and the published reference where there is one.

    python -m ccs_kornia.bench.micro.fisheye_real [--data ../shared/data/real]
"""

from __future__ import annotations

import argparse
import glob
import os
import time

import cv2
import numpy as np
import torch

from ccs_kornia.bench.methods.fisheye_opencv import opencv_fisheye
from ccs_kornia.modules.calibration.fisheye_calibration import calibrate_fisheye

SETS = {
    # name: (cols, rows, square, reference fx, fy, cx, cy or None, intrinsic guess for cv2 or None)
    "ros_fisheye_mono": (8, 6, 1.0, (290.050152, 289.392837, 399.938345, 273.885669), None),
    "boofcv_fisheye_chessboard": (6, 4, 0.03, None, ((190.0, 0, 319.5), (0, 190.0, 319.5), (0, 0, 1))),
}
CRIT = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def detect(folder, cols, rows, half_window=5):
    files = sorted(glob.glob(os.path.join(folder, "*.png")) + glob.glob(os.path.join(folder, "*.jpg")),
                   key=lambda f: (len(os.path.basename(f)), f))
    names, corners, size = [], [], None
    for f in files:
        g = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        size = (g.shape[1], g.shape[0])
        ok, c = cv2.findChessboardCorners(g, (cols, rows), cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE)
        names.append(os.path.basename(f))
        corners.append(cv2.cornerSubPix(g, c, (half_window, half_window), (-1, -1), CRIT).reshape(-1, 2) if ok else None)
    return names, corners, size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data", "real"))
    ap.add_argument("--sets", nargs="+", default=list(SETS))
    ap.add_argument("--subpix-half-window", type=int, default=5)
    a = ap.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    for name in a.sets:
        cols, rows, square, ref, guess = SETS[name]
        names, det, size = detect(os.path.join(a.data, name), cols, rows, a.subpix_half_window)
        found = [i for i, c in enumerate(det) if c is not None]
        obj = np.zeros((cols * rows, 3))
        obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
        print(f"\n== {name}: {size[0]}x{size[1]}, board {cols}x{rows}, classic corners (cornerSubPix half-window "
              f"{a.subpix_half_window}) found on {len(found)}/{len(det)} images")
        if ref:
            print(f"reference (ost.yaml)       fx {ref[0]:8.2f} fy {ref[1]:8.2f} cx {ref[2]:8.2f} cy {ref[3]:8.2f}")
        uv = torch.tensor(np.stack([det[i] for i in found]), dtype=torch.float64)
        t = time.perf_counter()
        res = calibrate_fisheye(uv, None, torch.tensor(obj), size)
        dt = time.perf_counter() - t
        K, D = res.K.numpy(), res.D.numpy()
        print(f"ccs_kornia calibrate_fisheye fx {K[0, 0]:8.2f} fy {K[1, 1]:8.2f} cx {K[0, 2]:8.2f} cy {K[1, 2]:8.2f} "
              f"D {np.array2string(D, precision=4)} RMS {float(res.rms):.5f} px, views used {int(res.used.sum())}/{len(found)} "
              f"({dt:.2f} s); std fx {float(res.std_intrinsics[0]):.3f} cx {float(res.std_intrinsics[2]):.3f}")
        if ref:
            print("  |diff| to reference       " + " ".join(f"{abs(v - r):.2f}" for v, r in zip((K[0, 0], K[1, 1], K[0, 2], K[1, 2]), ref)))
        for label, g in [("cv2.fisheye (no guess)", None)] + ([("cv2.fisheye (guess)", guess)] if guess else []):
            r = opencv_fisheye(obj, [det[i] for i in found], size, K_guess=g)
            if not r["ok"]:
                print(f"{label:26s} failed: {r['error']}")
                continue
            Kc = r["K"]
            used = [found[i] for i in r["used"]]
            print(f"{label:26s} fx {Kc[0, 0]:8.2f} fy {Kc[1, 1]:8.2f} cx {Kc[0, 2]:8.2f} cy {Kc[1, 2]:8.2f} "
                  f"D {np.array2string(r['D'], precision=4)} RMS {r['rms']:.5f} px, views used {len(used)}/{len(found)}")
            # ours on exactly cv2's views, for an RMS on the same data
            sub = torch.tensor([found.index(i) for i in used])
            mine = calibrate_fisheye(uv[sub], None, torch.tensor(obj), size)
            print(f"  ccs_kornia on those views: RMS {float(mine.rms):.5f} px (views used {int(mine.used.sum())})")
            left = [names[i] for i in found if i not in used]
            if left:
                print(f"  views cv2 could not use: {left}")


if __name__ == "__main__":
    main()
