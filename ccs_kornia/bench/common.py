"""Shared pieces of the benchmark sections: the two solvers side by side, the paper's metrics, summaries, timing."""

from __future__ import annotations

import math
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.metrics import e_fl, e_ip, e_pp
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import K1K2, OPENCV5, PINHOLE
from ccs_kornia.modules.correction.distortion_net import DEFAULT_DISTORTION_WEIGHTS
from ccs_kornia.modules.detection.base import measured_corners

__all__ = [
    "CV2_FLAGS",
    "cv2_calibrate",
    "ccs_calibrate",
    "calibration_metrics",
    "k0_scaled_intrinsics",
    "distortion_available",
    "summary",
    "Timer",
    "e_ip_px",
    "format_metric",
]

#: ``cv2.calibrateCamera``'s flags for the models it fits the way ours do
CV2_FLAGS: dict[CameraModel, int] = {
    OPENCV5: 0,
    K1K2: cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3,
    PINHOLE: cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
}


def cv2_calibrate(
    corners: np.ndarray, found: np.ndarray, board: tuple[int, int], square: float, image_size: tuple[int, int],
    model: CameraModel = OPENCV5,
) -> dict:
    """``cv2.calibrateCamera`` on the found views of one camera.

    Args:
        corners: :math:`(V, N, 2)` pixels (NaN at the hidden corners of a partial board: left out).
        found: :math:`(V,)` bool.
        model: ``OPENCV5`` (flags 0), ``K1K2`` (ZERO_TANGENT_DIST + FIX_K3) or ``PINHOLE`` (:data:`CV2_FLAGS`).

    Returns:
        ``{"success", "K" (3,3), "dist", "rms", "views"}`` (K NaN on failure).
    """
    obj = board_object_points(board[0], board[1], square, dtype=torch.float64).numpy().astype(np.float32)
    idx = np.nonzero(found)[0]
    fail = {"success": False, "K": np.full((3, 3), np.nan), "dist": None, "rms": float("nan"), "views": int(len(idx))}
    if len(idx) < 3:
        return fail
    # a partial board (hidden corners NaN) gives OpenCV its measured corners only, as any view may
    keep = [np.isfinite(corners[i]).all(-1) for i in idx]
    img_pts = [corners[i][k].reshape(-1, 1, 2).astype(np.float32) for i, k in zip(idx, keep)]
    obj_pts = [obj[k] for k in keep]
    try:
        rms, K, dist, _, _ = cv2.calibrateCamera(obj_pts, img_pts, tuple(int(s) for s in image_size), None, None,
                                                 flags=CV2_FLAGS[model])
    except cv2.error:
        return fail
    ok = bool(np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0)
    return {"success": ok, "K": K if ok else fail["K"], "dist": dist.ravel().tolist(), "rms": float(rms), "views": int(len(idx))}


def ccs_calibrate(
    corners: np.ndarray, found: np.ndarray, board: tuple[int, int], square: float, image_size: tuple[int, int],
    model: CameraModel = OPENCV5, device: str = "cpu",
) -> dict:
    """:class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver`, batched over cameras (trials).

    Args:
        corners: :math:`(C, V, N, 2)` pixels.
        found: :math:`(C, V)` bool.
        model: the camera model (:mod:`ccs_kornia.geometry.models`).

    Returns:
        ``{"success" (C,), "K" (C,3,3), "rms" (C,), "views" (C,) used views}`` as numpy arrays.
    """
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    c = torch.as_tensor(corners, dtype=torch.float64, device=device)
    f = torch.as_tensor(found, dtype=torch.bool, device=device)
    valid = measured_corners(c, f)
    obj = board_object_points(board[0], board[1], square, dtype=torch.float64, device=device)
    with torch.inference_mode():
        res = CalibrationSolver(model=model)(c, valid, obj, image_size)
    return {
        "success": res.success.cpu().numpy(),
        "K": res.K.cpu().numpy(),
        "rms": res.rms.cpu().numpy(),
        "views": res.used.sum(-1).cpu().numpy(),
    }


def e_ip_px(K, K_true) -> float:
    """:func:`ccs_kornia.geometry.metrics.e_ip` of one camera (arrays or tensors, 3x3) as a float."""
    as64 = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float64)  # noqa: E731
    return float(e_ip(as64(K), as64(K_true)))


def summary(values, prefix: str = "") -> dict:
    """``mean, median, p95, std, var, min, max, n`` of the finite values (None when there are none)."""
    a = np.asarray([v for v in np.ravel(values) if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    keys = ("mean", "median", "p95", "std", "var", "min", "max")
    if a.size == 0:
        return {**{prefix + k: None for k in keys}, prefix + "n": 0}
    vals = (a.mean(), np.median(a), np.percentile(a, 95), a.std(), a.var(), a.min(), a.max())
    return {**{prefix + k: float(v) for k, v in zip(keys, vals)}, prefix + "n": int(a.size)}


class Timer:
    """Context manager measuring wall seconds: ``with Timer() as t: ...; t.seconds``."""

    def __enter__(self) -> Timer:
        self._t = time.perf_counter()
        self.seconds = math.nan
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self._t


def calibration_metrics(
    K: np.ndarray, K_true: np.ndarray, success: np.ndarray, rms: np.ndarray, views: np.ndarray,
    K_scaled: np.ndarray | None = None,
) -> dict:
    """Paper metrics over trials: ``K (T,3,3)``, ``K_true (T,3,3)``, ``success (T,)``, ``rms (T,)``, ``views (T,)``.

    ``K_scaled`` (optional, ``(T,3,3)``): the true camera with the radial model's ``k0`` folded in (see
    :func:`k0_scaled_intrinsics`); gives ``e_ip_k0``, the error that is left once the unobservable scale is
    set aside.
    """
    Kt, Kg = torch.as_tensor(K, dtype=torch.float64), torch.as_tensor(K_true, dtype=torch.float64)
    fl, pp, ip = e_fl(Kt, Kg).numpy(), e_pp(Kt, Kg).numpy(), e_ip(Kt, Kg).numpy()
    ok = np.asarray(success, dtype=bool) & np.isfinite(ip)
    s_ip = summary(ip[ok])
    extra = {}
    if K_scaled is not None:
        extra["e_ip_k0"] = summary(e_ip(Kt, torch.as_tensor(K_scaled, dtype=torch.float64)).numpy()[ok])["mean"]
    return {**extra,
        "trials": int(len(ok)),
        "failures": int((~ok).sum()),
        "e_fl": summary(fl[ok])["mean"],
        "e_pp": summary(pp[ok])["mean"],
        "e_ip": s_ip["mean"],
        "e_ip_median": s_ip["median"],
        "e_ip_var": s_ip["var"],
        "e_ip_max": s_ip["max"],
        "rms": summary(np.asarray(rms)[ok])["mean"],
        "views_used": summary(np.asarray(views, dtype=np.float64)[ok])["mean"],
        "e_ip_per_trial": [float(v) if k else None for v, k in zip(ip, ok)],
    }


def k0_scaled_intrinsics(K: np.ndarray, radial: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """The camera a view with the paper's radial ``k0`` looks like near the image centre ``c``.

    ``r_d ~ k0 r_c`` for small radii, so the image is the ideal one scaled by ``k0`` about ``c``:
    ``f' = k0 f`` and ``p' = c + k0 (p - c)``. No calibration can tell that scale from the focal length.

    Args:
        K: :math:`(T, 3, 3)`; radial: :math:`(T, 3)` ``(k0, k1, k2)``; image_size: ``(W, H)``.
    """
    K = np.array(K, dtype=np.float64, copy=True)
    k0 = np.asarray(radial, dtype=np.float64)[:, 0]
    c = np.array([(image_size[0] - 1) / 2.0, (image_size[1] - 1) / 2.0])
    K[:, 0, 0] *= k0
    K[:, 1, 1] *= k0
    K[:, 0, 2] = c[0] + k0 * (K[:, 0, 2] - c[0])
    K[:, 1, 2] = c[1] + k0 * (K[:, 1, 2] - c[1])
    return K


def format_metric(x) -> str:
    """A metric of the calibration sections' log lines (E_IP, its variance) to three decimals, ``   n/a`` where the
    calibration gave none, so the columns of the log line up.

    Example:
        >>> format_metric(0.12345), format_metric(None)
        ('0.123', '   n/a')
    """
    return "   n/a" if x is None else f"{x:.3f}"


def distortion_available(weights: str | Path | None = None):
    """``(net, "")`` when the DistortionNet module and its weights load, else ``(None, reason)``."""
    try:
        from ccs_kornia.modules.correction import radial_warp  # noqa: F401
        from ccs_kornia.modules.correction.distortion_net import DistortionNet
    except ImportError as err:
        return None, f"distortion correction module not available ({err})"
    path = Path(weights) if weights else DEFAULT_DISTORTION_WEIGHTS
    if not path.is_file():
        return None, f"distortion correction weights not available ({path} not found)"
    try:
        return DistortionNet.from_export(path), ""
    except Exception as err:  # a half-written or incompatible export must not stop the other sections
        return None, f"distortion correction weights could not be loaded ({type(err).__name__}: {err})"
