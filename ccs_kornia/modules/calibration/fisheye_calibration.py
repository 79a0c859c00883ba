"""Fisheye (Kannala–Brandt) calibration: hypotheses initialisation -> LM -> view check -> LM, batched over cameras.

1. :func:`~ccs_kornia.modules.calibration.fisheye_init.init_fisheye` proposes the best few equidistant cameras
   (focal-length hypotheses, principal point at the image centre) with every view's pose;
2. the LM core refines ``fx, fy, cx, cy, k1..k4`` and all poses for every kept hypothesis at once (they are
   extra cameras of the batch) and the lowest-cost one is kept per camera;
3. every view is re-posed under that camera (ray DLT, then a poses-only LM): views whose error is an outlier
   (``max(abs, rel * median)``) are left out, views that failed the initialisation are re-admitted when they
   now fit, and the LM runs once more on the views kept.

With ``board_warp`` the board's sag (:mod:`~ccs_kornia.geometry.board_warp`) is estimated with the camera in the LMs
of steps 2 (warm start) and 3; the poses-only LM of step 3 holds it.

The result's ``K`` and ``D`` are ``cv2.fisheye``'s (zero skew), ready for ``cv2.fisheye.undistortImage`` and
kornia's Kannala–Brandt functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import torch
from torch import nn

from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.geometry.models.factory import FISHEYE
from ccs_kornia.modules.calibration.fisheye_init import board_to_ray_poses, init_fisheye
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.outliers import drop_outliers
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["FisheyeCalibrationResult", "calibrate_fisheye", "FisheyeCalibrator"]


@dataclass
class FisheyeCalibrationResult:
    """Kannala–Brandt calibration of C cameras from V views each."""

    K: torch.Tensor  #: (C, 3, 3)
    D: torch.Tensor  #: (C, 4) k1..k4 (cv2.fisheye)
    rvec: torch.Tensor  #: (C, V, 3) world-to-camera axis-angle
    tvec: torch.Tensor  #: (C, V, 3)
    view_rms: torch.Tensor  #: (C, V) px, NaN for views not used
    used: torch.Tensor  #: (C, V) bool
    rms: torch.Tensor  #: (C,) over the used views (cv2's definition)
    std_intrinsics: torch.Tensor  #: (C, 4) std of fx, fy, cx, cy
    std_dist: torch.Tensor  #: (C, 4) std of k1..k4
    covariance: torch.Tensor  #: (C, 8, 8) covariance of fx, fy, cx, cy, k1..k4 marginalised over the poses
    success: torch.Tensor  #: (C,) bool
    lm_status: torch.Tensor  #: (C,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus` of the final LM
    candidate_rms: torch.Tensor  #: (C, V) px of every view with corners under the final camera (used or not)
    #: (C, 2) the board's sag (mrcal's ``calobject_warp``, board units) where ``board_warp`` was given, else None
    warp: torch.Tensor | None = None
    warp_std: torch.Tensor | None = None  #: (C, 2) its 1-sigma


def _kmat(p: torch.Tensor) -> torch.Tensor:
    K = p.new_zeros(*p.shape[:-1], 3, 3)
    K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2], K[..., 2, 2] = p[..., 0], p[..., 1], p[..., 2], p[..., 3], 1
    return K


def calibrate_fisheye(
    corners: torch.Tensor,
    valid: torch.Tensor | None,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    weights: torch.Tensor | None = None,
    num_hypotheses: int = 32,
    keep: int = 3,
    min_corners: int = 6,
    min_views: int = 3,
    outlier_abs_threshold: float = 2.0,
    outlier_rel_threshold: float = 5.0,
    max_iters: int = 100,
    fix: tuple[str, ...] = (),
    initial: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    stall_tol: float = 0.0,
    board_warp: torch.Tensor | None = None,
) -> FisheyeCalibrationResult:
    r"""Calibrate Kannala–Brandt fisheye cameras from planar-board corners, no intrinsic guess needed.

    Args:
        corners: :math:`(C, V, N, 2)` or :math:`(V, N, 2)` pixels.
        valid: matching bool mask (``None``: the finite corners).
        object_points: :math:`(N, 3)` planar board points (``Z = 0``).
        image_size: ``(W, H)``.
        weights: optional per-corner inverse variances (same shape as ``valid``).
        num_hypotheses: focal lengths tried by the initialisation.
        keep: hypotheses refined per camera.
        min_corners: views with fewer corners are not used.
        min_views: cameras with fewer usable views fail.
        outlier_abs_threshold, outlier_rel_threshold: a view is left out when its RMS exceeds
            ``max(abs, rel * median view RMS)``.
        max_iters: LM iterations per stage.
        stall_tol: of the LM (:func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt`): a stage also stops
            where 10 iterations lowered the cost by at most this fraction.
        fix: parameters kept at their initial values, by name (``fx, fy, cx, cy, k1..k4``; e.g. ``("k3", "k4")``
            as ``cv2.fisheye.CALIB_FIX_K3 | CALIB_FIX_K4``, or ``("cx", "cy")`` for the image centre).
        initial: warm start ``(K (C, 3, 3), D (C, 4), rvec (C, V, 3), tvec (C, V, 3), used (C, V))``, e.g. the
            calibration of all the views when subsets of them are calibrated (cross-validation): the hypotheses are
            skipped and the LM starts from this camera and the poses of the views it used. Cameras without a finite
            initial camera, or with fewer than ``min_views`` usable initial views, start from the hypotheses.
        board_warp: :math:`(C, 2)` (or :math:`(2,)` unbatched) the board's sag to start from, estimated with the
            camera (:mod:`~ccs_kornia.geometry.board_warp`; the hypotheses assume a flat board); ``None``: the board
            is flat.

    Returns:
        :class:`FisheyeCalibrationResult` (no camera dim for unbatched input; failed cameras have NaN values).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import Camera
        >>> from ccs_kornia.geometry.models import FISHEYE
        >>> obj = board_object_points(6, 4, 0.05, dtype=torch.float64)
        >>> K = torch.tensor([[200., 0, 322], [0, 201, 237], [0, 0, 1]], dtype=torch.float64)
        >>> D = torch.tensor([0.02, -0.01, 0.002, 0.0], dtype=torch.float64)
        >>> rv = torch.tensor([[0.3, 0.2, 0.0], [-0.2, 0.9, 0.1], [0.1, -0.4, 0.3], [0.5, 0.1, -0.2]], dtype=torch.float64)
        >>> tv = torch.tensor([[-0.1, -0.05, 0.3], [0.0, -0.05, 0.25], [-0.2, 0.0, 0.3], [-0.1, -0.2, 0.3]], dtype=torch.float64)
        >>> uv = Camera.from_opencv(FISHEYE, K, D).project(obj, rv[None], tv[None])[0]
        >>> res = calibrate_fisheye(uv, None, obj, (640, 480))
        >>> bool(res.success), bool((res.K - K).abs().max() < 1e-6), bool(res.rms < 1e-6)
        (True, True, True)
    """
    unbatched = corners.dim() == 3
    if unbatched:
        corners = corners[None]
        valid = None if valid is None else valid[None]
        weights = None if weights is None else weights[None]
    check_tensor(corners, "corners", ["C", "V", "N", "2"], ["V", "N", "2"])
    C, V, N = corners.shape[:3]
    if valid is not None:
        check_tensor(valid, "valid", [C, V, N])
    if weights is not None:
        check_tensor(weights, "weights", [C, V, N])
    check_tensor(object_points, "object_points", [N, 3])
    dt, dev = torch.float64, corners.device
    ok_pts = corners.isfinite().all(-1) & (True if valid is None else valid.bool())
    w = ok_pts.to(dt) if weights is None else torch.where(ok_pts, weights.to(dt), 0.0)
    candidates = (w > 0).sum(-1) >= min_corners
    w = w * candidates[..., None]
    obj = object_points.to(device=dev, dtype=dt)
    model = FISHEYE
    unknown = set(fix) - set(model.param_names)
    if unknown:
        raise ValueError(f"Unknown parameters to fix {sorted(unknown)}; expected names from {model.param_names}.")
    free = [n not in fix for n in model.param_names]
    lm = partial(levenberg_marquardt, max_iters=max_iters, stall_tol=stall_tol)
    if board_warp is not None:
        board_warp = board_warp[None] if unbatched else board_warp
        check_tensor(board_warp, "board_warp", [C, 2])
        board_warp = board_warp.to(device=dev, dtype=dt)

    def sag(sel: torch.Tensor) -> torch.Tensor | None:
        return None if board_warp is None else board_warp[sel]

    def cold(sel: torch.Tensor) -> FisheyeCalibrationResult:
        return _calibrate(model, corners[sel], w[sel], candidates[sel], obj, free, min_views, outlier_abs_threshold,
                          outlier_rel_threshold, lm, None, image_size, num_hypotheses, keep, sag(sel))

    warm = torch.zeros(C, dtype=torch.bool, device=dev)
    if initial is not None:
        K0, D0, rv_i, tv_i, used_i = (x.to(dev) for x in initial)
        if unbatched:
            K0, D0, rv_i, tv_i, used_i = K0[None], D0[None], rv_i[None], tv_i[None], used_i[None]
        p_i = torch.cat([K0[:, 0, 0:1], K0[:, 1, 1:2], K0[:, 0, 2:3], K0[:, 1, 2:3], D0], -1).to(dt)
        used_i = used_i.bool() & candidates & rv_i.isfinite().all(-1) & tv_i.isfinite().all(-1)
        warm = p_i.isfinite().all(-1) & (used_i.sum(-1) >= min_views)

    def warm_start(sel: torch.Tensor) -> FisheyeCalibrationResult:
        return _calibrate(model, corners[sel], w[sel], candidates[sel], obj, free, min_views, outlier_abs_threshold,
                          outlier_rel_threshold, lm, (p_i[sel], rv_i[sel].to(dt), tv_i[sel].to(dt), used_i[sel]),
                          warp=sag(sel))

    out = _merge_cameras(warm, warm_start, cold)
    if unbatched:
        out = FisheyeCalibrationResult(**{f: None if v is None else v[0] for f, v in out.__dict__.items()})
    return out


def _merge_cameras(first: torch.Tensor, run_first, run_rest) -> FisheyeCalibrationResult:
    """Results of ``run_first`` on the cameras where ``first`` (C,) holds and of ``run_rest`` on the others, merged."""
    a, b = first.nonzero().flatten(), (~first).nonzero().flatten()
    if a.numel() == 0:
        return run_rest(b)
    if b.numel() == 0:
        return run_first(a)
    ra, rb = run_first(a), run_rest(b)
    merged = {}
    for f, va in ra.__dict__.items():
        vb = getattr(rb, f)
        if va is None:
            merged[f] = None
            continue
        v = va.new_empty((first.shape[0], *va.shape[1:]))
        v[a], v[b] = va, vb
        merged[f] = v
    return FisheyeCalibrationResult(**merged)


def _calibrate(model, corners, w, candidates, obj, free, min_views, outlier_abs_threshold, outlier_rel_threshold,
               lm, initial, image_size=None, num_hypotheses=32, keep=3, warp=None) -> FisheyeCalibrationResult:
    """Steps 1-3 of :func:`calibrate_fisheye` on batched cameras (``w`` the corner weights, ``candidates`` (C, V));
    with ``initial = (params (C, 8), rvec, tvec, used)`` step 1 is replaced by one LM from that start; ``warp``
    (C, 2) the board's sag to start from (``None``: flat)."""
    C, V, N = corners.shape[:3]
    dev = corners.device
    if initial is not None:
        p_i, rv_i, tv_i, used_i = initial
        res = lm(model, p_i, rv_i.nan_to_num(0.0), tv_i.nan_to_num(0.0), obj, corners, w * used_i[..., None],
                 free=free, board_warp=warp)
        params, rvec, tvec, used0 = res.params, res.rvec, res.tvec, res.view_used
        return _finish(model, corners, w, candidates, obj, free, min_views, outlier_abs_threshold,
                       outlier_rel_threshold, lm, params, rvec, tvec, used0, res.warp)
    # 1. hypotheses; 2. LM on every kept hypothesis as a camera of the batch
    p0, rv0, tv0, init_rms, _ = init_fisheye(corners, w, obj, image_size, num_hypotheses, keep)
    k = p0.shape[1]
    ok0 = init_rms.isfinite()
    wk = (w[:, None] * ok0[..., None]).reshape(C * k, V, N)
    ck = corners[:, None].expand(C, k, V, N, 2).reshape(C * k, V, N, 2)
    res = lm(model, p0.reshape(C * k, 8), rv0.reshape(C * k, V, 3), tv0.reshape(C * k, V, 3), obj, ck, wk, free=free,
             groups=torch.arange(C, device=dev).repeat_interleave(k))
    n_used = res.view_used.sum(-1).view(C, k)
    key = torch.where(res.rms.isfinite(), res.rms, float("inf")).view(C, k) - 1e6 * n_used  # most views, then rms
    best = key.argmin(-1)
    sel = torch.arange(C, device=dev) * k + best
    params, rvec, tvec = res.params[sel], res.rvec[sel], res.tvec[sel]
    return _finish(model, corners, w, candidates, obj, free, min_views, outlier_abs_threshold, outlier_rel_threshold,
                   lm, params, rvec, tvec, res.view_used[sel], warp)


def _finish(model, corners, w, candidates, obj, free, min_views, outlier_abs_threshold, outlier_rel_threshold,
            lm, params, rvec, tvec, used0, warp=None) -> FisheyeCalibrationResult:
    """Step 3 of :func:`calibrate_fisheye`: re-pose every candidate view under the refined camera (and the board's
    sag ``warp``, held), reject outliers, refine again (the sag with the rest)."""
    C = corners.shape[0]
    dt = torch.float64
    rays = model.unproject(corners.to(dt).nan_to_num(0.0), params)
    rv_d, tv_d, ok_d = board_to_ray_poses(rays, obj[:, :2], w)
    rv_c = torch.where(used0[..., None], rvec, rv_d)
    tv_c = torch.where(used0[..., None], tvec, tv_d)
    wc = w * (used0 | ok_d)[..., None]
    poses = lm(model, params, rv_c, tv_c, warped_board(obj, warp), corners, wc, free=[False] * 8)
    cand_rms = poses.view_rms
    used = drop_outliers(cand_rms, used0, candidates, outlier_abs_threshold, outlier_rel_threshold, min_views)
    final = lm(model, params, poses.rvec, poses.tvec, obj, corners, w * used[..., None], free=free, board_warp=warp)
    used = final.view_used

    success = (used.sum(-1) >= min_views) & final.rms.isfinite() & final.params.isfinite().all(-1)
    success = success & (final.params[:, 0] > 0) & (final.params[:, 1] > 0)
    nan = float("nan")

    def fail_nan(x: torch.Tensor) -> torch.Tensor:
        return torch.where(success.view(C, *([1] * (x.dim() - 1))), x, torch.full_like(x, nan))

    std = final.param_std
    # candidate RMS: the final camera, each candidate view's pose refined alone where it was not used
    cand = torch.where(used, final.view_rms, cand_rms)
    out = FisheyeCalibrationResult(
        K=fail_nan(_kmat(final.params)), D=fail_nan(final.params[:, 4:]), rvec=final.rvec, tvec=final.tvec,
        view_rms=torch.where(used, final.view_rms, nan), used=used, rms=fail_nan(final.rms),
        std_intrinsics=fail_nan(std[:, :4]), std_dist=fail_nan(std[:, 4:]), covariance=fail_nan(final.param_covariance),
        success=success, lm_status=final.status,
        candidate_rms=torch.where(candidates, cand, nan),
        warp=None if final.warp is None else fail_nan(final.warp),
        warp_std=None if final.warp is None else fail_nan(
            final.warp_covariance.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()),
    )
    return out


class FisheyeCalibrator(nn.Module):
    """Module form of :func:`calibrate_fisheye` (options fixed at construction).

    Example:
        >>> FisheyeCalibrator(keep=2).keep
        2
    """

    def __init__(self, num_hypotheses: int = 32, keep: int = 3, min_corners: int = 6, min_views: int = 3,
                 outlier_abs_threshold: float = 2.0, outlier_rel_threshold: float = 5.0, max_iters: int = 100,
                 fix: tuple[str, ...] = (), stall_tol: float = 0.0) -> None:
        super().__init__()
        self.num_hypotheses, self.keep = num_hypotheses, keep
        self.min_corners, self.min_views = min_corners, min_views
        self.outlier_abs_threshold, self.outlier_rel_threshold = outlier_abs_threshold, outlier_rel_threshold
        self.max_iters, self.stall_tol = max_iters, stall_tol
        self.fix = tuple(fix)

    def forward(self, corners, valid, object_points, image_size, weights=None) -> FisheyeCalibrationResult:
        return calibrate_fisheye(
            corners, valid, object_points, image_size, weights, num_hypotheses=self.num_hypotheses, keep=self.keep,
            min_corners=self.min_corners, min_views=self.min_views, outlier_abs_threshold=self.outlier_abs_threshold,
            outlier_rel_threshold=self.outlier_rel_threshold, max_iters=self.max_iters, fix=self.fix,
            stall_tol=self.stall_tol,
        )
