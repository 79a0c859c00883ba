r"""The board's scale against the robot's: is the board the size it was given?

Once the fit knows the rotations of ``X`` and ``Z``, every view's ``X M_v = A_v Z`` is linear in the translations and
in a scale ``s`` of the board (a board of the wrong size scales the camera's translations ``t_M`` alone):

.. math:: R_X (s\, t_{M_v}) + t_X - R_{A_v} t_Z = t_{A_v}

solved by least squares over the views (absolute poses: no motion pairs, so the robot's pose errors are not
differenced twice), with ``s``'s standard error from the residuals. ``s = 1`` for a board of the size it was given; a
board measured or printed at another scale (a circle grid's spacing or a square given wrong) gives ``s != 1``, and
the board's true size is ``s`` times the given one. :func:`~ccs_kornia.modules.hand_eye.solver.calibrate_hand_eye`
refuses a problem whose ``s`` is off by more than :data:`SCALE_TOLERANCE` and :data:`SCALE_SIGMAS` standard errors.
"""

from __future__ import annotations

import torch

__all__ = ["SCALE_SIGMAS", "SCALE_TOLERANCE", "board_scale"]

#: a board scale further than this from 1 (relative) ...
SCALE_TOLERANCE = 0.01
#: ... and by more than this many standard errors is refused: the board is not the size it was given
SCALE_SIGMAS = 5.0


def board_scale(A: torch.Tensor, M: torch.Tensor, valid: torch.Tensor, R_X: torch.Tensor, R_Z: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
    r"""The board's scale ``s`` :math:`(B,)` and its standard error :math:`(B,)` (module doc; NaN with fewer than 4
    views).

    Args:
        A: :math:`(B, V, 4, 4)` the robot's chain per view; M: :math:`(B, V, 4, 4)` the board's pose in the camera
            per view (``x_camera = M p``); valid: :math:`(B, V)`.
        R_X, R_Z: :math:`(B, 3, 3)` the rotations of ``X`` and ``Z``.

    Example:
        >>> from ccs_kornia.geometry.so3 import exp_so3
        >>> g = torch.Generator().manual_seed(0)
        >>> A = torch.eye(4, dtype=torch.float64).repeat(1, 6, 1, 1)
        >>> A[0, :, :3, :3] = exp_so3(torch.randn(6, 3, generator=g, dtype=torch.float64) * 0.4)
        >>> A[0, :, :3, 3] = torch.randn(6, 3, generator=g, dtype=torch.float64) * 0.2
        >>> X, Z = torch.eye(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
        >>> X[:3, 3], Z[:3, 3] = torch.tensor([0.05, 0.0, 0.1]), torch.tensor([0.5, 0.1, 0.0])
        >>> M = torch.linalg.inv(X) @ A @ Z
        >>> M[..., :3, 3] /= 1.03  # the board given 3 % larger than it is
        >>> s, se = board_scale(A, M, torch.ones(1, 6, dtype=torch.bool), X[None, :3, :3], Z[None, :3, :3])
        >>> round(float(s[0]), 4), float(se[0]) < 1e-6
        (1.03, True)
    """
    B, V = valid.shape
    dtype, device = A.dtype, A.device
    eye = torch.eye(3, dtype=dtype, device=device)
    C = torch.zeros(B, V, 3, 7, dtype=dtype, device=device)
    C[..., 0] = (R_X[:, None] @ M[..., :3, 3:4])[..., 0]
    C[..., 1:4] = eye
    C[..., 4:7] = -A[..., :3, :3]
    d = A[..., :3, 3]
    ok = valid.bool() & C.flatten(-2).isfinite().all(-1) & d.isfinite().all(-1)
    C = torch.where(ok[..., None, None], C.nan_to_num(0.0), 0.0)
    d = torch.where(ok[..., None], d.nan_to_num(0.0), 0.0)
    N = (C.transpose(-1, -2) @ C).sum(1)
    rhs = (C.transpose(-1, -2) @ d[..., None]).sum(1)
    sol = (torch.linalg.pinv(N) @ rhs)[..., 0]  # (B, 7)
    r = (C @ sol[:, None, :, None])[..., 0] - d
    dof = (3 * ok.sum(-1) - 7).clamp_min(1).to(dtype)
    var = (r * r).sum((-1, -2)) / dof
    se = (torch.linalg.pinv(N)[:, 0, 0].clamp_min(0) * var).sqrt()
    few = ok.sum(-1) < 4
    nan = torch.full_like(se, float("nan"))
    return torch.where(few, nan, sol[:, 0]), torch.where(few, nan, se)
