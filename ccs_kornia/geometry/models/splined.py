r"""mrcal's splined stereographic lens model (``LENSMODEL_SPLINED_STEREOGRAPHIC``): a lens model rich enough for any
lens, over 180 degrees included, with analytic derivatives.

A camera-frame point ``p`` goes to its stereographic projection ``u = 2 p_xy / (|p| + p_z)`` (``2 tan(theta / 2)``
along the point's direction: every direction but straight behind the camera); a cubic B-spline surface over ``u``
gives a correction ``delta_u(u)`` (two components), and the pixel is ``q = f (u + delta_u(u)) + c``. The spline's
``Nx x Ny`` control points sit on an even grid of the ``u`` plane whose ``Nx - 3`` middle intervals span the
horizontal field of view ``fov_x_deg``; outside the grid the nearest patch is extended (continuous, not meaningful).

The parameters are mrcal's, in mrcal's order: ``fx, fy, cx, cy`` then per control point, row by row (``y`` outer),
its ``delta_u_x, delta_u_y``; a ``.cameramodel`` file's ``intrinsics`` are this vector unchanged.

Each pixel depends on 16 control points only, so the model gives its derivatives in local form as well
(:meth:`SplinedStereographicModel.local_columns`): the Levenberg–Marquardt core builds its normal equations from them
without a column per control point.
"""

from __future__ import annotations

import math
import re

import torch

from ccs_kornia.geometry.models.base import (
    CameraModel,
    broadcast_params,
    check_projection_inputs,
    solve_2x2,
)

__all__ = ["SPLINE_NAME", "SplinedStereographicModel", "cubic_bspline_weights", "stereographic", "unstereographic"]

#: the start of the model's names (``splined_stereographic_order=3_Nx=30_Ny=20_fov_x_deg=170``)
SPLINE_NAME = "splined_stereographic"
#: the start of mrcal's names of the model
_MRCAL_PREFIX = "LENSMODEL_SPLINED_STEREOGRAPHIC"
#: Newton steps of :meth:`SplinedStereographicModel.unproject` on the stereographic plane
UNPROJECT_NEWTON_STEPS = 12
#: the control points each pixel depends on, per axis (a cubic spline)
SUPPORT = 4


def cubic_bspline_weights(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The uniform cubic B-spline's four weights at ``t`` (in ``[0, 1)`` between the 2nd and 3rd control points) and
    their derivatives, each :math:`(*, 4)`.

    Example:
        >>> w, dw = cubic_bspline_weights(torch.tensor([0.0]))
        >>> (w * 6).tolist(), dw.sum().item()
        ([[1.0, 4.0, 1.0, 0.0]], 0.0)
    """
    t2, t3 = t * t, t * t * t
    w = torch.stack([(1 - t) ** 3 / 6, (3 * t3 - 6 * t2 + 4) / 6, (-3 * t3 + 3 * t2 + 3 * t + 1) / 6, t3 / 6], -1)
    dw = torch.stack([-((1 - t) ** 2) / 2, 1.5 * t2 - 2 * t, -1.5 * t2 + t + 0.5, t2 / 2], -1)
    return w, dw


def stereographic(points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Stereographic projection ``u = 2 p_xy / (|p| + p_z)`` of points :math:`(*, 3)`, and ``d u / d p``
    :math:`(*, 2, 3)`."""
    mag = points.norm(dim=-1, keepdim=True)
    s = 2.0 / (mag + points[..., 2:3])
    u = points[..., :2] * s
    a = -s * s / 2
    b = a / mag
    xy = points[..., :2]
    du = xy.unsqueeze(-1) * (b.unsqueeze(-1) * points.unsqueeze(-2))  # (*, 2, 3): p_i b p_j
    du = du + torch.cat([torch.diag_embed(s.expand(*s.shape[:-1], 2)), xy.unsqueeze(-1) * a.unsqueeze(-1)], -1)
    return u, du


def unstereographic(u: torch.Tensor) -> torch.Tensor:
    """Unit rays :math:`(*, 3)` of stereographic coordinates :math:`(*, 2)` (the inverse of :func:`stereographic`)."""
    r2 = (u * u).sum(-1, keepdim=True)
    return torch.cat([4 * u, 4 - r2], -1) / (4 + r2)


class SplinedStereographicModel(CameraModel):
    r"""mrcal's splined stereographic model (module docstring): a stereographic core and a cubic B-spline correction.

    Args:
        nx, ny: control points across and down the stereographic plane (at least 4 each).
        fov_x_deg: the horizontal field of view the grid spans, in degrees (up to 360).
        order: the spline's order (3: cubic, the one supported).

    Example:
        >>> m = SplinedStereographicModel(6, 5, 120)
        >>> m.num_params, m.mrcal_name
        (64, 'LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=6_Ny=5_fov_x_deg=120')
        >>> params = torch.zeros(1, 64, dtype=torch.float64)
        >>> params[0, :4] = torch.tensor([300., 300., 320., 240.])
        >>> uv = m.project(torch.tensor([[[1.0, 0.0, 0.0]]], dtype=torch.float64), params)[0]
        >>> uv[0, 0].tolist()  # 90 degrees off the axis: u = 2 tan(45 deg) = 2
        [920.0, 240.0]
    """

    def __init__(self, nx: int, ny: int, fov_x_deg: float, order: int = 3) -> None:
        if int(order) != 3:
            raise ValueError(f"Only cubic splines (order=3) are supported, got order={order}.")
        if int(nx) < SUPPORT or int(ny) < SUPPORT:
            raise ValueError(f"A cubic spline needs Nx, Ny >= {SUPPORT}, got Nx={nx} Ny={ny}.")
        if not 0 < float(fov_x_deg) < 360:
            raise ValueError(f"fov_x_deg must be in (0, 360), got {fov_x_deg}.")
        self.order, self.nx, self.ny = 3, int(nx), int(ny)
        self.fov_x_deg = float(fov_x_deg)
        fov = f"{self.fov_x_deg:g}"
        self.name = f"{SPLINE_NAME}_order=3_Nx={self.nx}_Ny={self.ny}_fov_x_deg={fov}"
        self.param_names = ("fx", "fy", "cx", "cy") + tuple(
            f"knot{j}_{i}_{axis}" for j in range(self.ny) for i in range(self.nx) for axis in "xy")
        u_edge = 2 * math.tan(math.radians(self.fov_x_deg) / 4)
        #: control-point intervals per unit of the stereographic plane (mrcal's ``segments_per_u``)
        self.segments_per_u = (self.nx - 3) / (2 * u_edge)

    def _key(self) -> tuple:
        return (SPLINE_NAME, self.nx, self.ny, self.fov_x_deg)

    @property
    def mrcal_name(self) -> str:
        """mrcal's name of the model (a ``.cameramodel`` file's ``lensmodel``)."""
        return f"{_MRCAL_PREFIX}{self.name[len(SPLINE_NAME):]}"

    @classmethod
    def from_name(cls, name: str) -> SplinedStereographicModel:
        """The model a name stands for: this package's (``splined_stereographic_order=3_Nx=..``) or mrcal's
        (``LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=..``)."""
        m = re.fullmatch(r"(?:splined_stereographic|LENSMODEL_SPLINED_STEREOGRAPHIC)_order=(\d+)_Nx=(\d+)_Ny=(\d+)"
                         r"_fov_x_deg=([0-9.]+)", name)
        if m is None:
            raise ValueError(f"Not a splined stereographic model's name: {name!r}.")
        return cls(int(m[2]), int(m[3]), float(m[4]), int(m[1]))

    # -- what it is ------------------------------------------------------------------------------

    @property
    def is_fisheye(self) -> bool:
        """No: not ``cv2.fisheye``'s model (it reaches beyond 90 degrees, see :meth:`visible`)."""
        return False

    @property
    def opencv_family(self) -> str:
        """None of OpenCV's: the files that take OpenCV's coefficients get the nearest OpenCV model instead."""
        return "splined"

    @property
    def local_support(self) -> bool:
        """Yes: each pixel depends on 16 control points (:meth:`local_columns`)."""
        return True

    @property
    def num_local(self) -> int:
        """The control points' values (``2 Nx Ny``, after the core)."""
        return self.num_params - 4

    def straight(self, params: torch.Tensor) -> torch.Tensor:
        """Never: the stereographic projection bends straight lines."""
        return torch.zeros(params.shape[0], dtype=torch.bool, device=params.device)

    def visible(self, points: torch.Tensor) -> torch.Tensor:
        """Every direction but straight behind the camera."""
        return points.norm(dim=-1) + points[..., 2] > 1e-9 * points.norm(dim=-1).clamp_min(1e-300)

    @property
    def coeff_index(self) -> tuple[int, ...]:
        """The control points' values, in order (no OpenCV layout: the stored coefficients are these)."""
        return tuple(range(self.num_params - 4))

    @property
    def num_coeffs(self) -> int:
        """``2 Nx Ny``: the control points' values."""
        return self.num_params - 4

    @property
    def max_coeffs(self) -> int:
        """``2 Nx Ny``."""
        return self.num_coeffs

    def opencv_length(self, n: int) -> int:
        """``2 Nx Ny`` (the model's own layout; OpenCV's functions take none of it)."""
        if n > self.num_coeffs:
            raise ValueError(f"{self.name} has {self.num_coeffs} coefficients, got {n}.")
        return self.num_coeffs

    def params_from(self, K: torch.Tensor, D: torch.Tensor | None = None) -> torch.Tensor:
        """Params :math:`(C, P)` from ``K`` :math:`(C, 3, 3)` and the control points' values :math:`(C, 2 N_x N_y)`
        (default zeros: the plain stereographic projection)."""
        intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
        D = K.new_zeros(K.shape[0], self.num_coeffs) if D is None else self.opencv_coeffs(D.to(K.dtype)).expand(
            K.shape[0], self.num_coeffs)
        return torch.cat([intr, D], -1)

    def default_free(self) -> list[bool]:
        """The control points; the core ``fx, fy, cx, cy`` stays where the start put it (the spline can make any
        change of the core, so both free leave the fit undetermined: mrcal fixes the core too)."""
        return [False] * 4 + [True] * self.num_coeffs

    def monotonic_radius(self, params: torch.Tensor, max_angle: float) -> torch.Tensor:
        """``tan(max_angle)``: the spline bends where it has data, so undistortion relies on the image's own bounds
        (:meth:`CameraModel.monotonic_radius`)."""
        return params.new_full((params.shape[0],), math.tan(max_angle))

    # -- the projection ------------------------------------------------------------------------

    def _patch(self, u: torch.Tensor):
        """Per stereographic point :math:`(C, *, 2)`: the flat index :math:`(C, *, 16)` of the 16 control points it
        depends on, their weights :math:`(C, *, 16)` and the weights' derivatives by ``u_x`` and ``u_y``."""
        gx = u[..., 0] * self.segments_per_u + (self.nx - 1) / 2
        gy = u[..., 1] * self.segments_per_u + (self.ny - 1) / 2
        # a point without a ray (NaN: a view not posed, a point behind the camera) takes a valid patch, its
        # weights and so its projection staying NaN
        ix = gx.detach().nan_to_num(0.0).floor().clamp(1, self.nx - 3)
        iy = gy.detach().nan_to_num(0.0).floor().clamp(1, self.ny - 3)
        wx, dwx = cubic_bspline_weights(gx - ix)
        wy, dwy = cubic_bspline_weights(gy - iy)
        steps = torch.arange(SUPPORT, device=u.device) - 1
        rows = (iy.long().unsqueeze(-1) + steps).unsqueeze(-1)  # (*, 4, 1)
        cols = (ix.long().unsqueeze(-1) + steps).unsqueeze(-2)  # (*, 1, 4)
        index = (rows * self.nx + cols).flatten(-2)
        w = (wy.unsqueeze(-1) * wx.unsqueeze(-2)).flatten(-2)
        dw_dx = (wy.unsqueeze(-1) * dwx.unsqueeze(-2)).flatten(-2) * self.segments_per_u
        dw_dy = (dwy.unsqueeze(-1) * wx.unsqueeze(-2)).flatten(-2) * self.segments_per_u
        return index, w, dw_dx, dw_dy

    def _correction(self, u: torch.Tensor, params: torch.Tensor):
        """``delta_u`` :math:`(C, *, 2)`, its Jacobian by ``u`` :math:`(C, *, 2, 2)` and the patch of :meth:`_patch`."""
        index, w, dw_dx, dw_dy = self._patch(u)
        knots = params[:, 4:].reshape(params.shape[0], self.nx * self.ny, 2)
        flat = index.reshape(index.shape[0], -1, 1).expand(-1, -1, 2)
        ctrl = torch.gather(knots, 1, flat).reshape(*index.shape, 2)  # (C, *, 16, 2)
        delta = (w.unsqueeze(-1) * ctrl).sum(-2)
        ddx = (dw_dx.unsqueeze(-1) * ctrl).sum(-2)  # d delta / d u_x
        ddy = (dw_dy.unsqueeze(-1) * ctrl).sum(-2)
        return delta, torch.stack([ddx, ddy], -1), (index, w)

    def local_columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """Projection and derivatives with the control points' in local form (what the LM core consumes).

        Args:
            points: :math:`(C, *, 3)` camera-frame points.
            params: :math:`(C, P)` parameters.
            jacobians: also return the derivatives.

        Returns:
            ``(uv, d_dcore, index, d_dlocal, d_dX)``: uv :math:`(C, *, 2)`; ``d_dcore`` 4 columns (``fx, fy, cx, cy``)
            each :math:`(C, *, 2)` or broadcastable to it; ``index`` :math:`(C, *, 16)` the control points each point
            depends on, as the place of their ``x`` value (their ``y`` value follows), ``d_dlocal``
            :math:`(C, *, 16, 2)` the derivative of ``u`` by the ``x`` value and of ``v`` by the ``y`` value (the
            others are zero); ``d_dX`` 3 columns by the camera-frame point.
        """
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        f, c = p[..., 0:2], p[..., 2:4]
        u, du_dp = stereographic(points)
        delta, ddelta, (index, w) = self._correction(u, params)
        ud = u + delta
        uv = f * ud + c
        if not jacobians:
            return uv, None, None, None, None
        ex = torch.zeros_like(uv)
        ex[..., 0] = 1
        ey = torch.zeros_like(uv)
        ey[..., 1] = 1
        core = [ud * ex, ud * ey, ex, ey]
        local_index = 4 + 2 * index  # each control point's x value; its y value follows
        d_local = torch.stack([f[..., 0:1] * w, f[..., 1:2] * w], -1)  # d u / d x value, d v / d y value
        # d q / d p = diag(f) (I + d delta / d u) d u / d p
        M = torch.eye(2, dtype=uv.dtype, device=uv.device) + ddelta
        dq = f.unsqueeze(-1) * (M @ du_dp)  # (C, *, 2, 3)
        return uv, core, local_index, d_local, [dq[..., 0], dq[..., 1], dq[..., 2]]

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """See :meth:`CameraModel.columns` (the control points' columns scattered from :meth:`local_columns`)."""
        uv, core, index, d_local, dx = self.local_columns(points, params, jacobians)
        if not jacobians:
            return uv, None, None
        dense = uv.new_zeros(*uv.shape[:-1], self.num_params - 4, 2)
        dense[..., 0].scatter_add_(-1, index - 4, d_local[..., 0])
        dense[..., 1].scatter_add_(-1, index - 3, d_local[..., 1])
        return uv, [*core, *dense.unbind(-2)], dx

    def unproject(self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False):
        """Unit rays of pixels :math:`(C, *, 2)`: Newton's method on the stereographic plane (start: no correction),
        then the inverse stereographic projection (beyond 90 degrees too). See :meth:`CameraModel.unproject`."""
        p = broadcast_params(params, pixels)
        target = (pixels - p[..., 2:4]) / p[..., 0:2]  # u + delta_u(u)
        u = target
        eye = torch.eye(2, dtype=pixels.dtype, device=pixels.device)
        for _ in range(UNPROJECT_NEWTON_STEPS):
            delta, ddelta, _ = self._correction(u, params)
            u = u - solve_2x2(eye + ddelta, u + delta - target).clamp(-1.0, 1.0)
        rays = unstereographic(u)
        return (rays, self.ray_jacobian(rays, params)) if jacobians else rays

    def undistort(self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False):
        """Pixels to the ``z = 1`` plane through :meth:`unproject` (meaningful below 90 degrees). See
        :meth:`CameraModel.undistort`."""
        rays = self.unproject(pixels, params)
        xy = rays[..., :2] / rays[..., 2:3]
        if not jacobians:
            return xy
        return xy, torch.linalg.inv(self.distort(xy, params, jacobians=True)[1])
