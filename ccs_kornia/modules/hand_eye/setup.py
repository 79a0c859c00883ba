r"""Where the camera and the board sit on the robot: the two hand-eye set-ups as a type.

The robot reports the flange's pose in its base frame for every view, ``T`` with ``x_base = T x_flange``. One of
the camera and the board rides on the flange, the other stands still in the room:

* **eye-in-hand**: the camera on the flange; ``X`` is the camera's pose in the flange frame (``x_flange = X
  x_camera``) and the board stands still in the base frame (``x_base = Z x_board``);
* **eye-to-hand**: the camera fixed in the room; ``X`` is the camera's pose in the base frame (``x_base = X
  x_camera``) and the board rides on the flange (``x_flange = Z x_board``).

Either way a board point ``p`` is seen by the camera at ``x_camera = X^{-1} A Z p`` with the robot's *chain*
``A = T^{-1}`` (eye-in-hand) or ``A = T`` (eye-to-hand): :meth:`HandEyeSetup.chain`.
"""

from __future__ import annotations

import enum

import torch

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["HandEyeSetup", "invert_transforms"]


def invert_transforms(T: torch.Tensor) -> torch.Tensor:
    """Inverses :math:`(*, 4, 4)` of rigid transforms :math:`(*, 4, 4)` (``R^T``, ``-R^T t``).

    Example:
        >>> T = torch.eye(4, dtype=torch.float64); T[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
        >>> invert_transforms(T)[:3, 3].tolist()
        [-1.0, -2.0, -3.0]
    """
    check_tensor(T, "T", ["*", "4", "4"], what="transforms")
    out = torch.zeros_like(T)
    Rt = T[..., :3, :3].transpose(-1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


class HandEyeSetup(enum.Enum):
    """Eye-in-hand (camera on the flange) or eye-to-hand (camera fixed, board on the flange); see the module doc.

    Example:
        >>> HandEyeSetup.EYE_TO_HAND.camera_frame, HandEyeSetup.EYE_TO_HAND.board_frame
        ('base', 'flange')
        >>> HandEyeSetup.parse("eye-in-hand") is HandEyeSetup.EYE_IN_HAND
        True
    """

    EYE_IN_HAND = "eye_in_hand"
    EYE_TO_HAND = "eye_to_hand"

    @classmethod
    def parse(cls, value: "HandEyeSetup | str") -> "HandEyeSetup":
        """A set-up from itself or its name (``eye_in_hand``, ``eye-in-hand``, ...)."""
        if isinstance(value, cls):
            return value
        key = str(value).strip().lower().replace("-", "_")
        for member in cls:
            if member.value == key:
                return member
        raise ValueError(f"unknown hand-eye set-up {value!r}; expected eye_in_hand or eye_to_hand")

    @property
    def camera_frame(self) -> str:
        """The robot frame the camera is fixed in (``X`` is the camera's pose there)."""
        return "flange" if self is HandEyeSetup.EYE_IN_HAND else "base"

    @property
    def board_frame(self) -> str:
        """The robot frame the board is fixed in (``Z`` is the board's pose there)."""
        return "base" if self is HandEyeSetup.EYE_IN_HAND else "flange"

    @property
    def label(self) -> str:
        """``eye-in-hand`` or ``eye-to-hand``, as users write it."""
        return self.value.replace("_", "-")

    def chain(self, robot_poses: torch.Tensor) -> torch.Tensor:
        """The robot's chain ``A`` :math:`(*, 4, 4)` of ``x_camera = X^{-1} A Z p`` from the flange poses ``T``
        :math:`(*, 4, 4)` (``x_base = T x_flange``)."""
        return invert_transforms(robot_poses) if self is HandEyeSetup.EYE_IN_HAND else robot_poses
