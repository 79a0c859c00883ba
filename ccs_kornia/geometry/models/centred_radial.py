"""The paper's radial distortion about a free centre, applied to the pinhole projection (analytic derivatives).

``p = (fx x + cx, fy y + cy)`` is the pinhole pixel, ``c = ((W-1)/2 + ox, (H-1)/2 + oy)`` the distortion centre
(the image centre shifted by ``(ox, oy)`` px), ``r = |p - c| / max(W, H)`` and
``p_d = c + (p - c) (1 + k1 r^2 + k2 r^4 + k3 r^6)``, as
:func:`ccs_kornia.modules.calibration.centred_radial.centred_radial_distort`. Parameters are
``fx, fy, cx, cy, k1, k2, k3, ox, oy``; by default the centre offset is fixed (``default_free``).
"""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.models.base import (
    CameraModel,
    broadcast_params,
    check_projection_inputs,
    unit_columns,
)

__all__ = ["MONOTONIC_SAMPLES", "CentredRadialModel"]

#: radii sampled by :meth:`CentredRadialModel.monotonic_radius` up to the widest angle asked for
MONOTONIC_SAMPLES = 4096


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

    def _key(self) -> tuple:
        return (self.name, self.image_size, self.free_centre)

    def default_free(self) -> list[bool]:
        """``fx, fy, cx, cy, k1, k2, k3`` always; ``ox, oy`` with ``free_centre``."""
        return [True] * 7 + [self.free_centre] * 2

    def params_from(self, K: torch.Tensor, radial: torch.Tensor, offset: torch.Tensor | None = None) -> torch.Tensor:
        """Params :math:`(C, 9)` from ``K`` :math:`(C, 3, 3)`, ``radial`` :math:`(C, 3)` and an offset :math:`(C, 2)`."""
        intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
        offset = K.new_zeros(K.shape[0], 2) if offset is None else offset.to(K.dtype)
        return torch.cat([intr, radial.to(K.dtype), offset], -1)

    def monotonic_radius(self, params: torch.Tensor, max_angle: float) -> torch.Tensor:
        r"""Where ``rho (1 + k1 rho^2 + k2 rho^4 + k3 rho^6)`` stops increasing, as a radius on the normalized plane, at
        most ``tan(max_angle)``.

        ``rho = r max(fx, fy) / max(W, H)`` is the normalized radius ``r`` in the model's pixel units along the
        longer focal length (the first direction to turn); the centre offset is small and left out. The slope
        ``1 + 3 k1 rho^2 + 5 k2 rho^4 + 7 k3 rho^6`` is sampled at :data:`MONOTONIC_SAMPLES` radii; the answer is the
        last sample before it first stops being positive. See :meth:`CameraModel.monotonic_radius`.

        Example:
            >>> import math
            >>> m = CentredRadialModel((640, 480))
            >>> params = torch.tensor([[640., 640., 319.5, 239.5, -0.3, 0., 0., 0., 0.]], dtype=torch.float64)
            >>> round(m.monotonic_radius(params, math.radians(80)).item(), 3)  # 1 - 0.9 rho^2 = 0: 1 / sqrt(0.9)
            1.054
        """
        r = torch.linspace(0.0, math.tan(max_angle), MONOTONIC_SAMPLES + 1, dtype=params.dtype,
                           device=params.device)[None]
        rho2 = (r * params[:, 0:2].amax(-1, keepdim=True) / float(max(self.image_size))) ** 2
        k1, k2, k3 = (params[:, 4 + i, None] for i in range(3))
        slope = 1 + rho2 * (3 * k1 + rho2 * (5 * k2 + rho2 * 7 * k3))
        index = torch.arange(MONOTONIC_SAMPLES + 1, device=params.device)
        first_bad = torch.where(slope <= 0, index, MONOTONIC_SAMPLES + 1).amin(-1)  # the top where it never stops
        return r[0, (first_bad - 1).clamp(min=0)]

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """See :meth:`CameraModel.columns`."""
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        w, h = self.image_size
        inv_s2 = 1.0 / float(max(w, h)) ** 2
        inv_z = 1.0 / points[..., 2:3]
        xy = points[..., :2] * inv_z
        f, c = p[..., 0:2], p[..., 2:4]
        k1, k2, k3 = p[..., 4:5], p[..., 5:6], p[..., 6:7]
        centre = p[..., 7:9] + torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], dtype=p.dtype, device=p.device)
        d = f * xy + c - centre  # pinhole pixel relative to the distortion centre
        r2 = (d * d).sum(-1, keepdim=True) * inv_s2
        fr = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        uv = centre + d * fr
        if not jacobians:
            return uv, None, None

        # M = d p_d / d (p - c) = fr I + (2 fr' / S^2) d d^T, by columns m0 = (m00, m01), m1 = (m01, m11)
        ex, ey = unit_columns(uv)
        fpd = (2 * inv_s2) * (k1 + r2 * (2 * k2 + 3 * k3 * r2)) * d
        m0, m1 = fpd * d[..., 0:1] + fr * ex, fpd * d[..., 1:2] + fr * ey
        x, y = xy[..., 0:1], xy[..., 1:2]
        dr = d * r2
        dp = [m0 * x, m1 * y, m0, m1, dr, dr * r2, dr * r2 * r2, ex - m0, ey - m1]
        # d p / d Xc = diag(fx, fy) [[1, 0, -x], [0, 1, -y]] / z
        dx, dy = m0 * (p[..., 0:1] * inv_z), m1 * (p[..., 1:2] * inv_z)
        return uv, dp, [dx, dy, -(dx * x + dy * y)]
