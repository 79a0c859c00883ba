r"""The radial distortion a lens shows in a few board views, before any calibration: the guess a guided capture lays
its first poses out with (:func:`~ccs_kornia.pipeline.guided_capture.guess_camera`).

A board's rows are straight; a lens's barrel bends them. :func:`radial_from_views` finds the one-parameter division
model about the image centre that straightens them (no focal length, no pose needed: each view's homography absorbs
both), and :func:`radial_polynomial_from_division` writes it as a pinhole's ``k1, k2`` once a focal length is known.
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.modules.calibration.homography import find_homographies
from ccs_kornia.runtime.checks import check_tensor

__all__ = ["DIVISION_RANGE", "radial_from_views", "radial_polynomial_from_division"]

#: the barrel or pincushion a guess may take, as the division model's relative change of the image corner's radius
#: (:func:`radial_from_views`): at ``-0.6`` the corner's undistorted radius is 2.5 times its own
DIVISION_RANGE = (-0.6, 0.4)


def radial_from_views(corners: torch.Tensor, object_points: torch.Tensor, image_size: tuple[int, int],
                      steps: int = 51) -> float:
    r"""The radial distortion about the image centre that makes the views' boards most nearly flat projections: the
    one-parameter division model ``u = c + (d - c) / (1 + kappa |d - c|^2 / R^2)`` (``d`` the pixel seen, ``R`` the
    half-diagonal) whose undistorted corners each view's homography fits best, found over
    :data:`DIVISION_RANGE` (a grid, then a finer one about its best). The board's straight rows tell it, tilted or
    not, without the focal length.

    Args:
        corners: :math:`(V, N, 2)` px, NaN where not seen.
        object_points: :math:`(N, 3)` the board's corners (``z = 0``).
        image_size: ``(W, H)``.
        steps: grid values per pass.

    Returns:
        ``kappa`` (0 where no view has 8 corners seen).

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> obj = board_object_points(9, 6, 0.025, dtype=torch.float64)
        >>> c = torch.tensor([319.5, 239.5], dtype=torch.float64)
        >>> flat = obj[:, :2] * 2000 + torch.tensor([150.0, 120.0], dtype=torch.float64)  # a board held flat
        >>> seen = c + (flat - c) * 2 / (1 + (1 + 4 * 0.3 * ((flat - c) ** 2).sum(-1, keepdim=True) / 400**2).sqrt())
        >>> round(radial_from_views(seen[None], obj, (640, 480)), 2)  # pixels seen under a division model's -0.3
        -0.3
    """
    uv = torch.as_tensor(corners, dtype=torch.float64)
    check_tensor(uv, "corners", ["V", "N", "2"])
    check_tensor(object_points, "object_points", ["N", "3"], N=uv.shape[1])
    W, H = image_size
    valid = uv.isfinite().all(-1)
    valid = valid & (valid.sum(-1, keepdim=True) >= 8)
    if not bool(valid.any()):
        return 0.0
    c = torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=torch.float64)
    R2 = ((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2
    d = uv.nan_to_num(0.0) - c
    r2 = (d * d).sum(-1, keepdim=True) / R2  # (V, N, 1)
    xy = object_points.double()[:, :2]

    def cost(kappa: torch.Tensor) -> torch.Tensor:  # (K,) -> (K,) the squared residuals in the pixels seen
        scale = 1 + kappa[:, None, None, None] * r2[None]  # (K, V, N, 1)
        und = c + d[None] / scale.clamp_min(1e-3)
        Hs = find_homographies(xy, und, valid[None].expand(len(kappa), -1, -1))
        p = torch.cat([xy, torch.ones_like(xy[:, :1])], -1) @ Hs.transpose(-1, -2)
        res = ((p[..., :2] / p[..., 2:] - und) * scale).pow(2).sum(-1)
        return torch.where(valid[None] & (scale[..., 0] > 1e-3), res, torch.zeros_like(res)).flatten(1).sum(-1)

    lo, hi = DIVISION_RANGE
    kappa = torch.linspace(lo, hi, steps, dtype=torch.float64)
    best = float(kappa[int(torch.argmin(cost(kappa)))])
    step = (hi - lo) / (steps - 1)
    kappa = torch.linspace(best - step, best + step, steps, dtype=torch.float64)
    return float(kappa[int(torch.argmin(cost(kappa)))])


def radial_polynomial_from_division(kappa: float, focal: float,
                                    image_size: tuple[int, int]) -> tuple[float, float] | None:
    """The ``k1, k2`` of the pinhole's radial polynomial (OpenCV's, in normalised coordinates) nearest the division
    model ``kappa`` (:func:`radial_from_views`) over the image's radius, at the focal length given; ``None`` where the
    division model or the polynomial does not map the whole image one to one.

    Example:
        >>> k1, k2 = radial_polynomial_from_division(-0.3, 330.0, (640, 480))
        >>> k1 < 0
        True
        >>> radial_polynomial_from_division(-0.9, 330.0, (640, 480)) is None  # folds before the image's corner
        True
    """
    W, H = image_size
    rc = math.hypot((W - 1) / 2, (H - 1) / 2) / focal  # the image corner's normalised radius
    lam = kappa / rc**2
    rd = torch.linspace(0.0, rc, 65, dtype=torch.float64)[1:]
    if 1 + lam * rc**2 < 0.2:
        return None
    ru = rd / (1 + lam * rd**2)
    A = torch.stack([ru**2, ru**4], -1)
    k = torch.linalg.lstsq(A, (rd / ru - 1)[:, None]).solution[:, 0]
    r = torch.linspace(0.0, float(ru[-1]) * 1.05, 256, dtype=torch.float64)
    if not bool((1 + 3 * k[0] * r**2 + 5 * k[1] * r**4 > 0.05).all()):
        return None
    return float(k[0]), float(k[1])
