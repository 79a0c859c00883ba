"""Detection loss of the corner UNet (paper Eq. 2): squared error between predicted and target heatmaps."""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.runtime.checks import check_same_shape, check_tensor

__all__ = ["heatmap_loss", "HeatmapLoss"]

_REDUCTIONS = ("mean", "sum", "none")


def heatmap_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    reduction: str = "mean",
    pos_weight: float = 0.0,
    pos_threshold: float = 0.1,
) -> torch.Tensor:
    r"""Squared error between a predicted and a target Gaussian heatmap, optionally up-weighting corner pixels.

    .. math::
        L = \operatorname{reduce}\big(w \odot (\hat Y - Y)^2\big), \qquad
        w = 1 + \text{pos\_weight} \cdot [Y > \text{pos\_threshold}]

    The paper's loss is the plain integral of :math:`(\hat Y - Y)^2` (``pos_weight=0``). On a 640x480 image with
    54 corners of sigma 1.5 px, only about 0.6 % of the pixels have ``Y > 0.1``, so the all-zero heatmap already
    scores a tiny loss and early training tends to collapse towards it. ``pos_weight > 0`` multiplies the error
    on those pixels by ``1 + pos_weight`` to counter that imbalance. Because the weight is positive and depends
    only on the target, the per-pixel minimiser is still ``pred == target`` everywhere: the weighting changes how
    errors are traded off while the network cannot fit exactly, not what a perfect fit looks like, so it does not
    bias the sub-pixel peak position or the fitted sigma.

    Args:
        pred: predicted heatmap :math:`(B, C, H, W)`.
        target: target heatmap of the same shape (Gaussians with unit peak, zero background).
        reduction: ``"mean"`` (over all elements), ``"sum"`` or ``"none"`` (per-pixel weighted squared error).
        pos_weight: extra weight for pixels where ``target > pos_threshold``; ``0`` gives the paper's loss.
        pos_threshold: target value above which a pixel counts as "near a corner".

    Returns:
        scalar loss, or :math:`(B, C, H, W)` for ``reduction="none"``.

    Example:
        >>> pred = torch.zeros(1, 1, 8, 8)
        >>> target = torch.zeros(1, 1, 8, 8); target[..., 4, 4] = 1.0
        >>> heatmap_loss(pred, target, reduction="sum", pos_weight=3.0)
        tensor(4.)
    """
    check_tensor(pred, "pred", ["B", "C", "H", "W"])
    check_same_shape(target, "target", pred, "pred")
    if reduction not in _REDUCTIONS:
        raise ValueError(f"Unknown reduction {reduction!r}; expected one of {_REDUCTIONS}.")
    if pos_weight < 0:
        raise ValueError(f"pos_weight must be >= 0, got {pos_weight}.")
    error = (pred - target) ** 2
    if pos_weight > 0:
        error = error * (1.0 + pos_weight * (target > pos_threshold).to(error.dtype))
    if reduction == "mean":
        return error.mean()
    if reduction == "sum":
        return error.sum()
    return error


class HeatmapLoss(nn.Module):
    r"""Module form of :func:`heatmap_loss` (paper Eq. 2, optional corner-pixel weighting).

    Args:
        reduction: ``"mean"``, ``"sum"`` or ``"none"``.
        pos_weight: extra weight on pixels with ``target > pos_threshold`` (see :func:`heatmap_loss` for why).
        pos_threshold: threshold on the target defining "near a corner".

    Example:
        >>> loss = HeatmapLoss(pos_weight=10.0)
        >>> loss(torch.rand(2, 1, 16, 16), torch.rand(2, 1, 16, 16)).shape
        torch.Size([])
    """

    def __init__(self, reduction: str = "mean", pos_weight: float = 0.0, pos_threshold: float = 0.1) -> None:
        super().__init__()
        if reduction not in _REDUCTIONS:
            raise ValueError(f"Unknown reduction {reduction!r}; expected one of {_REDUCTIONS}.")
        if pos_weight < 0:
            raise ValueError(f"pos_weight must be >= 0, got {pos_weight}.")
        self.reduction = reduction
        self.pos_weight = float(pos_weight)
        self.pos_threshold = float(pos_threshold)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return heatmap_loss(pred, target, self.reduction, self.pos_weight, self.pos_threshold)

    def extra_repr(self) -> str:
        return f"reduction={self.reduction!r}, pos_weight={self.pos_weight}, pos_threshold={self.pos_threshold}"
