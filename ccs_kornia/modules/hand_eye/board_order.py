r"""One corner numbering for every view of a symmetric board, agreed through the robot.

A chessboard maps onto itself by a 180-degree turn (and 90-degree ones when square); a detector that cannot tell
them apart may number one board's corners differently in two views (:mod:`~ccs_kornia.modules.calibration.board_symmetry`).
A single camera does not care, a hand-eye fit does: the board's pose in the robot must be one for all views. The robot
tells the orders apart: the rotation between two views is the same angle seen from the robot
(``A_j A_i^{-1}``) and from the camera (``M_j M_i^{-1}``), for the right numbering only. :func:`align_board_orders`
gives each view the symmetry whose rotations to the other views agree best with the robot's (the median over the
other views, in a few rounds, each against the last round's numbering of the others); the views' majority fixes the
board's numbering.
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.calibration.board_symmetry import BoardSymmetry, undo_symmetry
from ccs_kornia.modules.hand_eye.setup import invert_transforms

__all__ = ["align_board_orders", "renumber_corners"]


def _angle(T: torch.Tensor) -> torch.Tensor:
    return log_so3(T[..., :3, :3]).norm(dim=-1)


def align_board_orders(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor, syms: list[BoardSymmetry],
                       rounds: int = 3) -> torch.Tensor:
    """The symmetry :math:`(B, V)` int64 of each view's numbering (index into ``syms``; 0: as detected).

    Args:
        A: :math:`(B, V, 4, 4)` the robot's chain per view.
        M: :math:`(B, V, 4, 4)` the board's pose in the camera per view, as detected.
        valid: :math:`(B, V)` the views with both.
        syms: :func:`~ccs_kornia.modules.calibration.board_symmetry.board_symmetries` of the board.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.modules.calibration.board_symmetry import board_symmetries
        >>> syms = board_symmetries(board_object_points(3, 2, 1.0, dtype=torch.float64))
        >>> T = torch.eye(4, dtype=torch.float64).repeat(1, 3, 1, 1)
        >>> align_board_orders(T, T, torch.ones(1, 3, dtype=torch.bool), syms).tolist()
        [[0, 0, 0]]
    """
    B, V = valid.shape
    K = len(syms)
    if K == 1 or V < 2:
        return torch.zeros(B, V, dtype=torch.long, device=valid.device)
    Mk = []
    for s in syms:
        R, t = undo_symmetry(M[..., :3, :3], M[..., :3, 3], s)
        T = M.clone()
        T[..., :3, :3], T[..., :3, 3] = R, t
        Mk.append(T)
    Mk = torch.stack(Mk, 2)  # (B, V, K, 4, 4)
    theta_a = _angle(A[:, None] @ invert_transforms(A)[:, :, None])  # (B, i, j): A_j A_i^-1
    pair = valid[:, :, None] & valid[:, None, :] & ~torch.eye(V, dtype=torch.bool, device=valid.device)
    order = torch.zeros(B, V, dtype=torch.long, device=valid.device)
    b = torch.arange(B, device=valid.device)[:, None]
    v = torch.arange(V, device=valid.device)[None]
    for _ in range(rounds):
        cur_inv = invert_transforms(Mk[b, v, order])  # (B, V, 4, 4): view i in its current numbering
        theta_b = _angle(Mk[:, None] @ cur_inv[:, :, None, None])  # (B, i, j, K): M_j^k M_i^-1
        mis = (theta_b - theta_a[..., None]).abs()
        mis = torch.where(pair[..., None], mis, torch.full_like(mis, float("nan")))
        new = mis.nanmedian(1).values.nan_to_num(0.0).argmin(-1)  # (B, V)
        new = torch.where(valid, new, 0)
        if bool((new == order).all()):
            break
        order = new
    # the majority's numbering is the board's: a board numbered the other way in most views is turned as a whole
    counts = torch.stack([((order == k) & valid).sum(1) for k in range(K)], -1)  # (B, K)
    major = counts.argmax(-1)
    perm = torch.stack([torch.tensor([_compose(syms, k, m) for k in range(K)], device=valid.device)
                        for m in range(K)])  # (K major, K view): symmetry relative to the major one
    return torch.where(valid, perm[major[:, None], order], 0)


def _compose(syms: list[BoardSymmetry], k: int, m: int) -> int:
    """The index of the symmetry taking the numbering ``m`` to ``k`` (``S_m^T S_k``, a turn of the group)."""
    S = syms[m].S.T @ syms[k].S
    for j, s in enumerate(syms):
        if torch.allclose(s.S, S, atol=1e-9):
            return j
    return k


def renumber_corners(corners: torch.Tensor, valid: torch.Tensor, order: torch.Tensor, syms: list[BoardSymmetry]
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Corners :math:`(B, V, N, 2)` and their mask :math:`(B, V, N)` in the board's numbering: a view numbered by
    symmetry ``k`` (its corner ``n`` is the board's ``perm[n]``) has its corners moved to ``perm[n]``."""
    out_c, out_v = corners.clone(), valid.clone()
    for k in range(1, len(syms)):
        sel = order == k
        if not bool(sel.any()):
            continue
        inv = torch.empty_like(syms[k].perm)
        inv[syms[k].perm] = torch.arange(syms[k].perm.numel(), device=inv.device)
        out_c[sel] = corners[sel][:, inv.to(corners.device)]
        out_v[sel] = valid[sel][:, inv.to(valid.device)]
    return out_c, out_v
