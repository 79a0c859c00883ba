"""The paper's radial distortion about a free centre, applied to the pinhole projection (analytic derivatives).

``p = (fx x + cx, fy y + cy)`` is the pinhole pixel, ``c = ((W-1)/2 + ox, (H-1)/2 + oy)`` the distortion centre
(the image centre shifted by ``(ox, oy)`` px), ``r = |p - c| / max(W, H)`` and
``p_d = c + (p - c) (1 + k1 r^2 + k2 r^4 + k3 r^6)``, as
:func:`ccs_kornia.modules.calibration.centred_radial.centred_radial_distort`. Parameters are
``fx, fy, cx, cy, k1, k2, k3, ox, oy``; by default the centre offset is fixed (``default_free``).
"""

from __future__ import annotations

import torch

from ccs_kornia.modules.calibration.models.base import CameraModel, broadcast_params, check_projection_inputs

__all__ = ["CentredRadialModel"]


class CentredRadialModel(CameraModel):
    r"""Pinhole + the paper's image-centred radial distortion with an optional free centre.

    Args:
        image_size: ``(W, H)``; the distortion is centred on ``((W-1)/2, (H-1)/2)`` plus the offset parameters and
            radii are in units of ``max(W, H)``.
        free_centre: whether :meth:`default_free` includes the centre offset ``ox, oy``.

    Example:
        >>> m = CentredRadialModel((640, 480))
        >>> params = torch.tensor([[400., 400., 319.5, 239.5, -0.3, 0., 0., 0., 0.]], dtype=torch.float64)
        >>> uv, J, Jx = m.project(torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64), params)
        >>> uv[0, 0].tolist(), J.shape
        ([319.5, 239.5], torch.Size([1, 1, 2, 9]))
    """

    name = "centred_radial"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "ox", "oy")

    def __init__(self, image_size: tuple[int, int], free_centre: bool = False) -> None:
        if len(image_size) != 2 or min(int(image_size[0]), int(image_size[1])) <= 0:
            raise ValueError(f"image_size must be (W, H) with positive entries, got {image_size!r}.")
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.free_centre = bool(free_centre)

    def default_free(self) -> list[bool]:
        """``fx, fy, cx, cy, k1, k2, k3`` always; ``ox, oy`` with ``free_centre``."""
        return [True] * 7 + [self.free_centre] * 2

    def params_from(self, K: torch.Tensor, radial: torch.Tensor, offset: torch.Tensor | None = None) -> torch.Tensor:
        """Params :math:`(C, 9)` from ``K`` :math:`(C, 3, 3)`, ``radial`` :math:`(C, 3)` and an offset :math:`(C, 2)`."""
        intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
        offset = K.new_zeros(K.shape[0], 2) if offset is None else offset.to(K.dtype)
        return torch.cat([intr, radial.to(K.dtype), offset], -1)

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """See :meth:`CameraModel.columns`."""
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        w, h = self.image_size
        inv_s2 = 1.0 / float(max(w, h)) ** 2
        X, Y, Z = points.unbind(-1)
        inv_z = 1.0 / Z
        x, y = X * inv_z, Y * inv_z
        fx, fy, cx, cy = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
        k1, k2, k3 = p[..., 4], p[..., 5], p[..., 6]
        ccx, ccy = (w - 1) / 2.0 + p[..., 7], (h - 1) / 2.0 + p[..., 8]
        dx, dy = fx * x + cx - ccx, fy * y + cy - ccy
        r2 = (dx * dx + dy * dy) * inv_s2
        f = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        uv = torch.stack([ccx + dx * f, ccy + dy * f], -1)
        if not jacobians:
            return uv, None, None, None, None

        # M = d p_d / d (p - c) = f I + (2 f' / S^2) d d^T
        fp = 2 * (k1 + r2 * (2 * k2 + 3 * k3 * r2)) * inv_s2
        m00, m01, m11 = f + fp * dx * dx, fp * dx * dy, f + fp * dy * dy
        ju = [m00 * x, m01 * y, m00, m01, dx * r2, dx * r2 * r2, dx * r2 * r2 * r2, 1 - m00, -m01]
        jv = [m01 * x, m11 * y, m01, m11, dy * r2, dy * r2 * r2, dy * r2 * r2 * r2, -m01, 1 - m11]
        # d p / d Xc = diag(fx, fy) [[1, 0, -x], [0, 1, -y]] / z
        ax, ay = fx * inv_z, fy * inv_z
        xu = [m00 * ax, m01 * ay, -(m00 * ax * x + m01 * ay * y)]
        return uv, ju, jv, xu, [m01 * ax, m11 * ay, -(m01 * ax * x + m11 * ay * y)]
