r"""Leave-one-pose-out prediction: how well a hand-eye calibration predicts a view it was not fitted on.

For every used view ``v`` of a problem, the fit is repeated without it (every held-out problem of the batch solved
together, started from the full solution, the held-out view's robot-pose correction reset) and the board's corners
of view ``v`` are *predicted from the robot's reported pose alone*: ``x_c = X^{-1} A_v Z p`` projected by the camera.
The prediction error is given in pixels (RMS over the corners) and as a distance in the robot's unit: the RMS
distance of the predicted board corners to the lines of sight through the observed ones (the millimetres a
grasp at the board would miss by, when the poses are in millimetres). This is the figure a user can trust: it is
what the calibration does on a pose it has not seen, with the robot's and the detector's errors in it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.hand_eye.fit import FitResult, fit_problem
from ccs_kornia.modules.hand_eye.problem import HandEyeProblem, HandEyeState

__all__ = ["MAX_HELDOUT_CORNERS", "HeldOut", "jackknife_covariance", "leave_one_pose_out", "ray_distances"]

#: held-out problems are solved in chunks of at most this many corners (problems x views x corners)
MAX_HELDOUT_CORNERS = 1 << 20


@dataclass
class HeldOut:
    """Leave-one-pose-out figures of ``B`` problems of ``V`` views (NaN where a view was not held out)."""

    rms_px: torch.Tensor  #: (B, V) RMS prediction error of the held-out view's corners, px
    rms_distance: torch.Tensor  #: (B, V) RMS distance of its predicted corners to their lines of sight (pose unit)
    predicted: torch.Tensor  #: (B, V, N, 2) the corners predicted from the robot's pose alone
    X: torch.Tensor  #: (B, V, 4, 4) the camera's pose fitted without the view (NaN where not held out)
    Z: torch.Tensor  #: (B, V, 4, 4) the board's pose fitted without the view
    params: torch.Tensor  #: (B, V, P) the camera's parameters fitted without the view


def ray_distances(points: torch.Tensor, rays: torch.Tensor) -> torch.Tensor:
    """Distances :math:`(*)` of camera-frame points :math:`(*, 3)` to the lines of sight through normalized image
    points :math:`(*, 2)` (``(x, y, 1)`` directions).

    Example:
        >>> ray_distances(torch.tensor([[0.1, 0.0, 1.0]]), torch.tensor([[0.0, 0.0]])).tolist()
        [0.10000000149011612]
    """
    d = torch.cat([rays, torch.ones_like(rays[..., :1])], -1)
    d = d / d.norm(dim=-1, keepdim=True)
    along = (points * d).sum(-1, keepdim=True)
    return (points - along * d).norm(dim=-1)


def _pose(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def leave_one_pose_out(problem: HandEyeProblem, solution: HandEyeState, used: torch.Tensor,
                       min_views: int = 3, max_iters: int = 100,
                       refit: Callable[[HandEyeProblem, HandEyeState], FitResult] | None = None) -> HeldOut:
    """Hold out each used view of each problem in turn (module doc).

    Args:
        problem: the fitted problems (``B`` of them).
        solution: their optimum (the start of every held-out fit).
        used: :math:`(B, V)` the views the fit used; a view is held out where at least ``min_views`` others remain.
        min_views: views a held-out fit needs.
        max_iters: iterations of each held-out fit.
        refit: how a held-out problem is fitted (default :func:`~ccs_kornia.modules.hand_eye.fit.fit_problem`): the
            same procedure as the full fit (e.g. with its noise estimate), so that nothing of the held-out view
            enters its prediction.

    Returns:
        :class:`HeldOut`.
    """
    B, V, N = problem.shape
    dtype, device = problem.w.dtype, problem.w.device
    nan = float("nan")
    rms_px = torch.full((B, V), nan, dtype=dtype, device=device)
    rms_d = torch.full((B, V), nan, dtype=dtype, device=device)
    predicted = torch.full((B, V, N, 2), nan, dtype=dtype, device=device)
    Xs = torch.full((B, V, 4, 4), nan, dtype=dtype, device=device)
    Zs = Xs.clone()
    Ps = torch.full((B, V, solution.params.shape[-1]), nan, dtype=dtype, device=device)
    enough = used.sum(1) > min_views
    pb, pv = torch.nonzero(used & enough[:, None], as_tuple=True)
    chunk = max(1, MAX_HELDOUT_CORNERS // max(V * N, 1))
    eye = torch.eye(3, dtype=dtype, device=device)
    for a in range(0, int(pb.numel()), chunk):
        b, v = pb[a:a + chunk], pv[a:a + chunk]
        K = int(b.numel())
        w = problem.w[b].clone()
        w[torch.arange(K, device=device), v] = 0.0
        sub = problem.subset(b, w)
        start = HandEyeState(*(x[b] for x in solution))
        RE, tE = start.RE.clone(), start.tE.clone()
        RE[torch.arange(K, device=device), v] = eye
        tE[torch.arange(K, device=device), v] = 0.0
        start = start._replace(RE=RE, tE=tE)
        fit = fit_problem(sub, start, max_iters=max_iters) if refit is None else refit(sub, start)
        s = fit.state
        # the held-out view predicted from its reported robot pose: no correction
        RE0 = s.RE.clone()
        tE0 = s.tE.clone()
        RE0[torch.arange(K, device=device), v] = eye
        tE0[torch.arange(K, device=device), v] = 0.0
        s = s._replace(RE=RE0, tE=tE0)
        k = torch.arange(K, device=device)
        xc = sub.camera_points(s)[k, v]  # (K, N, 3)
        uv = sub.residuals(s)[k, v] + sub.obs[k, v]
        on = problem.w[b, v] > 0
        err = ((uv - problem.obs[b, v]) ** 2).sum(-1)
        rms_px[b, v] = (torch.where(on, err, 0.0).sum(-1) / on.sum(-1).clamp_min(1)).sqrt()
        rays = Camera(problem.model, s.params).undistort(problem.obs[b, v])
        dist = ray_distances(xc, rays)
        rms_d[b, v] = (torch.where(on, dist * dist, 0.0).sum(-1) / on.sum(-1).clamp_min(1)).sqrt()
        predicted[b, v] = uv
        Xs[b, v] = _pose(s.RX, s.tX)
        Zs[b, v] = _pose(s.RZ, s.tZ)
        Ps[b, v] = s.params
    return HeldOut(rms_px, rms_d, predicted, Xs, Zs, Ps)


def jackknife_covariance(T: torch.Tensor, T_out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The jackknife covariance :math:`(B, 6, 6)` of a pose from its leave-one-out refits: with ``n`` refits ``i``
    (the finite ones), ``(n - 1) / n \sum_i (d_i - \bar d)(d_i - \bar d)^T`` where ``d_i`` is the refit's offset
    from the full fit ``T`` as (left rotation vector, translation); and the number of refits :math:`(B,)`.

    Each view's errors (a robot pose a little off moves all of its corners together) are in its refit, so this
    covariance holds what the corners' independent noise cannot show.

    Args:
        T: :math:`(B, 4, 4)` the full fit; T_out: :math:`(B, V, 4, 4)` the refits (NaN where none).

    Example:
        >>> T = torch.eye(4, dtype=torch.float64)[None]
        >>> T_out = T[:, None].repeat(1, 3, 1, 1); T_out[0, :, 0, 3] = torch.tensor([-1.0, 0.0, 1.0])
        >>> cov, n = jackknife_covariance(T, T_out)
        >>> round(float(cov[0, 3, 3]), 4), int(n[0])
        (1.3333, 3)
    """
    ok = T_out.flatten(-2).isfinite().all(-1)
    safe = torch.where(ok[..., None, None], T_out, T[:, None])
    w = log_so3(safe[..., :3, :3] @ T[:, None, :3, :3].transpose(-1, -2))
    d = torch.cat([w, safe[..., :3, 3] - T[:, None, :3, 3]], -1) * ok[..., None]
    n = ok.sum(-1)
    nf = n.clamp_min(1).to(T.dtype)
    mean = d.sum(1) / nf[:, None]
    c = (d - mean[:, None]) * ok[..., None]
    cov = c.transpose(-1, -2) @ c * ((nf - 1) / nf)[:, None, None]
    return cov, n
