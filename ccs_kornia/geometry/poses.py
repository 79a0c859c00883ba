"""Relative poses of a rig's cameras from their extrinsics (``x_c = R_c x_0 + T_c``, OpenCV's ``stereoCalibrate``
convention): the pose of one camera in another's frame, for the solver's figures and the exported pairs alike."""

from __future__ import annotations

import torch

__all__ = ["pair_pose"]


def pair_pose(R: torch.Tensor, T: torch.Tensor, i: int, j: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(R_ij, T_ij)`` with ``x_j = R_ij x_i + T_ij``, from rig extrinsics ``R`` :math:`(C, 3, 3)`, ``T``
    :math:`(C, 3)`.

    Example:
        >>> R = torch.eye(3, dtype=torch.float64).expand(2, 3, 3)
        >>> T = torch.tensor([[0.0, 0.0, 0.0], [-0.1, 0.0, 0.0]], dtype=torch.float64)
        >>> pair_pose(R, T, 1, 0)[1].tolist()
        [0.1, 0.0, 0.0]
    """
    Rij = R[j] @ R[i].T
    return Rij, T[j] - Rij @ T[i]
