r"""How well one board pose explains every camera of a frame: the frame's disagreement and its robust weight.

A frame of a rig is one instant: the joint fit gives it one board pose for all its cameras. A board that moved between
the cameras' exposures (software sync, per-camera exposure times, a rolling shutter) or a frame paired with the wrong
instant cannot be explained by one pose, and averaging it in drags the extrinsics, and the intrinsics, toward it.

* **Disagreement** of frame ``f``: per camera ``c`` its squared error under the rig (``sq_rig``, the frame's pose
  through the camera's extrinsics) less its squared error under its own best pose with the same intrinsics
  (``sq_own``, :func:`own_view_errors`), summed over the frame's cameras and divided by their corners:

  .. math:: d_f = \sqrt{\frac{\sum_c \max(0, e^{rig}_{cf} - e^{own}_{cf})}{\sum_c n_{cf}}}

  (px). A consistent frame's excess is the noise's share of the 6 pose unknowns the cameras give up to one pose
  (a fraction of the noise); a board that moved between exposures gives its motion in pixels. Frames seen by one
  camera have none (NaN).
* **Weight**: a robust kernel (:class:`FrameKernel`) of ``d_f / scale`` multiplies the frame's corner weights in the
  next fit (iteratively reweighted).
* **Motion** (:func:`board_motion`): where the frames are in time order, how far the board moved in the image
  between a frame and its neighbours, per frame period: a disagreement no larger than the board's own motion is a
  board that moved between the cameras' exposures; a larger one is not explained by the motion (a mis-paired frame
  or a wrong detection).
"""

from __future__ import annotations

import enum
import math

import torch

from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.geometry.board_warp import warped_board
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.rig.rig_state import RigObservations, RigState

__all__ = ["BOARD_MOVING", "NOT_MOTION", "FrameKernel", "board_motion", "disagreement_cause", "frame_disagreement",
           "own_view_errors"]

#: the cause of a disagreement no larger than the board's motion per frame period
BOARD_MOVING = "board moving"
#: the cause of a larger one
NOT_MOTION = "more than the board's motion (a mis-paired frame or a wrong detection)"


class FrameKernel(enum.Enum):
    """The robust kernel turning a frame's disagreement into its weight (``x = d / scale``).

    * ``CAUCHY``: ``1 / (1 + x^2)`` (a frame twice the scale off counts a fifth);
    * ``HUBER``: ``min(1, 1 / x)``;
    * ``DROP``: ``0`` beyond ``x = 3``, else 1;
    * ``NONE``: every frame counts fully (the joint fit averages all frames in).

    Example:
        >>> FrameKernel.CAUCHY.weights(torch.tensor([0.0, 1.0, 3.0, float("nan")]), 1.0).tolist()
        [1.0, 0.5, 0.10000000149011612, 1.0]
    """

    CAUCHY = "cauchy"
    HUBER = "huber"
    DROP = "drop"
    NONE = "none"

    def weights(self, disagreement: torch.Tensor, scale: float | torch.Tensor) -> torch.Tensor:
        """Weights in ``[0, 1]`` of disagreements ``(*)`` px at ``scale`` px (a scalar or broadcastable); NaN (frames
        of one camera) weigh 1."""
        scale = torch.as_tensor(scale, dtype=disagreement.dtype, device=disagreement.device)
        x = (disagreement / scale).nan_to_num(0.0)
        if self is FrameKernel.CAUCHY:
            w = 1.0 / (1.0 + x * x)
        elif self is FrameKernel.HUBER:
            w = torch.where(x > 1.0, 1.0 / x.clamp_min(1e-12), torch.ones_like(x))
        elif self is FrameKernel.DROP:
            w = (x <= 3.0).to(x.dtype)
        else:
            w = torch.ones_like(x)
        return w

    @property
    def reweights(self) -> bool:
        """The kernel changes weights (``NONE`` does not: no reweighting pass)."""
        return self is not FrameKernel.NONE


def own_view_errors(rig: RigState, observations: RigObservations, max_iters: int = 20) -> torch.Tensor:
    r"""Each camera's squared pixel error per frame under its own best board pose, its intrinsics held.

    Starts from the rig's pose of the board in the camera
    (:meth:`~ccs_kornia.modules.rig.rig_state.RigState.board_poses`) and refines the pose alone
    (:func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt` with no camera parameter free).

    Args:
        rig: the rigs (:class:`~ccs_kornia.modules.rig.rig_state.RigState`).
        observations: the board points, corners :math:`(B, C, F, N, 2)` and weights :math:`(B, C, F, N)` (0: unused).
        max_iters: pose iterations at most.

    Returns:
        :math:`(B, C, F)` unweighted sum of squared pixel errors of the used corners (0 where unused).
    """
    Rc, tc = rig.board_poses()
    corners, weights = observations.corners, observations.weights
    board = warped_board(observations.object_points, rig.board_warp)  # (B, N, 3) where the board is bent
    B, C, F = weights.shape[:3]
    out = corners.new_zeros(B, C, F)
    for c, model in enumerate(rig.models):
        w = weights[:, c]
        if not bool((w > 0).any()):
            continue
        res = levenberg_marquardt(model, rig.params[c], log_so3(Rc[:, c]), tc[:, c], board,
                                  corners[:, c], w, free=[False] * model.num_params, max_iters=max_iters)
        n = (w > 0).sum(-1)
        out[:, c] = (res.view_rms.nan_to_num(0.0) ** 2 * n).to(out.dtype)
    return out


def frame_disagreement(sq_rig: torch.Tensor, sq_own: torch.Tensor, count: torch.Tensor,
                       used: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Per camera and per frame, how much worse one board pose for the frame explains the corners than each
    camera's own pose (see the module doc).

    Args:
        sq_rig: :math:`(B, C, F)` squared pixel errors under the rig; sq_own: the same under each camera's own pose.
        count: :math:`(B, C, F)` corners; used: :math:`(B, C, F)` bool observations in the fit.

    Returns:
        ``(per_camera, per_frame)``: :math:`(B, C, F)` px (NaN where unused) and :math:`(B, F)` px (NaN for frames
        with fewer than two cameras).

    Example:
        >>> sq_rig = torch.tensor([[[4.0, 1.0], [16.0, 0.0]]], dtype=torch.float64)  # 2 cameras x 2 frames
        >>> sq_own = torch.tensor([[[0.0, 1.0], [0.0, 0.0]]], dtype=torch.float64)
        >>> used = torch.tensor([[[True, True], [True, False]]])
        >>> cam, frame = frame_disagreement(sq_rig, sq_own, torch.full((1, 2, 2), 4), used)
        >>> cam.tolist(), frame.round(decimals=4).tolist()  # 4 corners each
        ([[[1.0, 0.0], [2.0, nan]]], [[1.5811, nan]])
    """
    excess = torch.where(used, (sq_rig - sq_own).clamp_min(0.0), 0.0)
    n = torch.where(used, count, 0).to(sq_rig.dtype)
    per_cam = (excess / n.clamp_min(1)).sqrt().masked_fill(~used, float("nan"))
    shared = used.sum(1) >= 2
    per_frame = (excess.sum(1) / n.sum(1).clamp_min(1)).sqrt().masked_fill(~shared, float("nan"))
    return per_cam, per_frame


def board_motion(rig: RigState, object_points: torch.Tensor, used: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
    r"""How far the board moves in the image per frame period around each frame (px), from its fitted poses in the
    neighbouring frames.

    Per frame, in each camera that sees it and a neighbour (the previous or next used frame in time), the RMS
    displacement of the board's corners between the two poses, divided by the time between them and multiplied by
    the median time between consecutive used frames; the largest over the cameras and neighbours.

    Args:
        rig: the rigs (:class:`~ccs_kornia.modules.rig.rig_state.RigState`); object_points: :math:`(N, 3)`.
        used: :math:`(B, C, F)` bool observations.
        times: :math:`(F,)` the frames' times (any unit; increasing order not required), NaN where unknown.

    Returns:
        :math:`(B, F)` px per frame period (NaN without a neighbour).
    """
    B, F = used.shape[0], used.shape[2]
    frame_t = rig.frame_t
    out = torch.full((B, F), float("nan"), dtype=frame_t.dtype, device=frame_t.device)
    times = times.to(device=frame_t.device, dtype=frame_t.dtype)
    if F < 2:
        return out
    Rc, tc = rig.board_poses()
    obj = object_points.to(frame_t)
    for b in range(B):
        frames = used[b].any(0) & times.isfinite()
        idx = torch.nonzero(frames).flatten()
        if idx.numel() < 2:
            continue
        order = idx[torch.argsort(times[idx])]
        gaps = (times[order[1:]] - times[order[:-1]]).abs()
        period = float(gaps[gaps > 0].median()) if bool((gaps > 0).any()) else float("nan")
        for c, model in enumerate(rig.models):
            X = (Rc[b, c] @ obj.T).transpose(-1, -2) + tc[b, c][:, None]  # (F, N, 3)
            uv = model.columns(X[None], rig.params[c][b : b + 1], jacobians=False)[0][0]
            for a, z in zip(order[:-1].tolist(), order[1:].tolist()):
                dt = abs(float(times[z] - times[a]))
                if not (bool(used[b, c, a]) and bool(used[b, c, z])) or dt <= 0:
                    continue
                d = float(((uv[a] - uv[z]) ** 2).sum(-1).mean().sqrt()) * period / dt
                for f in (a, z):
                    if not (out[b, f] >= d):
                        out[b, f] = d
    return out


def disagreement_cause(disagreement: float, motion: float) -> str:
    """Why a frame's cameras disagree: :data:`BOARD_MOVING` where the board moved in the image at least as far per
    frame period (cameras paired within half a period disagree by at most half of it), :data:`NOT_MOTION` where it
    moved less, ``""`` where either figure is unknown.

    Example:
        >>> disagreement_cause(6.3, 25.0), disagreement_cause(6.3, 1.0)[:9], disagreement_cause(6.3, float("nan"))
        ('board moving', 'more than', '')
    """
    if math.isnan(disagreement) or math.isnan(motion):
        return ""
    return BOARD_MOVING if motion >= disagreement else NOT_MOTION
