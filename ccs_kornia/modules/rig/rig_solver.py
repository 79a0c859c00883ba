r"""Rig calibration: stereo heads and multi-camera rigs from board corners, batched over rigs.

Pipeline of :class:`RigSolver` (each step a module of its own):

1. each camera alone (:mod:`~ccs_kornia.modules.rig.rig_init`): its own calibration with its model (or the
   given ``initial`` camera), its board pose in every frame with enough corners;
2. every camera's pose relative to camera 0: robust means over shared frames, chained over the maximum spanning tree
   of the co-visibility graph (cameras not connected to camera 0: ``ValueError`` naming them and their shared frames);
3. one joint Levenberg-Marquardt (:mod:`~ccs_kornia.modules.rig.rig_lm`) over all intrinsics, the extrinsics
   of cameras ``1..C-1`` and one board pose per frame (frame poses eliminated by a Schur complement); each camera's
   intrinsics carry a prior, the information its own views give it alone (``intrinsics_prior``), so the rig cannot
   drag them beyond what those views allow (the prior is held in the units of the rig's own residuals: a camera the
   one-pose-per-frame fit leaves with k times the squared error its noise explains is held by k - 1 times its own
   views' information, so a consistent rig is not held and an inconsistent one firmly);
4. frames that one board pose does not explain (a board that moved between the cameras' exposures, a mis-paired
   frame: :mod:`~ccs_kornia.modules.rig.frame_consistency`) are down-weighted by a robust kernel of their
   disagreement and the rig fitted again (``frame_kernel``, ``frame_passes``); then an outlier check of every
   camera x frame observation (RMS above ``max(abs, rel * median)``) and a fit without them;
5. figures (:mod:`~ccs_kornia.modules.rig.rig_diagnostics`): covariance -> baseline, rotation and intrinsics
   standard deviations; how far each intrinsic moved in units of its single-camera 1-sigma; epipolar RMS on the fit
   frames and on frames held out (k-fold over frames); the links between cameras, the session's advice; the verdict.

Nothing requires a camera to see the whole board or every frame: partial boards and missing frames only change the
weights. Cameras of different models (pinhole and fisheye) mix in one rig.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
from torch import nn

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import CAMERA_MODELS, OPENCV5
from ccs_kornia.geometry.poses import pair_pose
from ccs_kornia.geometry.so3 import exp_so3, log_so3
from ccs_kornia.modules.calibration.board_symmetry import (
    align_frame_orders,
    board_symmetries,
    undo_symmetry,
)
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.calibration.outliers import drop_outliers
from ccs_kornia.modules.calibration.quality.diagnostics import split_views
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.rig.frame_consistency import (
    FrameKernel,
    board_motion,
    frame_disagreement,
    own_view_errors,
)
from ccs_kornia.modules.rig.rig_diagnostics import (
    RigVerdictThresholds,
    epipolar_sums,
    rig_verdict,
)
from ccs_kornia.modules.rig.rig_init import initial_rig_cameras, rig_extrinsics
from ccs_kornia.modules.rig.rig_lm import rig_layout, rig_levenberg_marquardt
from ccs_kornia.modules.rig.rig_state import RigObservations, RigState
from ccs_kornia.modules.rig.session_advice import session_advice, shared_frames
from ccs_kornia.modules.rig.stereo import StereoPair, stereo_pair
from ccs_kornia.runtime.checks import check_tensor
from ccs_kornia.runtime.threads import small_problem_threads

__all__ = ["DRAGGED_EXCESS", "FRAME_SCALE", "FRAME_SCALE_MIN_PX", "PRIOR_INFLATION", "RigResult", "RigSolver",
           "calibrate_rig"]

#: default ``intrinsics_prior``: the prior's information is divided by this factor; see ``docs/rig.md`` for the
#: measurement behind it
PRIOR_INFLATION = 1.0
#: a camera whose squared error under the rig exceeds what its noise explains by this factor (1: twice) has been
#: dragged by the rig's frames: its intrinsics' move counts in the verdict and the advice
DRAGGED_EXCESS = 1.0
#: a frame's disagreement is weighed against this many times the median per-view RMS of the cameras' own poses ...
FRAME_SCALE = 3.0
#: ... and never against less than this (px)
FRAME_SCALE_MIN_PX = 0.1


@dataclass
class RigResult:
    """Calibration of one rig of C cameras over F frames (see ``docs/rig.md``)."""

    success: bool
    reason: str  #: "" when success; else one line naming cameras / frames
    names: list[str]
    image_sizes: list[tuple[int, int]]  #: (W, H) per camera
    cameras: Camera  #: the C solved cameras (``cameras[c]``: camera c)
    R: torch.Tensor  #: (C, 3, 3) x_c = R_c x_0 + T_c; R_0 = I
    T: torch.Tensor  #: (C, 3) board unit; T_0 = 0
    board_rvec: torch.Tensor  #: (F, 3) board -> camera 0, NaN for frames no camera used
    board_tvec: torch.Tensor  #: (F, 3)
    used: torch.Tensor  #: (C, F) bool
    rms_matrix: torch.Tensor  #: (C, F) px, NaN where unused
    camera_rms: torch.Tensor  #: (C,)
    rms: float
    baseline_std: torch.Tensor  #: (C,) 1-sigma of |T_c|; 0 for camera 0
    rotation_std_deg: torch.Tensor  #: (C,) 1-sigma rotation error of R_c (sqrt of the trace of its covariance), deg
    intrinsics_std: list[torch.Tensor]  #: per camera std of (fx, fy, cx, cy, coeffs...), 0 where fixed
    epipolar_rms: torch.Tensor  #: (C, C) px, symmetric, NaN where no shared corner, 0 on the diagonal
    heldout_epipolar_rms: torch.Tensor  #: (C, C) px on held-out frames (k-fold), NaN if too few frames
    verdict: str  #: "good" | "usable" | "not reliable: <what to do>"
    reasons: list[str] = field(default_factory=list)  #: what made the verdict less than good
    lm_status: LMStatus = LMStatus.NO_DATA  #: how the joint LM ended
    iterations: int = 0  #: joint LM iterations
    #: (C, F) int64: 0 where a camera's corners were used in the detector's numbering, k > 0 where they were
    #: renumbered by the board's k-th symmetry (1: the 180-degree turn, i.e. reversed) to agree with the frame
    corner_order: torch.Tensor | None = None
    #: per camera the intrinsics the joint fit started from (its own calibration, or the given ``initial``)
    single_cameras: Camera | None = None
    #: per camera the 1-sigma of (fx, fy, cx, cy, coeffs...) from its own views alone (zeros where fixed)
    single_std: list[torch.Tensor] | None = None
    #: per camera (joint - single) / single 1-sigma of every intrinsic (0 where fixed)
    intrinsics_moved_sigma: list[torch.Tensor] | None = None
    #: (F,) px: how much worse one board pose explains the frame's cameras than each camera's own pose (NaN for
    #: frames with fewer than two cameras; :mod:`~ccs_kornia.modules.rig.frame_consistency`)
    frame_disagreement: torch.Tensor | None = None
    #: (F,) the robust weight each frame had in the final fit (1: fully counted)
    frame_weight: torch.Tensor | None = None
    #: (F,) px per frame period the board moved in the image around the frame (NaN without frame times/neighbours)
    frame_motion: torch.Tensor | None = None
    frame_scale: float = float("nan")  #: px, the scale of the frame kernel
    #: (C, C) effective shared frames of each pair (the frame weights of the frames both cameras use)
    shared_frames: torch.Tensor | None = None
    advice: list[str] = field(default_factory=list)  #: what the next session should record differently
    #: (C,) how firmly each camera's intrinsics were held: its prior's information over its own views' (the rig's
    #: squared error of the camera over what its noise explains, less 1, over ``intrinsics_prior``); 0 without prior
    prior_weight: torch.Tensor | None = None
    #: (2,) the board's sag (mrcal's ``calobject_warp``, board units) where the fit estimated it, else None
    board_warp: torch.Tensor | None = None
    board_warp_std: torch.Tensor | None = None  #: (2,) its 1-sigma

    def pair(self, i: int, j: int) -> StereoPair:
        """Pose of camera ``j`` relative to camera ``i`` (``x_j = R x_i + T``) with ``E`` and ``F``."""
        R, T = pair_pose(self.R, self.T, i, j)
        return stereo_pair(self.cameras[i], self.cameras[j], R, T)

    @property
    def converged(self) -> bool:
        """The joint LM settled at an optimum: converged or stalled
        (:attr:`~ccs_kornia.modules.calibration.schur_lm.LMStatus.converged`)."""
        return self.lm_status.converged

    @property
    def baseline(self) -> torch.Tensor:
        """(C,) ``|T_c|`` in the board's unit."""
        return self.T.norm(dim=-1)


def _check(corners, valid, object_points, image_sizes, weights):
    check_tensor(corners, "corners", ["C", "F", "N", "2"], ["B", "C", "F", "N", "2"])
    if valid is None:
        valid = corners.isfinite().all(-1)
    check_tensor(valid, "valid", corners.shape[:-1])
    N = corners.shape[-2]
    check_tensor(object_points, "object_points", [N, 3])
    C = corners.shape[-4]
    if C < 2:
        raise ValueError(f"A rig needs at least 2 cameras, got C={C}.")
    if len(image_sizes) != C or any(len(s) != 2 or min(int(s[0]), int(s[1])) <= 0 for s in image_sizes):
        raise ValueError(f"image_sizes must be {C} pairs (W, H) with positive entries, got {image_sizes!r}.")
    if weights is not None:
        check_tensor(weights, "weights", corners.shape[:-1])
    return valid


def _per_camera(value, C: int, what: str) -> list:
    if value is None or isinstance(value, (str, bool, CameraModel)):
        return [value] * C
    value = list(value)
    if len(value) != C:
        raise ValueError(f"{what} needs one entry per camera ({C}), got {len(value)}.")
    return value


class RigSolver(nn.Module):
    r"""Calibrate camera rigs (intrinsics and extrinsics) from board corners; batched over rigs.

    Args:
        models: one model for every camera or one per camera (:mod:`ccs_kornia.geometry.models`: ``PINHOLE``,
            ``K1K2``, ``OPENCV5``, ``RATIONAL``, ``FISHEYE``).
        dtype: solve precision.
        max_iters: joint LM iterations at most.
        min_corners: a camera x frame observation with fewer valid corners is not used.
        ftol: the joint LM stops when an accepted step lowers the cost by less than this fraction.
        stall_tol: the joint LM also stops where 10 iterations lowered the cost by at most this fraction (0: never;
            :func:`~ccs_kornia.modules.calibration.schur_lm.schur_lm`).
        outlier_abs_threshold, outlier_rel_threshold: an observation whose RMS exceeds ``max(abs, rel * median)`` is
            left out of the second fit.
        folds: frames are split into this many folds for the held-out epipolar RMS (0: none); needs at least
            ``min_heldout_frames`` used frames.
        min_heldout_frames: fewer used frames give NaN held-out figures.
        thresholds: :class:`~ccs_kornia.modules.rig.rig_diagnostics.RigVerdictThresholds`.
        symmetric_board: the detector may number a symmetric board's corners in any of its symmetric orders (a
            180-degree turn; also 90 degrees for square grids), differently per camera and frame: each observation
            is renumbered to agree with the frame's reference camera
            (:mod:`~ccs_kornia.modules.calibration.board_symmetry`; ``RigResult.corner_order`` says where).
        intrinsics_prior: each free camera's intrinsics carry a Gaussian prior at its own calibration: the
            information of its own views times ``k - 1`` (``k``: the camera's squared error under the rig over what
            its noise explains; the first fit takes 1) divided by this factor; ``None``: no prior (the intrinsics
            move wherever the joint fit takes them).
        frame_kernel: :class:`~ccs_kornia.modules.rig.frame_consistency.FrameKernel` (or its name) weighting each
            frame by its disagreement; ``none``: every frame counts fully.
        frame_scale: px, the kernel's scale; default ``max(FRAME_SCALE * median own-pose view RMS,
            FRAME_SCALE_MIN_PX)``.
        frame_passes: reweighting passes (each a joint fit).
        board_warp: estimate the board's sag with the rig (mrcal's two parameters,
            :mod:`~ccs_kornia.geometry.board_warp`): ``RigResult.board_warp`` and its 1-sigma. Whether it
            is worth keeping is judged on held-out frames by the caller (the rig pipeline compares the held-out
            epipolar RMS of both fits).

    Shape:
        corners :math:`(C, F, N, 2)` or :math:`(B, C, F, N, 2)` px (NaN where not seen), valid :math:`(C, F, N)` /
        :math:`(B, C, F, N)` bool, object_points :math:`(N, 3)`, image_sizes C pairs ``(W, H)``, weights as valid ->
        :class:`RigResult` (a list of B of them for batched input).

    Example:
        >>> from ccs_kornia.data.scenes.rig import render_rig
        >>> K = torch.tensor([[500., 0, 320], [0, 500, 240], [0, 0, 1]], dtype=torch.float64)
        >>> R = torch.eye(3, dtype=torch.float64).expand(2, 3, 3)
        >>> T = torch.tensor([[0.0, 0, 0], [-0.1, 0, 0]], dtype=torch.float64)
        >>> from ccs_kornia.geometry.models import K1K2
        >>> cam = Camera.from_opencv(K1K2, K, torch.tensor([-0.1, 0.01], dtype=torch.float64), (640, 480))
        >>> s = render_rig(Camera.cat([cam, cam]), R, T, num_frames=8)
        >>> res = RigSolver(K1K2, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
        >>> res.success, round(float(res.T[1, 0]), 6)
        (True, -0.1)
    """

    def __init__(
        self,
        models: CameraModel | Sequence[CameraModel] = OPENCV5,
        dtype: torch.dtype = torch.float64,
        max_iters: int = 100,
        min_corners: int = 6,
        ftol: float = 1e-10,
        stall_tol: float = 0.0,
        outlier_abs_threshold: float = 2.0,
        outlier_rel_threshold: float = 5.0,
        folds: int = 5,
        min_heldout_frames: int = 4,
        thresholds: RigVerdictThresholds | None = None,
        symmetric_board: bool = True,
        intrinsics_prior: float | None = PRIOR_INFLATION,
        frame_kernel: FrameKernel | str = FrameKernel.CAUCHY,
        frame_scale: float | None = None,
        frame_passes: int = 2,
        board_warp: bool = False,
    ) -> None:
        super().__init__()
        self.board_warp = bool(board_warp)
        for m in [models] if isinstance(models, CameraModel) else models:
            if m not in CAMERA_MODELS.values():
                raise ValueError(f"A rig camera's model must be one of the models {', '.join(CAMERA_MODELS)} "
                                 f"(ccs_kornia.geometry.models), got {m!r}.")
        self.models = models if isinstance(models, CameraModel) else list(models)
        self.dtype = dtype
        self.max_iters = max_iters
        self.min_corners = max(int(min_corners), 4)
        self.ftol = ftol
        self.stall_tol = stall_tol
        self.outlier_abs_threshold = outlier_abs_threshold
        self.outlier_rel_threshold = outlier_rel_threshold
        self.folds = int(folds)
        self.min_heldout_frames = max(int(min_heldout_frames), 2)
        self.thresholds = thresholds or RigVerdictThresholds()
        self.symmetric_board = bool(symmetric_board)
        if intrinsics_prior is not None and not intrinsics_prior > 0:
            raise ValueError(f"intrinsics_prior must be positive or None, got {intrinsics_prior}.")
        self.intrinsics_prior = None if intrinsics_prior is None else float(intrinsics_prior)
        self.frame_kernel = FrameKernel(frame_kernel)
        if frame_scale is not None and not frame_scale > 0:
            raise ValueError(f"frame_scale must be positive or None, got {frame_scale}.")
        self.frame_scale = None if frame_scale is None else float(frame_scale)
        self.frame_passes = max(int(frame_passes), 0)

    def forward(
        self,
        corners: torch.Tensor,
        valid: torch.Tensor | None,
        object_points: torch.Tensor,
        image_sizes: Sequence[tuple[int, int]],
        initial: Sequence[Camera | None] | Camera | None = None,
        fixed: Sequence[bool] | None = None,
        names: Sequence[str] | None = None,
        weights: torch.Tensor | None = None,
        frame_times: torch.Tensor | None = None,
    ) -> RigResult | list[RigResult]:
        """Calibrate (see the class doc).

        Args:
            corners: :math:`(C, F, N, 2)` / :math:`(B, C, F, N, 2)` observed pixels.
            valid: matching bool mask (``None``: the finite corners).
            object_points: :math:`(N, 3)` board points (their unit is the unit of ``T``).
            image_sizes: ``(W, H)`` per camera.
            initial: per camera a camera to start from (one :class:`~ccs_kornia.geometry.camera.Camera`; its model
                must be the camera's) or ``None``; or one value holding every camera's.
            fixed: per camera: keep its intrinsics at ``initial`` exactly.
            names: camera names (default ``cam0, cam1, ...``).
            weights: per-corner inverse variances, shaped as ``valid``.
            frame_times: :math:`(F,)` the frames' times (seconds, or frame numbers; NaN where unknown): the board's
                motion around each frame is measured from its neighbours in time (``RigResult.frame_motion``).

        Raises:
            ValueError: bad shapes or options; cameras not connected to camera 0 through shared frames.
        """
        valid = _check(corners, valid, object_points, image_sizes, weights)
        batched = corners.dim() == 5
        if not batched:
            corners, valid = corners[None], valid[None]
            weights = None if weights is None else weights[None]
        C = corners.shape[1]
        models = _per_camera(self.models, C, "models")
        initial = [initial[c] for c in range(len(initial))] if isinstance(initial, Camera) else initial
        initial = _per_camera(initial, C, "initial")
        fixed = [bool(f) for f in _per_camera(fixed if fixed is not None else False, C, "fixed")]
        names = [f"cam{c}" for c in range(C)] if names is None else [str(n) for n in _per_camera(names, C, "names")]
        for c in range(C):
            if fixed[c] and initial[c] is None:
                raise ValueError(f"{names[c]} is fixed but has no initial camera to keep.")
            if initial[c] is not None and initial[c].model != models[c]:
                raise ValueError(f"{names[c]}: initial camera model {initial[c].model} differs from {models[c]}.")
        if frame_times is not None:
            check_tensor(frame_times, "frame_times", [corners.shape[-3]])
        with torch.inference_mode(), small_problem_threads(corners.shape[:-1].numel(), corners.device):
            out = self._solve(corners, valid, object_points, [tuple(map(int, s)) for s in image_sizes], models,
                              initial, fixed, names, weights, batched, frame_times)
        if not torch.is_inference_mode_enabled():  # ordinary tensors out (inference tensors refuse in-place edits)
            out = [_clone(r) for r in out]
        return out if batched else out[0]

    def _solve(self, corners, valid, obj, sizes, models, initial, fixed, names, weights, batched, frame_times=None):
        B, C, F, N = corners.shape[:4]
        dtype, device = self.dtype, corners.device
        corners = corners.to(dtype)
        obj = obj.to(device=device, dtype=dtype)
        valid = valid.to(device).bool() & corners.isfinite().all(-1)
        weights = valid.to(dtype) if weights is None else weights.to(device, dtype)
        syms = board_symmetries(obj) if self.symmetric_board else board_symmetries(obj)[:1]

        params, rvec, tvec, ok_pose, ok_cam = initial_rig_cameras(corners, valid, obj, sizes, models, initial,
                                                                   self.min_corners)
        order = torch.zeros(B, C, F, dtype=torch.long, device=device)
        R0 = torch.eye(3, dtype=dtype, device=device).repeat(B, C, 1, 1)
        T0 = torch.zeros(B, C, 3, dtype=dtype, device=device)
        failed = [""] * B
        for b in range(B):
            bad = [names[c] for c in range(C) if not bool(ok_cam[b, c])]
            if bad:
                failed[b] = (f"{', '.join(bad)}: the camera alone could not be calibrated (frames with at least "
                             f"{self.min_corners} corners: {[int(ok_pose[b, c].sum()) for c in range(C)]}); give its "
                             f"intrinsics as initial or add frames")
                continue
            try:
                R0[b], T0[b] = rig_extrinsics(rvec[b], tvec[b], ok_pose[b], valid[b], names, syms)
            except ValueError as e:
                raise ValueError(f"rig {b}: {e}" if batched else str(e)) from None
            order[b] = align_frame_orders(exp_so3(rvec[b]), tvec[b], ok_pose[b], valid[b].sum(-1), R0[b], T0[b], syms)
        if bool(order.any()):  # renumber the corners of observations numbered by another symmetry of the board
            corners, valid, weights = corners.clone(), valid.clone(), weights.clone()
            for k in range(1, len(syms)):
                m = order == k
                inv = torch.argsort(syms[k].perm)
                corners[m], valid[m], weights[m] = corners[m][:, inv], valid[m][:, inv], weights[m][:, inv]
                r, t = undo_symmetry(exp_so3(rvec[m]), tvec[m], syms[k])
                rvec[m], tvec[m] = log_so3(r), t
        base_w = torch.where(valid, weights, 0.0)
        alive = torch.tensor([not f for f in failed], device=device)
        used = ok_pose & alive[:, None, None]
        frame_R, frame_t = _frame_poses(rvec, tvec, used, valid, R0, T0)

        lm_models = list(models)
        intr, ext, G = rig_layout(lm_models)
        free = torch.ones(G, dtype=torch.bool)
        for c in range(C):
            if fixed[c]:
                free[intr[c]] = False

        priors, single_std, single_params = self._priors(lm_models, params, rvec, tvec, obj, corners, base_w, used,
                                                         fixed)
        frame_w = torch.ones(B, F, dtype=dtype, device=device)
        prior_scale = torch.ones(B, C, dtype=dtype, device=device)

        def fit(use, start: RigState, iters=self.max_iters):
            k = use.shape[0] // B  # the held-out folds stack k copies of the rigs
            w = (base_w * frame_w[:, None, :, None]).repeat(k, 1, 1, 1) * use[..., None].to(dtype)
            prior = None if priors is None else [
                None if q is None else (q[0].repeat(k, 1), (q[1] * prior_scale[:, c, None, None]).repeat(k, 1, 1))
                for c, q in enumerate(priors)]
            return rig_levenberg_marquardt(start, RigObservations(obj, corners.repeat(k, 1, 1, 1, 1), w), free,
                                           max_iters=iters, ftol=self.ftol, stall_tol=self.stall_tol, prior=prior)

        def consistency(res, use):
            """(B, F) frame disagreements, (B,) the median own-pose view RMS of each rig and (B, C) how much more
            than its own poses the rig's one pose per frame leaves of each camera's squared error, beyond what the
            noise alone leaves (frames weighted as in the fit; 0 for a consistent rig)."""
            w = base_w * use[..., None].to(dtype)
            own = own_view_errors(res.state, RigObservations(obj, corners, w))
            _, per_frame = frame_disagreement(res.sq_error, own, res.count, use)
            own_rms = (own / res.count.clamp_min(1)).sqrt().masked_fill(~use, float("nan")).flatten(1)
            fw = frame_w[:, None] * use.to(dtype)
            n = torch.where(use, res.count, 0).to(dtype)
            # the noise's share: a camera's 2n residuals less its share of the frame's 6 pose unknowns (n / N_f of
            # them under the rig, all 6 under its own pose)
            rig_dof = (2 * n - 6 * n / n.sum(1, keepdim=True).clamp_min(1)).clamp_min(0)
            own_dof = (2 * n - 6).clamp_min(0)
            expected = (fw * rig_dof).sum(-1) / (fw * own_dof).sum(-1).clamp_min(1e-300)
            ratio = (fw * res.sq_error).sum(-1) / (fw * own).sum(-1).clamp_min(1e-300)
            excess = (ratio / expected.clamp_min(1e-300) - 1.0).nan_to_num(0.0).clamp_min(0.0)
            return per_frame, own_rms.nanmedian(-1).values, excess

        warp0 = torch.zeros(B, 2, dtype=dtype, device=device) if self.board_warp else None
        res = fit(used, RigState(lm_models, params, R0, T0, frame_R, frame_t, warp0))
        scale = torch.full((B,), float("nan"), dtype=dtype, device=device)
        passes = self.frame_passes if (self.frame_kernel.reweights or priors is not None) else 0
        for _ in range(passes):  # frames one board pose does not explain count less (iteratively reweighted)
            d, own_rms, ratio = consistency(res, used)
            scale = self._scale(own_rms)
            frame_w = self.frame_kernel.weights(d, scale[:, None])
            # the priors in the units of the rig's own residuals, less the camera's own views the rig's data already
            # hold: a camera the one-pose-per-frame fit leaves with k times the squared error the noise explains is
            # held by k - 1 times its own views' information (none in a consistent rig)
            prior_scale = ratio
            res = fit(used, res.state)
        for _ in range(2):  # outlier observations (camera x frame), then fit again without them
            rms = (res.sq_error / res.count.clamp_min(1)).sqrt()
            keep = drop_outliers(rms, used, used, self.outlier_abs_threshold, self.outlier_rel_threshold, 2)
            if bool((keep == used).all()):
                break
            used = keep
            res = fit(used, res.state)
        d_final, own_rms, final_excess = consistency(res, used)
        if not bool(scale.isfinite().any()):
            scale = self._scale(own_rms)
        motion = torch.full((B, F), float("nan"), dtype=dtype, device=device)
        if frame_times is not None:
            motion = board_motion(res.state, obj, used, frame_times)
        fc = {"disagreement": d_final, "weight": frame_w, "motion": motion, "scale": scale}
        single = {"params": single_params, "std": single_std, "excess": final_excess,
                  "prior_scale": prior_scale if priors is not None else torch.zeros_like(prior_scale)}

        held = self._heldout(fit, res, used, corners, valid, models, B, C)
        return [self._result(b, res, used, corners, valid, models, names, sizes, failed[b], ext, intr, held[b],
                             order[b], fc, single, fixed, obj) for b in range(B)]

    def _scale(self, own_rms: torch.Tensor) -> torch.Tensor:
        """(B,) px: the frame kernel's scale (the given one, else from each rig's median own-pose view RMS)."""
        if self.frame_scale is not None:
            return torch.full_like(own_rms, self.frame_scale)
        return (FRAME_SCALE * own_rms).nan_to_num(FRAME_SCALE_MIN_PX).clamp_min(FRAME_SCALE_MIN_PX)

    def _priors(self, lm_models, params, rvec, tvec, obj, corners, weights, used, fixed):
        """Per camera ``(p0, information / intrinsics_prior)`` (``None`` where fixed or without a prior: all
        ``None`` gives ``None``), per camera the 1-sigma of its intrinsics from its own views alone (B, P) and
        ``p0`` (B, P) (the start where fixed).

        ``p0`` is the camera's calibration on its own views of the rig (its corners and weights), refined from its
        start (its own calibration, or the given ``initial``, which is then a start and not the prior's centre);
        the information is its own views' normal equations there, the board poses eliminated; directions its views
        do not determine carry no information, hence no pull."""
        priors, std, centres = [], [], []
        for c, model in enumerate(lm_models):
            w = weights[:, c] * used[:, c, :, None].to(weights.dtype)
            if fixed[c] or not bool((w > 0).any()):
                priors.append(None)
                std.append(torch.zeros_like(params[c]))
                centres.append(params[c])
                continue
            own = levenberg_marquardt(model, params[c], rvec[:, c], tvec[:, c], obj, corners[:, c], w,
                                      max_iters=self.max_iters, ftol=self.ftol)
            has = (w > 0).flatten(1).any(-1) & own.params.isfinite().all(-1) & own.cost.isfinite()
            info = own.basis @ own.information @ own.basis.transpose(-1, -2)
            p0 = torch.where(has[:, None], own.params, params[c])
            std.append(torch.where(has[:, None], own.param_std, 0.0))
            centres.append(p0)
            priors.append(None if self.intrinsics_prior is None else
                          (p0, torch.where(has[:, None, None], info / self.intrinsics_prior, 0.0)))
        return (priors if any(p is not None for p in priors) else None), std, centres

    def _heldout(self, fit, res, used, corners, valid, models, B, C):
        """Per rig (C, C) epipolar RMS on held-out frames: k folds over the used frames, all refitted at once."""
        nan = torch.full((C, C), float("nan"), dtype=corners.dtype, device=corners.device)
        frames = used.any(1)  # (B, F)
        k = self.folds
        enough = frames.sum(-1) >= self.min_heldout_frames  # (B,) rigs with frames to hold out
        if k < 2 or not bool(enough.any()):
            return [nan.clone() for _ in range(B)]
        folds = split_views(frames, k).unbind(1)  # (B, F) each
        use = torch.cat([used & ~f[:, None, :] for f in folds])  # (k B, C, F)

        out = fit(use, res.state.repeat(k), iters=max(self.max_iters // 2, 10)).state
        held = []
        for b in range(B):
            if not bool(enough[b]):
                held.append(nan.clone())
                continue
            sums = torch.zeros(C, C, dtype=corners.dtype, device=corners.device)
            counts = torch.zeros(C, C, dtype=torch.long, device=corners.device)
            for i in range(k):
                r = i * B + b
                cams = _cameras(models, [p[r] for p in out.params], [None] * C)
                trained = use[r].any(-1)  # cameras with frames in this fold's fit (the others were not refitted)
                s, n = epipolar_sums(cams, out.R[r], out.T[r], corners[b], valid[b],
                                     used[b] & folds[i][b][None] & trained[:, None])
                sums, counts = sums + s, counts + n
            h = (sums / counts.clamp_min(1)).sqrt().masked_fill(counts == 0, float("nan"))
            h.fill_diagonal_(0.0)
            held.append(h)
        return held

    def _result(self, b, res, used, corners, valid, models, names, sizes, failed, ext, intr, held, order, fc,
                single, fixed, obj) -> RigResult:
        C, F = used.shape[1:]
        rig = res.state
        dtype = rig.R.dtype
        nan = float("nan")
        cams = _cameras(models, [p[b] for p in rig.params], sizes)
        u = used[b]
        rms_m = (res.sq_error[b] / res.count[b].clamp_min(1)).sqrt().masked_fill(~u, nan)
        cnt = torch.where(u, res.count[b], 0).sum(-1)
        cam_rms = (torch.where(u, res.sq_error[b], 0.0).sum(-1) / cnt.clamp_min(1)).sqrt().masked_fill(cnt == 0, nan)
        total = float((torch.where(u, res.sq_error[b], 0.0).sum() / cnt.sum().clamp_min(1)).sqrt())
        cov = res.covariance[b]
        T = rig.T[b].clone()
        bstd = torch.zeros(C, dtype=dtype, device=T.device)
        rstd = torch.zeros(C, dtype=dtype, device=T.device)
        for c in range(1, C):
            e = ext[c]
            n = T[c] / T[c].norm().clamp_min(1e-300)
            bstd[c] = (n @ cov[e.start + 3 : e.stop, e.start + 3 : e.stop] @ n).clamp_min(0).sqrt()
            rstd[c] = torch.rad2deg(cov[e.start : e.start + 3, e.start : e.start + 3].trace().clamp_min(0).sqrt())
        istd = [cov[intr[c], intr[c]].diagonal().clamp_min(0).sqrt().clone() for c in range(C)]
        frames = u.any(0)
        rvec = torch.where(frames[:, None], log_so3(rig.frame_R[b]), nan)
        tvec = torch.where(frames[:, None], rig.frame_t[b], nan)
        s, n = epipolar_sums(cams, rig.R[b], T, corners[b], valid[b], u)
        epi = (s / n.clamp_min(1)).sqrt().masked_fill(n == 0, nan)
        epi.fill_diagonal_(0.0)
        success = not failed and bool(res.frame_used[b].any()) and bool(torch.isfinite(cam_rms).all())
        reason = failed or ("" if success else "the joint fit failed (no finite solution)")
        singles = _cameras(models, [p[b] for p in single["params"]], sizes)
        sstd = [single["std"][c][b].clone() for c in range(C)]
        moved = [torch.where(sstd[c] > 0, (rig.params[c][b] - single["params"][c][b]) / sstd[c].clamp_min(1e-300),
                             0.0) for c in range(C)]
        # moves of the cameras the rig explains worse than their noise (in a consistent rig a move is what the shared
        # frames know better, not a drag): those the verdict and the advice speak of
        excess = single["excess"][b]
        dragged = [m if float(excess[c]) >= DRAGGED_EXCESS else torch.zeros_like(m) for c, m in enumerate(moved)]
        fw = fc["weight"][b].masked_fill(~u.any(0), float("nan"))
        shared = shared_frames(u, fc["weight"][b])
        advice = session_advice(names, sizes, rig.rig(b), obj, corners[b], valid[b], u, fc["disagreement"][b], fw,
                                fc["motion"][b], shared, dragged, fixed) if success else []
        status = LMStatus(int(res.status[b]))
        if success:
            verdict, reasons = rig_verdict(names, sizes, cam_rms, epi, held, T.norm(dim=-1), bstd, rstd,
                                           self.thresholds, converged=status.converged,
                                           iterations=int(res.iterations[b]),
                                           moved_sigma=[float(m.abs().max()) if m.numel() else 0.0 for m in dragged])
        else:
            verdict, reasons = f"not reliable: {reason}", [reason]
        return RigResult(
            success=success, reason=reason, names=list(names), image_sizes=list(sizes), cameras=cams,
            R=rig.R[b].clone(), T=T, board_rvec=rvec, board_tvec=tvec, used=u.clone(), rms_matrix=rms_m,
            camera_rms=cam_rms, rms=total, baseline_std=bstd, rotation_std_deg=rstd, intrinsics_std=istd,
            epipolar_rms=epi, heldout_epipolar_rms=held, verdict=verdict, reasons=reasons,
            lm_status=status, iterations=int(res.iterations[b]), corner_order=order.clone(),
            single_cameras=singles, single_std=sstd, intrinsics_moved_sigma=moved,
            frame_disagreement=fc["disagreement"][b].clone(), frame_weight=fw, frame_motion=fc["motion"][b].clone(),
            frame_scale=float(fc["scale"][b]), shared_frames=shared, advice=advice,
            prior_weight=torch.tensor([0.0 if fixed[c] or self.intrinsics_prior is None else
                                       float(single["prior_scale"][b, c]) / self.intrinsics_prior for c in range(C)],
                                      dtype=dtype, device=T.device),
            board_warp=None if rig.board_warp is None else rig.board_warp[b].clone(),
            board_warp_std=None if res.warp_covariance is None else
            res.warp_covariance[b].diagonal().clamp_min(0).sqrt().clone(),
        )


def _clone(x):
    """A copy of a result made of ordinary tensors (of tensors made under inference mode)."""
    if isinstance(x, torch.Tensor):
        return x.clone()
    if isinstance(x, list):
        return [_clone(v) for v in x]
    if isinstance(x, Camera):
        return x.clone()
    if isinstance(x, RigResult):
        return type(x)(**{k: _clone(v) for k, v in x.__dict__.items()})
    return x


def _cameras(models: Sequence[CameraModel], params: Sequence[torch.Tensor], sizes) -> Camera:
    """One value of C cameras from each one's model, parameters :math:`(P_c,)` and image size."""
    return Camera.cat([Camera(m, p.clone()[None], s) for m, p, s in zip(models, params, sizes)])


def _frame_poses(rvec, tvec, used, valid, R, T):
    """Board -> camera 0 per frame (B, F): from the camera with the most corners in that frame, through its
    extrinsics (``x_0 = R_c^T (x_c - T_c)``)."""
    n = torch.where(used, (valid & used[..., None]).sum(-1), -1)  # (B, C, F)
    best = n.argmax(1)  # (B, F)
    B, C, F = used.shape
    idx = best[:, None, :, None]
    rv = rvec.gather(1, idx.expand(B, 1, F, 3))[:, 0]
    tv = tvec.gather(1, idx.expand(B, 1, F, 3))[:, 0]
    Rc = R.gather(1, best[..., None, None].expand(B, F, 3, 3))  # (B, F, 3, 3)
    Tc = T.gather(1, best[..., None].expand(B, F, 3))
    Rt = Rc.transpose(-1, -2)
    frame_R = Rt @ exp_so3(rv)
    frame_t = (Rt @ (tv - Tc)[..., None])[..., 0]
    return frame_R, frame_t


def calibrate_rig(
    corners: torch.Tensor,
    valid: torch.Tensor | None,
    object_points: torch.Tensor,
    image_sizes: Sequence[tuple[int, int]],
    models: CameraModel | Sequence[CameraModel] = OPENCV5,
    initial: Sequence[Camera | None] | Camera | None = None,
    fixed: Sequence[bool] | None = None,
    names: Sequence[str] | None = None,
    weights: torch.Tensor | None = None,
    frame_times: torch.Tensor | None = None,
    **kwargs,
) -> RigResult | list[RigResult]:
    """Functional form of :class:`RigSolver` (``kwargs`` go to its constructor)."""
    return RigSolver(models, **kwargs)(corners, valid, object_points, image_sizes, initial, fixed, names, weights,
                                       frame_times)

