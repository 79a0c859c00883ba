"""``cv2.fisheye.calibrate`` as its users run it (the ROS recipe), for the fisheye benchmarks.

Flags ``CALIB_RECOMPUTE_EXTRINSIC | CALIB_CHECK_COND | CALIB_FIX_SKEW`` (as ``ros_fisheye_mono/reference/
calibrate.py``), no intrinsic guess unless given. When OpenCV rejects a view ("CALIB_CHECK_COND - Ill-conditioned
matrix for input array N"), that view is dropped and the calibration rerun, as users do; anything else that
raises is a failure.
"""

from __future__ import annotations

import re

import cv2
import numpy as np

__all__ = ["opencv_fisheye"]

FLAGS = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_CHECK_COND | cv2.CALIB_FIX_SKEW


def opencv_fisheye(obj, corners, image_size, K_guess=None, flags=FLAGS, min_views=3,
                   criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)):
    """Returns dict(ok, K, D, rms, used (list of view indices), error) for one camera.

    obj: (N, 3) array; corners: list of (N, 2) arrays (one per view).
    """
    views = list(range(len(corners)))
    o = np.asarray(obj, np.float64).reshape(1, -1, 3)
    f = flags | (cv2.CALIB_USE_INTRINSIC_GUESS if K_guess is not None else 0)
    last = ""
    while len(views) >= min_views:
        K = None if K_guess is None else np.array(K_guess, np.float64)
        try:
            rms, K, D, _, _ = cv2.fisheye.calibrate(
                [o] * len(views), [np.asarray(corners[i], np.float64).reshape(1, -1, 2) for i in views],
                tuple(int(s) for s in image_size), K, None if K is None else np.zeros(4), flags=f, criteria=criteria)
        except cv2.error as e:
            last = str(e).strip().splitlines()[-1]
            m = re.search(r"input array (\d+)", str(e))
            if m is None:
                return dict(ok=False, K=None, D=None, rms=float("nan"), used=views, error=last)
            views.pop(int(m.group(1)))
            continue
        ok = bool(np.isfinite(K).all() and np.isfinite(D).all() and np.isfinite(rms))
        return dict(ok=ok, K=K, D=D.ravel(), rms=float(rms), used=views, error="" if ok else "non-finite result")
    return dict(ok=False, K=None, D=None, rms=float("nan"), used=views, error=f"fewer than {min_views} views left: {last}")
