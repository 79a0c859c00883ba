r"""Distribution-aware outlier rejection of heatmap peaks (paper Sec. III-B).

The network is trained to draw every corner with the same sigma, so a blob whose fitted sigma
(:func:`~ccs_kornia.modules.detection.learned.gaussian_fit.gaussian_fit`) differs from it is an unreliable detection
and is dropped.
"""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["sigma_outlier_rejection", "SigmaOutlierRejection"]


def sigma_outlier_rejection(
    sigma: torch.Tensor,
    mask: torch.Tensor,
    expected_sigma: float | torch.Tensor,
    tolerance: float = 0.5,
) -> torch.Tensor:
    r"""Distribution-aware outlier rejection: drop peaks whose fitted sigma is not the training sigma.

    A peak is kept when ``mask`` is set and both :math:`|\sigma_x - \sigma^*| \le \text{tol}\,\sigma^*` and
    :math:`|\sigma_y - \sigma^*| \le \text{tol}\,\sigma^*` (non-finite sigmas are rejected).

    Args:
        sigma: fitted standard deviations :math:`(B, M, 2)` from :func:`gaussian_fit`.
        mask: :math:`(B, M)` bool, peaks to consider (typically ``mask & ok``).
        expected_sigma: the sigma of the training targets, a positive float or a tensor broadcastable to
            :math:`(B, M, 2)` (e.g. per axis ``(2,)`` or per image ``(B, 1, 1)``).
        tolerance: allowed relative deviation.

    Returns:
        :math:`(B, M)` bool mask of the kept peaks.

    Example:
        >>> sigma = torch.tensor([[[1.5, 1.4], [3.5, 1.5], [1.5, 1.5]]])
        >>> sigma_outlier_rejection(sigma, torch.tensor([[True, True, False]]), 1.5, 0.5)
        tensor([[ True, False, False]])
    """
    check_tensor(sigma, "sigma", ["B", "M", "2"])
    check_tensor(mask, "mask", sigma.shape[:2])
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}.")
    expected = torch.as_tensor(expected_sigma, dtype=sigma.dtype, device=sigma.device)
    if not bool((expected > 0).all()):
        raise ValueError(f"expected_sigma must be positive, got {expected_sigma!r}.")
    try:
        deviation = (sigma - expected).abs() / expected
        deviation = torch.broadcast_to(deviation, sigma.shape)
    except RuntimeError as err:
        raise ValueError(
            f"expected_sigma of shape {tuple(expected.shape)} does not broadcast to sigma {tuple(sigma.shape)}."
        ) from err
    within = (deviation <= tolerance) & torch.isfinite(sigma)
    return mask.bool() & within.all(-1)


class SigmaOutlierRejection(nn.Module):
    r"""Module form of :func:`sigma_outlier_rejection`.

    Args:
        expected_sigma: sigma of the training heatmaps (pixels).
        tolerance: allowed relative deviation of each fitted sigma.

    Example:
        >>> reject = SigmaOutlierRejection(expected_sigma=1.5, tolerance=0.5)
        >>> reject(torch.tensor([[[1.6, 1.4], [0.5, 1.5]]]), torch.tensor([[True, True]]))
        tensor([[ True, False]])
    """

    def __init__(self, expected_sigma: float = 1.5, tolerance: float = 0.5) -> None:
        super().__init__()
        if expected_sigma <= 0:
            raise ValueError(f"expected_sigma must be positive, got {expected_sigma}.")
        if tolerance < 0:
            raise ValueError(f"tolerance must be >= 0, got {tolerance}.")
        self.expected_sigma = float(expected_sigma)
        self.tolerance = float(tolerance)

    def forward(self, sigma: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return sigma_outlier_rejection(sigma, mask, self.expected_sigma, self.tolerance)

    def extra_repr(self) -> str:
        return f"expected_sigma={self.expected_sigma}, tolerance={self.tolerance}"
