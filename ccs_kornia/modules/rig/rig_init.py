"""Initialisation of a rig that does not need a guess: cameras alone, then relative poses over a spanning tree.

1. Each camera alone: its own calibration (:class:`~ccs_kornia.modules.calibration.solver.CalibrationSolver` with
   its model, on every frame it sees) or the given initial camera; a camera whose own calibration fails (too few
   frames) is calibrated again with the principal point at the image centre and ``fx = fy`` from one frame up.
2. Its board pose in every frame with enough corners: from the homography of the undistorted corners, refined with
   the intrinsics held (the single-camera solver's pose where it used the frame).
3. Every camera's pose relative to another one from the frames both see: rotation by the chordal L1 mean of the
   per-frame relative rotations (Weiszfeld from the L2 mean), translation by the per-axis median; chained from
   camera 0 over the maximum spanning tree of the co-visibility graph (edge weight: the corners the two cameras see
   in shared frames). A camera not connected to camera 0 is an error naming it and the frames it does share.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.board_poses import camera_poses
from ccs_kornia.modules.calibration.board_symmetry import (
    BoardSymmetry,
    symmetry_candidates,
    undo_symmetry,
)
from ccs_kornia.modules.calibration.solver import CalibrationSolver

__all__ = ["calibrate_cameras", "rotation_mean", "relative_pose", "spanning_tree", "rig_extrinsics",
           "initial_rig_cameras"]


def calibrate_cameras(
    corners: torch.Tensor,
    valid: torch.Tensor,
    obj: torch.Tensor,
    image_size: tuple[int, int],
    model: CameraModel,
    min_corners: int = 6,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One camera of B rigs calibrated alone: corners :math:`(B, F, N, 2)` -> params :math:`(B, P)`, ok :math:`(B,)`,
    rvec/tvec :math:`(B, F, 3)` and the frames the solver used :math:`(B, F)`."""
    kw = {"checks": False, "min_corners": min_corners}
    res = CalibrationSolver(model=model, **kw)(corners, valid, obj, image_size)
    params = res.camera.params
    ok = res.success & params.isfinite().all(-1)
    if not bool(ok.all()):  # few frames: the principal point at the centre and fx = fy from one frame up
        fb = CalibrationSolver(model=model, min_views=1, fix_principal_point=True,
                               fix_aspect_ratio=not model.is_fisheye, use_ransac=False,
                               **kw)(corners, valid, obj, image_size)
        p_fb = fb.camera.params
        ok_fb = fb.success & p_fb.isfinite().all(-1) & ~ok
        params = torch.where(ok_fb[:, None], p_fb, params)
        for name in ("rvec", "tvec", "used"):
            getattr(res, name)[ok_fb] = getattr(fb, name)[ok_fb]
        ok = ok | ok_fb
    return params, ok, res.rvec, res.tvec, res.used & ok[:, None]


def rotation_mean(R: torch.Tensor, iters: int = 20) -> torch.Tensor:
    """Chordal L1 mean :math:`(3, 3)` of rotations :math:`(M, 3, 3)` (Weiszfeld from the chordal L2 mean).

    Example:
        >>> R = exp_so3(torch.tensor([[0.1, 0, 0], [0.12, 0, 0], [0.11, 0, 0], [2.0, 0, 0]], dtype=torch.float64))
        >>> round(float(torch.asin(rotation_mean(R)[2, 1])), 3)  # the outlier (2 rad) barely moves it from 0.11
        0.11
    """

    def project(M):
        U, _, Vh = torch.linalg.svd(M)
        d = torch.linalg.det(U @ Vh)
        return U @ torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d])) @ Vh

    mean = project(R.sum(0))
    for _ in range(iters):
        dist = (R - mean).flatten(1).norm(dim=-1).clamp_min(1e-9)
        mean = project((R / dist[:, None, None]).sum(0))
    return mean


def relative_pose(Ra, ta, Rb, tb) -> tuple[torch.Tensor, torch.Tensor]:
    """Robust relative pose ``x_b = R x_a + T`` :math:`((3, 3), (3,))` from the board poses of two cameras in the
    frames both see (:math:`(M, 3, 3)` and :math:`(M, 3)` each)."""
    R = rotation_mean(Rb @ Ra.transpose(-1, -2))
    T = (tb - ta @ R.T).median(0).values
    return R, T


def spanning_tree(weights: torch.Tensor) -> tuple[list[int], list[int]]:
    """Maximum spanning tree from node 0 of a symmetric :math:`(C, C)` weight matrix (0: no edge), by Prim.

    Returns:
        ``(order, parent)``: nodes in the order they join (0 first; unreachable nodes are left out) and each node's
        parent (-1 for 0 and for unreachable nodes).

    Example:
        >>> spanning_tree(torch.tensor([[0, 5, 1, 0], [5, 0, 9, 0], [1, 9, 0, 0], [0, 0, 0, 0]]))
        ([0, 1, 2], [-1, 0, 1, -1])
    """
    C = weights.shape[0]
    order, parent = [0], [-1] * C
    while True:
        best, edge = 0, None
        for a in order:
            for b in range(C):
                if b not in order and float(weights[a, b]) > best:
                    best, edge = float(weights[a, b]), (a, b)
        if edge is None:
            return order, parent
        order.append(edge[1])
        parent[edge[1]] = edge[0]


def _frames_text(frames: list[int]) -> str:
    return "[" + ", ".join(map(str, frames[:12])) + (", ..." if len(frames) > 12 else "") + "]"


def rig_extrinsics(
    rvec: torch.Tensor, tvec: torch.Tensor, ok: torch.Tensor, valid: torch.Tensor, names: Sequence[str],
    symmetries: Sequence[BoardSymmetry] = (),
) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera poses relative to camera 0 of one rig from per-camera board poses.

    Args:
        rvec, tvec: :math:`(C, F, 3)` board -> camera poses; ok :math:`(C, F)` where they exist.
        valid: :math:`(C, F, N)` the corners (edge weights: corners seen in shared frames).
        names: camera names (for the error).
        symmetries: the board's symmetries (:func:`~ccs_kornia.modules.calibration.board_symmetry.board_symmetries`):
            a camera's frames numbered differently from its tree parent's are turned back before averaging.

    Returns:
        ``R`` :math:`(C, 3, 3)`, ``T`` :math:`(C, 3)` with ``x_c = R_c x_0 + T_c``.

    Raises:
        ValueError: cameras not connected to camera 0 through shared frames (names them and the frames they share).
    """
    C = rvec.shape[0]
    n = (valid & ok[..., None]).sum(-1)  # (C, F)
    shared = ok[:, None] & ok[None]  # (C, C, F)
    weight = torch.where(shared, torch.minimum(n[:, None], n[None]), 0).sum(-1)
    weight.fill_diagonal_(0)
    order, parent = spanning_tree(weight)
    if len(order) < C:
        lost = [c for c in range(C) if c not in order]
        pairs = []
        for a in range(C):
            for b in range(a + 1, C):
                fr = torch.nonzero(shared[a, b]).flatten().tolist()
                if fr and (a in lost or b in lost):
                    pairs.append(f"{names[a]}-{names[b]} {_frames_text(fr)}")
        alone = [names[c] for c in lost if not any(bool(shared[c, o].any()) for o in range(C) if o != c)]
        text = (f"cameras {', '.join(names[c] for c in lost)} are not connected to {names[0]} through shared frames "
                f"(a frame where two cameras each see at least the minimum number of corners of the board)")
        text += "; frames they share: " + ("; ".join(pairs) if pairs else "none")
        if alone:
            text += f"; {', '.join(alone)} share no frame with any camera"
        raise ValueError(text + ". Add frames where the board is seen by a connected camera and by these.")
    Rb = exp_so3(rvec)
    R = torch.eye(3, dtype=rvec.dtype, device=rvec.device).repeat(C, 1, 1)
    T = torch.zeros(C, 3, dtype=rvec.dtype, device=rvec.device)
    for c in order[1:]:
        p = parent[c]
        m = shared[p, c]
        Rc, tc = Rb[c, m], tvec[c, m]
        if len(symmetries) > 1:
            s = symmetry_candidates(Rb[p, m], tvec[p, m], Rc, tc, list(symmetries))
            for k in range(1, len(symmetries)):
                Ru, tu = undo_symmetry(Rc, tc, symmetries[k])
                Rc, tc = torch.where((s == k)[:, None, None], Ru, Rc), torch.where((s == k)[:, None], tu, tc)
        Rpc, Tpc = relative_pose(Rb[p, m], tvec[p, m], Rc, tc)
        R[c] = Rpc @ R[p]
        T[c] = Rpc @ T[p] + Tpc
    return R, T


def initial_rig_cameras(
    corners: torch.Tensor,
    valid: torch.Tensor,
    obj: torch.Tensor,
    image_sizes: Sequence[tuple[int, int]],
    models: Sequence[CameraModel],
    initial: Sequence[Camera | None],
    min_corners: int = 6,
) -> tuple[list[torch.Tensor], torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, list[str]]:
    """Steps 1-2 for B rigs: per camera params :math:`(B, P_c)`, rvec/tvec :math:`(B, C, F, 3)`, pose ok
    :math:`(B, C, F)`, camera ok :math:`(B, C)` and per camera a line on why it failed ("" if not)."""
    B, C, F, N = corners.shape[:4]
    params, rv, tv, ok_pose, ok_cam = [], [], [], [], []
    for c in range(C):
        known = r0 = t0 = None
        if initial[c] is not None:
            p = initial[c].params.to(corners.device, corners.dtype).expand(B, -1).clone()
            ok = torch.ones(B, dtype=torch.bool, device=corners.device)
        else:
            p, ok, r0, t0, known = calibrate_cameras(corners[:, c], valid[:, c], obj, image_sizes[c], models[c],
                                                     min_corners)
            p = torch.where(ok[:, None], p, _fallback(models[c], image_sizes[c], p))
        r, t, okp, _ = camera_poses(p, models[c], corners[:, c], valid[:, c], obj, min_corners, r0, t0, known)
        params.append(p)
        rv.append(r)
        tv.append(t)
        ok_pose.append(okp & ok[:, None])
        ok_cam.append(ok)
    return params, torch.stack(rv, 1), torch.stack(tv, 1), torch.stack(ok_pose, 1), torch.stack(ok_cam, 1)


def _fallback(model: CameraModel, image_size: tuple[int, int], like: torch.Tensor) -> torch.Tensor:
    """A finite stand-in camera (``f = max(W, H)`` at the centre) for a camera whose own calibration failed."""
    W, H = image_size
    p = torch.zeros_like(like)
    p[:, 0] = p[:, 1] = float(max(W, H))
    p[:, 2], p[:, 3] = (W - 1) / 2.0, (H - 1) / 2.0
    return p
