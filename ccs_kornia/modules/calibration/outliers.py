"""The outlier rule of the solvers: which views (or a rig's camera x frame observations) the next fit keeps.

An observation is an outlier when its RMS reprojection error exceeds ``max(abs_threshold, rel_threshold * median)``,
the median taken over the observations the last fit used: the relative part follows the noise of the set, the
absolute floor keeps a very clean set from rejecting views for fractions of a pixel. The camera, fisheye and rig
solvers apply it after their first fit; a candidate left out of that fit comes back when it fits the refined camera.
"""

from __future__ import annotations

import torch

__all__ = ["drop_outliers"]


def drop_outliers(
    rms: torch.Tensor,
    used: torch.Tensor,
    candidates: torch.Tensor,
    abs_threshold: float,
    rel_threshold: float,
    min_kept: int,
) -> torch.Tensor:
    r"""The observations to keep, per problem of a batch.

    Args:
        rms: :math:`(B, ..., V)` RMS error of every observation (any value where not a candidate).
        used: :math:`(B, ..., V)` bool, the observations of the last fit (their median sets the threshold).
        candidates: :math:`(B, ..., V)` bool, the observations that may be kept.
        abs_threshold: px, the threshold's floor.
        rel_threshold: the threshold's factor on the median.
        min_kept: where a row (the last dimension) of a problem would keep fewer observations, or where the problem
            has no finite median, the problem keeps ``used`` as it is.

    Returns:
        :math:`(B, ..., V)` bool.

    Example:
        >>> rms = torch.tensor([[0.3, 0.4, 0.35, 9.0, 0.5]])
        >>> used = torch.tensor([[True, True, True, True, False]])
        >>> drop_outliers(rms, used, torch.ones_like(used), 2.0, 5.0, 3).tolist()  # threshold max(2, 5 * 0.35)
        [[True, True, True, False, True]]
    """
    B = rms.shape[0]
    med = torch.where(used, rms, float("nan")).reshape(B, -1).nanmedian(-1).values
    thr = torch.clamp(rel_threshold * med, min=abs_threshold)
    shape = (B,) + (1,) * (rms.dim() - 1)
    keep = candidates & (rms <= thr.view(shape))
    enough = (keep.sum(-1) >= min_kept).reshape(B, -1).all(-1) & med.isfinite()
    return torch.where(enough.view(shape), keep, used)
