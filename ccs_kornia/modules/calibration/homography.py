"""Batched board-to-image homographies (kornia DLT with per-corner weights).

Every view of every camera is one batch element of :func:`kornia.geometry.homography.find_homography_dlt`;
missing corners get weight 0. Kornia already Hartley-normalises both point sets (using the weights), so the
fit is well conditioned in float32 and float64 without extra work here.
"""

from __future__ import annotations

import torch
from kornia.geometry.homography import find_homography_dlt
from torch import nn

from ccs_kornia.runtime.checks import broadcast_shapes, check_tensor

__all__ = ["MIN_HOMOGRAPHY_POINTS", "find_homographies", "BatchedHomography"]

#: a homography has 8 degrees of freedom: 4 correspondences in general position
MIN_HOMOGRAPHY_POINTS = 4


def find_homographies(
    object_xy: torch.Tensor, image_xy: torch.Tensor, valid: torch.Tensor | None = None, return_ok: bool = False
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Fit one homography per view, mapping board plane coordinates to pixels.

    ``image ~ H @ [X, Y, 1]``. Views with fewer than 4 valid corners, or whose fit is not finite
    (e.g. all corners collinear), get the identity (never NaN) and ``ok = False``.

    Args:
        object_xy: :math:`(*, N, 2)` board coordinates (``X, Y`` of the planar object points); broadcast
            against ``image_xy``, so a single :math:`(N, 2)` board serves every view.
        image_xy: :math:`(*, N, 2)` pixel coordinates; entries where ``valid`` is False may be anything,
            NaN included.
        valid: :math:`(*, N)` bool mask of observed corners (default: all observed).
        return_ok: also return the :math:`(*)` bool flag of views with a usable homography.

    Returns:
        :math:`(*, 3, 3)` homographies scaled to ``H[2, 2] = 1`` (and the ``ok`` flags if requested).

    Example:
        >>> obj = torch.tensor([[0., 0.], [1., 0.], [0., 1.], [1., 1.]])
        >>> H = find_homographies(obj, 2 * obj + 3)
        >>> torch.allclose(H, torch.tensor([[2., 0., 3.], [0., 2., 3.], [0., 0., 1.]]), atol=1e-5)
        True
    """
    check_tensor(image_xy, "image_xy", ["*", "N", "2"])
    check_tensor(object_xy, "object_xy", ["*", "N", "2"], N=image_xy.shape[-2])
    batch_shape = broadcast_shapes(object_xy.shape[:-2], image_xy.shape[:-2])
    num_points = image_xy.shape[-2]
    if valid is None:
        valid = torch.ones(image_xy.shape[:-1], dtype=torch.bool, device=image_xy.device)
    check_tensor(valid, "valid", ["*", "N"], N=num_points)
    batch_shape = broadcast_shapes(batch_shape, valid.shape[:-1])
    if num_points < MIN_HOMOGRAPHY_POINTS:
        raise ValueError(f"A homography needs at least {MIN_HOMOGRAPHY_POINTS} points per view, got N={num_points}.")

    dtype = image_xy.dtype if image_xy.is_floating_point() else torch.float32
    src = object_xy.to(dtype).expand(*batch_shape, num_points, 2).reshape(-1, num_points, 2)
    dst = image_xy.to(dtype).expand(*batch_shape, num_points, 2).reshape(-1, num_points, 2)
    mask = valid.bool().expand(*batch_shape, num_points).reshape(-1, num_points)
    mask = mask & dst.isfinite().all(-1) & src.isfinite().all(-1)

    enough = mask.sum(-1) >= MIN_HOMOGRAPHY_POINTS
    # A view without enough corners is solved as the identity problem (board onto itself, all weights 1)
    # so the batched solve stays finite and no NaN can leak into gradients through torch.where.
    weights = torch.where(enough[:, None], mask, torch.ones_like(mask)).to(dtype)
    dst = torch.where(mask[..., None] & enough[:, None, None], dst, src)
    src = torch.where(src.isfinite(), src, torch.zeros_like(src))
    dst = torch.where(dst.isfinite(), dst, torch.zeros_like(dst))

    H = find_homography_dlt(src, dst, weights=weights, solver="svd")
    ok = enough & H.flatten(-2).isfinite().all(-1) & (H[:, 2, 2].abs() > 1e-12)
    eye = torch.eye(3, dtype=dtype, device=H.device).expand_as(H)
    H = torch.where(ok[:, None, None], H, eye)
    H = H.reshape(*batch_shape, 3, 3)
    ok = ok.reshape(batch_shape)
    return (H, ok) if return_ok else H


class BatchedHomography(nn.Module):
    r"""Module wrapper of :func:`find_homographies`.

    Args:
        return_ok: also return the per-view ``ok`` flags.

    Shape:
        - object_xy: :math:`(*, N, 2)`, image_xy: :math:`(*, N, 2)`, valid: :math:`(*, N)`
        - output: :math:`(*, 3, 3)` [and :math:`(*)` bool]

    Example:
        >>> obj = torch.tensor([[0., 0.], [1., 0.], [0., 1.], [1., 1.]])
        >>> H, ok = BatchedHomography(return_ok=True)(obj, obj[None] + 1, torch.ones(1, 4, dtype=torch.bool))
        >>> H.shape, ok.tolist()
        (torch.Size([1, 3, 3]), [True])
    """

    def __init__(self, return_ok: bool = False) -> None:
        super().__init__()
        self.return_ok = return_ok

    def forward(
        self, object_xy: torch.Tensor, image_xy: torch.Tensor, valid: torch.Tensor | None = None
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        return find_homographies(object_xy, image_xy, valid, return_ok=self.return_ok)
