"""Symmetric boards in a rig: the corner orders a detector may hand over, and agreeing on one per frame.

A chessboard grid maps onto itself by a 180-degree turn about its centre (and by 90-degree turns when square). A
detector that cannot tell those orientations apart (e.g. a board with an odd number of squares both ways, ordered
from the image's top-left corner by :func:`~ccs_kornia.modules.detection.checks.board_checks.canonical_corner_order`) may
number the corners of one board differently in two cameras of a rig: for a single camera that only changes the board
pose, for a rig it breaks the one board pose per frame that all cameras share.

A symmetry ``s`` is a turn ``S`` about the board normal with offset ``c`` and the permutation ``perm`` such that
``X[perm[n]] = S X[n] + c``. A camera that numbered the corners by ``s`` (its corner ``n`` is the board's corner
``perm[n]``) estimates the pose ``(R S, R c + t)`` instead of ``(R, t)``.

Example:
    >>> from ccs_kornia.geometry.board_points import board_object_points
    >>> syms = board_symmetries(board_object_points(3, 2, 1.0, dtype=torch.float64))
    >>> len(syms), syms[1].perm.tolist()  # identity, then the 180-degree turn (reversed order)
    (2, [5, 4, 3, 2, 1, 0])
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.so3 import log_so3

__all__ = ["BoardSymmetry", "board_symmetries", "undo_symmetry", "symmetry_candidates", "rotation_angle",
           "align_frame_orders"]


@dataclass
class BoardSymmetry:
    """``X[perm[n]] = S X[n] + c`` (identity first in :func:`board_symmetries`)."""

    perm: torch.Tensor  #: (N,) int64
    S: torch.Tensor  #: (3, 3)
    c: torch.Tensor  #: (3,)


def board_symmetries(obj: torch.Tensor, tol: float = 1e-6) -> list[BoardSymmetry]:
    """The in-plane turns (180, then 90 and 270 degrees) that map planar board points :math:`(N, 3)` onto
    themselves, after the identity. A non-planar point set has the identity only."""
    N = obj.shape[0]
    eye = BoardSymmetry(torch.arange(N, device=obj.device), torch.eye(3, dtype=obj.dtype, device=obj.device),
                        torch.zeros(3, dtype=obj.dtype, device=obj.device))
    out = [eye]
    scale = float((obj - obj.mean(0)).abs().amax()) if N else 0.0
    if N < 2 or scale == 0 or float(obj[:, 2].abs().amax()) > tol * scale:
        return out
    centre = obj.mean(0)
    for k in (2, 1, 3):
        a = k * math.pi / 2
        S = torch.tensor([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]],
                         dtype=obj.dtype, device=obj.device).round(decimals=12)
        moved = (obj - centre) @ S.T + centre
        d = torch.cdist(moved, obj)
        dist, perm = d.min(-1)
        if float(dist.amax()) <= tol * scale and perm.unique().numel() == N:
            out.append(BoardSymmetry(perm, S, centre - S @ centre))
    return out


def undo_symmetry(R: torch.Tensor, t: torch.Tensor, sym: BoardSymmetry) -> tuple[torch.Tensor, torch.Tensor]:
    """The board pose :math:`(*, 3, 3)`, :math:`(*, 3)` of a camera that numbered the corners by ``sym``, in the
    board's own numbering: ``R' S^T`` and ``t' - R c``."""
    Rt = R @ sym.S.T
    return Rt, t - Rt @ sym.c


def rotation_angle(Ra: torch.Tensor, Rb: torch.Tensor) -> torch.Tensor:
    """Angle (radians) between rotations, broadcast over leading dims."""
    return log_so3(Ra @ Rb.transpose(-1, -2)).norm(dim=-1)


def symmetry_candidates(
    Ra: torch.Tensor, ta: torch.Tensor, Rb: torch.Tensor, tb: torch.Tensor, syms: list[BoardSymmetry],
    tol_deg: float = 3.0,
) -> torch.Tensor:
    """Per frame, the symmetry of camera b's numbering relative to camera a's :math:`(M,)` int64.

    Every frame gives one relative rotation per symmetry; the true one agrees across frames, the others scatter
    (they depend on the board's pose). The seed is the candidate that most frames agree with (within ``tol_deg``;
    ties: the one keeping most frames' own numbering), then each frame takes its candidate nearest the seed.

    Args:
        Ra, ta: :math:`(M, 3, 3)`, :math:`(M, 3)` board poses of camera a; Rb, tb: camera b's, same frames.
        syms: :func:`board_symmetries`.
    """
    M, K = Ra.shape[0], len(syms)
    if K == 1 or M == 0:
        return torch.zeros(M, dtype=torch.long, device=Ra.device)
    rel = torch.stack([undo_symmetry(Rb, tb, s)[0] @ Ra.transpose(-1, -2) for s in syms], 1)  # (M, K, 3, 3)
    flat = rel.reshape(M * K, 3, 3)
    ang = rotation_angle(flat[:, None], flat[None])  # (MK, MK)
    close = (ang <= math.radians(tol_deg)).reshape(M * K, M, K).any(-1)  # frames agreeing with each candidate
    # among the candidates most frames agree with, the one whose agreeing frames keep their own numbering most
    ident = (ang <= math.radians(tol_deg)).reshape(M * K, M, K)[..., 0].sum(-1)
    score = close.sum(-1) * (M + 1) + ident
    seed = flat[int(score.argmax())]
    return rotation_angle(rel, seed).argmin(-1)


def align_frame_orders(
    rvec_R: torch.Tensor, tvec: torch.Tensor, ok: torch.Tensor, counts: torch.Tensor, R: torch.Tensor, T: torch.Tensor,
    syms: list[BoardSymmetry],
) -> torch.Tensor:
    """One numbering per frame: per camera and frame, the symmetry :math:`(C, F)` int64 that brings its board pose
    (mapped to camera 0 through the extrinsics) nearest the pose of the frame's reference camera (the one with the
    most corners, kept as detected).

    Args:
        rvec_R: :math:`(C, F, 3, 3)` board rotations per camera and frame; tvec :math:`(C, F, 3)`.
        ok: :math:`(C, F)` where they exist; counts :math:`(C, F)` corners per observation.
        R, T: :math:`(C, 3, 3)`, :math:`(C, 3)` extrinsics (``x_c = R_c x_0 + T_c``).
        syms: :func:`board_symmetries`.
    """
    C, F = ok.shape
    order = torch.zeros(C, F, dtype=torch.long, device=ok.device)
    if len(syms) == 1:
        return order
    ref = torch.where(ok, counts, -1).argmax(0)  # (F,)
    Rt = R.transpose(-1, -2)[:, None]  # (C, 1, 3, 3)
    in0 = torch.stack([Rt @ undo_symmetry(rvec_R, tvec, s)[0] for s in syms], 2)  # (C, F, K, 3, 3) in camera 0
    ref_R = in0[ref, torch.arange(F, device=ok.device), 0]  # (F, 3, 3)
    best = rotation_angle(in0, ref_R[None, :, None]).argmin(-1)  # (C, F)
    return torch.where(ok, best, 0)
