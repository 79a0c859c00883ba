"""``cv2.fisheye.calibrate`` as its users run it (the ROS recipe), for the fisheye benchmarks.

Flags ``CALIB_RECOMPUTE_EXTRINSIC | CALIB_CHECK_COND | CALIB_FIX_SKEW`` (as ``ros_fisheye_mono/reference/
calibrate.py``), no intrinsic guess unless given (OpenCV then starts from ``f = max(W, H) / pi`` at the image
centre). Views OpenCV cannot use are removed and the calibration rerun, as users do:

* an error naming a view ("Ill-conditioned matrix for input array N"): that view is dropped;
* an error naming none (``InitExtrinsics`` / ``ComputeJacobians`` assertions): every view is first tried alone
  with the intrinsics fixed at the starting guess and those that fail are dropped; if none fails alone, the
  single view whose removal lets the calibration succeed with the lowest RMS is dropped;
* anything else, or fewer than ``min_views`` views left: a failure.
"""

from __future__ import annotations

import re

import cv2
import numpy as np

__all__ = ["opencv_fisheye"]

FLAGS = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_CHECK_COND | cv2.CALIB_FIX_SKEW
CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def _calib(o, corners, views, size, K, flags, criteria):
    Kc = None if K is None else np.array(K, np.float64)
    return cv2.fisheye.calibrate(
        [o] * len(views), [np.asarray(corners[i], np.float64).reshape(1, -1, 2) for i in views], size, Kc,
        None if Kc is None else np.zeros(4), flags=flags, criteria=criteria)


def opencv_fisheye(obj, corners, image_size, K_guess=None, flags=FLAGS, min_views=3, criteria=CRITERIA):
    """Returns dict(ok, K, D, rms, used (view indices), error) for one camera.

    obj: (N, 3) array; corners: list of (N, 2) arrays (one per view).
    """
    size = tuple(int(s) for s in image_size)
    views = list(range(len(corners)))
    o = np.asarray(obj, np.float64).reshape(1, -1, 3)
    f = flags | (cv2.CALIB_USE_INTRINSIC_GUESS if K_guess is not None else 0)
    start = np.array(K_guess, np.float64) if K_guess is not None else np.array(
        [[max(size) / np.pi, 0, size[0] / 2 - 0.5], [0, max(size) / np.pi, size[1] / 2 - 0.5], [0, 0, 1]])
    screened, last = False, ""
    while len(views) >= min_views:
        try:
            rms, K, D, _, _ = _calib(o, corners, views, size, K_guess, f, criteria)
            ok = bool(np.isfinite(K).all() and np.isfinite(D).all() and np.isfinite(rms))
            return dict(ok=ok, K=K, D=D.ravel(), rms=float(rms), used=views, error="" if ok else "non-finite result")
        except cv2.error as e:
            last = str(e).strip().splitlines()[-1]
            m = re.search(r"input array (\d+)", str(e))
            if m is not None:
                views.pop(int(m.group(1)))
                continue
        if not screened:
            screened = True
            alone_ok = []
            for i in views:
                try:
                    _calib(o, corners, [i], size, start, FLAGS | cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_INTRINSIC, criteria)
                    alone_ok.append(i)
                except cv2.error:
                    pass
            if len(alone_ok) < len(views):
                views = alone_ok
                continue
        best = None
        for j in range(len(views)):
            trial = views[:j] + views[j + 1:]
            try:
                rms, K, D, _, _ = _calib(o, corners, trial, size, K_guess, f, criteria)
            except cv2.error:
                continue
            if np.isfinite(rms) and (best is None or rms < best[0]):
                best = (rms, trial)
        if best is None:
            break
        views = best[1]
    return dict(ok=False, K=None, D=None, rms=float("nan"), used=views, error=f"no usable set of >= {min_views} views: {last}")
