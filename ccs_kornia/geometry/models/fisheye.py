"""Kannala–Brandt fisheye camera (``cv2.fisheye``'s model, k1..k4), analytic derivatives.

``theta = atan2(r, z)`` with ``r = sqrt(X^2 + Y^2)`` (the angle from the optical axis, so points at and beyond
90 degrees project correctly; ``cv2.fisheye.projectPoints`` uses ``atan(r / z)``, identical for ``z > 0``),
``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` and
``u = fx theta_d X / r + cx``, ``v = fy theta_d Y / r + cy`` (zero skew, ``CALIB_FIX_SKEW``). Parameters are
``fx, fy, cx, cy, k1, k2, k3, k4``: ``K`` and ``D`` drop into ``cv2.fisheye`` and kornia's Kannala–Brandt
functions unchanged.
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.models.base import (
    CameraModel,
    broadcast_params,
    check_projection_inputs,
    unit_columns,
)

__all__ = ["KannalaBrandtModel"]

#: below this r / z the closed forms are replaced by their series about the optical axis
_AXIS_EPS = 1e-4
#: Newton steps on the angle from the optical axis when inverting the projection
ANGLE_NEWTON_STEPS = 20
#: angles sampled by :meth:`KannalaBrandtModel.monotonic_radius`
MONOTONIC_SAMPLES = 4096


class KannalaBrandtModel(CameraModel):
    r"""Kannala–Brandt fisheye projection as ``cv2.fisheye.projectPoints`` (zero skew), valid beyond 90 degrees.

    Example:
        >>> m = KannalaBrandtModel()
        >>> params = torch.tensor([[300., 300., 320., 240., 0.01, 0., 0., 0.]], dtype=torch.float64)
        >>> uv, J, Jx = m.project(torch.tensor([[[1.0, 0.0, -0.5]]], dtype=torch.float64), params)
        >>> bool(uv[0, 0, 0] > 320 + 300 * 2.0)  # beyond 90 degrees: theta = atan2(1, -0.5) = 2.03 rad
        True
        >>> J.shape, Jx.shape
        (torch.Size([1, 1, 2, 8]), torch.Size([1, 1, 2, 3]))
    """

    name = "fisheye"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

    @property
    def is_fisheye(self) -> bool:
        """Yes: ``cv2.fisheye``'s model."""
        return True

    def straight(self, params: torch.Tensor) -> torch.Tensor:
        """Never: even without coefficients the equidistant projection bends straight lines."""
        return torch.zeros(params.shape[0], dtype=torch.bool, device=params.device)

    def visible(self, points: torch.Tensor) -> torch.Tensor:
        """Every direction (``theta = atan2(r, z)`` reaches beyond 90 degrees)."""
        return torch.ones_like(points[..., 2], dtype=torch.bool)

    @property
    def coeff_index(self) -> tuple[int, ...]:
        """``k1 .. k4`` in ``cv2.fisheye``'s order."""
        return (0, 1, 2, 3)

    @property
    def num_coeffs(self) -> int:
        """Four (``k1 .. k4``)."""
        return 4

    @property
    def max_coeffs(self) -> int:
        """Four (``k1 .. k4``)."""
        return 4

    def opencv_length(self, n: int) -> int:
        """Four: ``cv2.fisheye`` takes ``k1 .. k4``."""
        if n > 4:
            raise ValueError(f"cv2.fisheye's model takes 4 coefficients, got {n}.")
        return 4

    def params_from(self, K: torch.Tensor, D: torch.Tensor | None = None) -> torch.Tensor:
        """Params :math:`(C, 8)` from ``K`` :math:`(C, 3, 3)` and ``D`` :math:`(C, 4)` (default zeros; fewer columns:
        the missing ones zero)."""
        intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
        D = K.new_zeros(K.shape[0], 4) if D is None else self.opencv_coeffs(D.to(K.dtype)).expand(K.shape[0], 4)
        return torch.cat([intr, D], -1)

    def monotonic_radius(self, params: torch.Tensor, max_angle: float) -> torch.Tensor:
        r"""``tan`` of the angle where ``theta_d(theta) = theta (1 + k1 theta^2 + ... + k4 theta^8)`` stops increasing,
        at most ``tan(max_angle)``.

        The slope ``d theta_d / d theta`` is sampled at :data:`MONOTONIC_SAMPLES` angles up to ``max_angle``; the
        answer is the last sample before it first stops being positive. See :meth:`CameraModel.monotonic_radius`.

        Example:
            >>> import math
            >>> params = torch.tensor([[300., 300., 320., 240., -0.3, 0., 0., 0.]], dtype=torch.float64)
            >>> angle = KannalaBrandtModel().monotonic_radius(params, math.radians(80)).atan()
            >>> round(math.degrees(angle.item()), 1)  # d theta_d / d theta = 1 - 0.9 theta^2: 1 / sqrt(0.9) rad
            60.4
        """
        theta = torch.linspace(0.0, max_angle, MONOTONIC_SAMPLES + 1, dtype=params.dtype, device=params.device)[None]
        t2 = theta * theta
        k1, k2, k3, k4 = (params[:, 4 + i, None] for i in range(4))
        slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        index = torch.arange(MONOTONIC_SAMPLES + 1, device=params.device)
        first_bad = torch.where(slope <= 0, index, MONOTONIC_SAMPLES + 1).amin(-1)  # the top where it never stops
        return torch.tan(theta[0, (first_bad - 1).clamp(min=0)])

    def _angles(self, pixels: torch.Tensor, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pixels to ``(theta, cos(phi), sin(phi))`` by Newton's method on ``theta`` (start: ``theta_d``); the
        direction of the centre pixel itself is arbitrary: ``(1, 0)``."""
        p = broadcast_params(params, pixels)
        ab = (pixels - p[..., 2:4]) / p[..., 0:2]
        a, b = ab[..., 0], ab[..., 1]
        theta_d = (a * a + b * b).sqrt()
        k1, k2, k3, k4 = p[..., 4], p[..., 5], p[..., 6], p[..., 7]
        theta = theta_d
        for _ in range(ANGLE_NEWTON_STEPS):
            t2 = theta * theta
            f = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
            df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - f / torch.where(df.abs() > 1e-12, df, torch.full_like(df, 1e-12))
        off_centre = theta_d > 0
        safe = torch.where(off_centre, theta_d, torch.ones_like(theta_d))
        cos_phi = torch.where(off_centre, a / safe, torch.ones_like(a))
        sin_phi = torch.where(off_centre, b / safe, torch.zeros_like(b))
        return theta, cos_phi, sin_phi

    def undistort(self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False):
        """Pixels to ``tan(theta) (cos(phi), sin(phi))`` (``cv2.fisheye.undistortPoints``), by Newton's method on the
        angle alone; meaningful below 90 degrees (:meth:`unproject` reaches beyond). See
        :meth:`CameraModel.undistort`."""
        theta, ca, sa = self._angles(pixels, params)
        t = theta.tan()
        xy = torch.stack([t * ca, t * sa], -1)
        if not jacobians:
            return xy
        return xy, torch.linalg.inv(self.distort(xy, params, jacobians=True)[1])

    def unproject(self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False):
        """Unit rays ``(sin(theta) cos(phi), sin(theta) sin(phi), cos(theta))``, valid beyond 90 degrees. See
        :meth:`CameraModel.unproject`."""
        theta, ca, sa = self._angles(pixels, params)
        s = theta.sin()
        rays = torch.stack([s * ca, s * sa, theta.cos()], -1)
        return (rays, self.ray_jacobian(rays, params)) if jacobians else rays

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """See :meth:`CameraModel.columns`."""
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        XY, Z = points[..., :2], points[..., 2:3]
        f, c = p[..., 0:2], p[..., 2:4]
        k1, k2, k3, k4 = p[..., 4:5], p[..., 5:6], p[..., 6:7], p[..., 7:8]
        r2 = (XY * XY).sum(-1, keepdim=True)
        r = r2.sqrt()
        theta = torch.atan2(r, Z)
        t2 = theta * theta
        poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        near_axis = (r < _AXIS_EPS * Z.abs()) & (Z > 0)
        r_safe = torch.where(near_axis | (r == 0), torch.ones_like(r), r)
        z_safe = torch.where(near_axis, Z, torch.ones_like(Z))
        inv_z = 1.0 / z_safe
        # theta / r and s = theta_d / r, with their series about the axis
        t_over_r = torch.where(near_axis, inv_z * (1 - r2 * inv_z * inv_z / 3), theta / r_safe)
        s = t_over_r * poly
        fXY = f * XY
        uv = fXY * s + c
        if not jacobians:
            return uv, None, None

        ex, ey = unit_columns(uv)
        sXY = s * XY
        g1 = fXY * (t_over_r * t2)
        t4 = t2 * t2
        dp = [sXY * ex, sXY * ey, ex, ey, g1, g1 * t2, g1 * t4, g1 * t4 * t2]

        dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))  # d theta_d / d theta
        inv_rho2 = 1.0 / (r2 + Z * Z)
        g_far = (dpoly * Z * inv_rho2 - s) / (r_safe * r_safe)
        g = torch.where(near_axis, (2 * k1 - 2.0 / 3.0) * inv_z * inv_z * inv_z, g_far)
        gXY = g * XY  # d s / d (X, Y) = g (X, Y); d s / d Z = -dpoly / rho^2
        dX = f * (s * ex + gXY * XY[..., 0:1])
        dY = f * (s * ey + gXY * XY[..., 1:2])
        return uv, dp, [dX, dY, fXY * (-dpoly * inv_rho2)]
