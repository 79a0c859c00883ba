r"""A rig at one point of its fit, and the board corners the fit explains: the two values the rig's stages pass.

:class:`RigState` holds the unknowns of B rigs of C cameras over F frames: each camera's model and parameters, the
extrinsics ``(R_c, T_c)`` (``x_c = R_c x_0 + T_c``; camera 0 the reference) and one board pose ``(R_f, t_f)`` per
frame, board to camera 0. A board point ``X`` seen by camera ``c`` in frame ``f`` projects as
``model_c(R_c (R_f X + t_f) + T_c)`` (:meth:`RigState.board_poses`: ``R_c R_f`` and ``R_c t_f + T_c``).
:class:`RigObservations` holds what the fit explains: the board's points, the observed corners and their weights.
The joint fit (:func:`~ccs_kornia.modules.rig.rig_lm.rig_levenberg_marquardt`) takes a start state and the
observations and returns the state it reached; the frame figures
(:mod:`~ccs_kornia.modules.rig.frame_consistency`) and the advice (:mod:`~ccs_kornia.modules.rig.session_advice`)
read a state.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.models.base import CameraModel

__all__ = ["RigObservations", "RigState"]


@dataclass(frozen=True)
class RigState:
    r"""The unknowns of B rigs of C cameras over F frames (see the module doc).

    Attributes:
        models: C camera models (:class:`~ccs_kornia.geometry.models.CameraModel`; pinhole and fisheye mix).
        params: per camera :math:`(B, P_c)` its model's parameters.
        R: :math:`(B, C, 3, 3)` extrinsic rotations (``R[:, 0] = I``).
        T: :math:`(B, C, 3)` extrinsic translations (``T[:, 0] = 0``).
        frame_R: :math:`(B, F, 3, 3)` board rotations, board -> camera 0.
        frame_t: :math:`(B, F, 3)` board translations.
        board_warp: :math:`(B, 2)` the board's sag (mrcal's ``calobject_warp``,
            :mod:`~ccs_kornia.geometry.board_warp`), estimated with the rest; ``None``: a flat board.

    Example:
        >>> from ccs_kornia.geometry.models import PINHOLE
        >>> p = torch.tensor([[500.0, 500.0, 320.0, 240.0]])
        >>> T = torch.tensor([[[0.0, 0, 0], [-0.1, 0, 0]]])
        >>> s = RigState([PINHOLE] * 2, [p, p], torch.eye(3).expand(1, 2, 3, 3), T,
        ...              torch.eye(3).expand(1, 4, 3, 3), torch.zeros(1, 4, 3))
        >>> s.num_cameras, s.num_frames, s.repeat(3).T.shape, s.rig(0).params[1].shape
        (2, 4, torch.Size([3, 2, 3]), torch.Size([1, 4]))
    """

    models: Sequence[CameraModel]
    params: Sequence[torch.Tensor]
    R: torch.Tensor
    T: torch.Tensor
    frame_R: torch.Tensor
    frame_t: torch.Tensor
    board_warp: torch.Tensor | None = None

    @property
    def num_cameras(self) -> int:
        return len(self.models)

    @property
    def num_frames(self) -> int:
        return self.frame_R.shape[1]

    def board_poses(self) -> tuple[torch.Tensor, torch.Tensor]:
        r"""Each camera's board pose in every frame: ``R_c R_f`` :math:`(B, C, F, 3, 3)` and ``R_c t_f + T_c``
        :math:`(B, C, F, 3)`.

        Example:
            >>> from ccs_kornia.geometry.models import PINHOLE
            >>> p = torch.tensor([[500.0, 500.0, 320.0, 240.0]])
            >>> s = RigState([PINHOLE] * 2, [p, p], torch.eye(3).expand(1, 2, 3, 3),
            ...              torch.tensor([[[0.0, 0, 0], [-0.1, 0, 0]]]), torch.eye(3).expand(1, 1, 3, 3),
            ...              torch.tensor([[[0.0, 0, 1]]]))
            >>> s.board_poses()[1][0, :, 0].tolist()
            [[0.0, 0.0, 1.0], [-0.10000000149011612, 0.0, 1.0]]
        """
        Rc = self.R[:, :, None] @ self.frame_R[:, None]
        tc = (self.R[:, :, None] @ self.frame_t[:, None, :, :, None])[..., 0] + self.T[:, :, None]
        return Rc, tc

    def rig(self, b: int) -> RigState:
        """Rig ``b`` alone (the batch dimension kept, of size 1)."""
        return RigState(self.models, [p[b : b + 1] for p in self.params], self.R[b : b + 1], self.T[b : b + 1],
                        self.frame_R[b : b + 1], self.frame_t[b : b + 1],
                        None if self.board_warp is None else self.board_warp[b : b + 1])

    def repeat(self, k: int) -> RigState:
        """``k`` copies of the B rigs, :math:`(k B, ...)` (copy ``i`` of rig ``b`` at ``i B + b``)."""
        def rep(x):
            return x.repeat(k, *([1] * (x.dim() - 1)))

        return RigState(self.models, [rep(p) for p in self.params], rep(self.R), rep(self.T), rep(self.frame_R),
                        rep(self.frame_t), None if self.board_warp is None else rep(self.board_warp))


@dataclass(frozen=True)
class RigObservations:
    r"""The board corners a rig's fit explains.

    Attributes:
        object_points: :math:`(N, 3)` board points (their unit is the unit of ``T`` and ``frame_t``).
        corners: :math:`(B, C, F, N, 2)` observed pixels (anything where the weight is 0).
        weights: :math:`(B, C, F, N)` per-corner inverse variances (0: not used).
    """

    object_points: torch.Tensor
    corners: torch.Tensor
    weights: torch.Tensor
