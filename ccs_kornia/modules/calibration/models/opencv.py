"""OpenCV's pinhole camera with its polynomial distortion (``cv2.projectPoints``), analytic derivatives.

Variants (OpenCV coefficient order ``k1, k2, p1, p2, k3, k4, k5, k6``):

* ``none``: pinhole only;
* ``k1k2``: two radial terms;
* ``opencv5``: ``k1, k2, p1, p2, k3`` (OpenCV's default);
* ``rational``: ``k1 .. k6`` with the rational radial factor (``CALIB_RATIONAL_MODEL``).

Parameters are ``fx, fy, cx, cy`` followed by the variant's coefficients (zero skew). The distortion is applied
even when every coefficient is zero, so the derivatives are right at the usual zero start.
"""

from __future__ import annotations

import torch

from ccs_kornia.modules.calibration.models.base import CameraModel, broadcast_params, check_projection_inputs

__all__ = ["OPENCV_VARIANTS", "OpenCVModel"]

#: indices (in OpenCV's 8-coefficient order) estimated by each variant
OPENCV_VARIANTS: dict[str, tuple[int, ...]] = {
    "none": (),
    "k1k2": (0, 1),
    "opencv5": (0, 1, 2, 3, 4),
    "rational": (0, 1, 2, 3, 4, 5, 6, 7),
}
_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


class OpenCVModel(CameraModel):
    r"""Pinhole + OpenCV polynomial distortion, as ``cv2.projectPoints`` (zero skew).

    Args:
        variant: ``none`` | ``k1k2`` | ``opencv5`` | ``rational``.

    Example:
        >>> m = OpenCVModel("opencv5")
        >>> params = torch.tensor([[500., 500., 320., 240., -0.2, 0.05, 0., 0., 0.]], dtype=torch.float64)
        >>> uv, J, Jx = m.project(torch.tensor([[[0.1, 0.0, 1.0]]], dtype=torch.float64), params)
        >>> uv.shape, J.shape, Jx.shape
        (torch.Size([1, 1, 2]), torch.Size([1, 1, 2, 9]), torch.Size([1, 1, 2, 3]))
        >>> round(float(uv[0, 0, 0]), 5)  # 320 + 500 * 0.1 * (1 - 0.2 * 0.01 + 0.05 * 1e-4)
        369.90025
    """

    def __init__(self, variant: str = "opencv5") -> None:
        if variant not in OPENCV_VARIANTS:
            raise ValueError(f"Unknown OpenCV variant {variant!r}; expected one of {sorted(OPENCV_VARIANTS)}.")
        self.name = variant
        self.coeff_index = OPENCV_VARIANTS[variant]
        self.param_names = ("fx", "fy", "cx", "cy", *(_NAMES[i] for i in self.coeff_index))

    def dist8(self, params: torch.Tensor) -> torch.Tensor:
        """The 8 OpenCV coefficients :math:`(C, 8)` from params :math:`(C, P)` (zeros outside the variant)."""
        d = params.new_zeros(params.shape[0], 8)
        if self.coeff_index:
            d[:, list(self.coeff_index)] = params[:, 4:]
        return d

    def params_from(self, K: torch.Tensor, dist: torch.Tensor | None = None) -> torch.Tensor:
        """Params :math:`(C, P)` from ``K`` :math:`(C, 3, 3)` and OpenCV coefficients :math:`(C, D)` (any D <= 8)."""
        intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
        d8 = K.new_zeros(K.shape[0], 8)
        if dist is not None and dist.shape[-1] > 0:
            d = dist.to(K.dtype).expand(K.shape[0], -1)[:, :8]
            d8[:, : d.shape[-1]] = d
        return torch.cat([intr, d8[:, list(self.coeff_index)]], -1)

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """See :meth:`CameraModel.columns`."""
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        X, Y, Z = points.unbind(-1)
        inv_z = 1.0 / Z
        x, y = X * inv_z, Y * inv_z
        fx, fy, cx, cy = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
        d = dict(zip(self.coeff_index, p[..., 4:].unbind(-1)))
        zero = torch.zeros((), dtype=points.dtype, device=points.device)
        k1, k2, p1, p2, k3, k4, k5, k6 = (d.get(i, zero) for i in range(8))
        rational = len(self.coeff_index) > 5
        r2 = x * x + y * y
        r4 = r2 * r2
        r6 = r4 * r2
        a = 1 + k1 * r2 + k2 * r4 + k3 * r6
        inv_b = 1.0 / (1 + k4 * r2 + k5 * r4 + k6 * r6) if rational else torch.ones_like(r2)
        rad = a * inv_b
        xy2 = 2 * x * y
        xd = x * rad + p1 * xy2 + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + p2 * xy2
        uv = torch.stack([fx * xd + cx, fy * yd + cy], -1)
        if not jacobians:
            return uv, None, None, None, None

        zeros, ones = torch.zeros((), dtype=x.dtype, device=x.device), torch.ones((), dtype=x.dtype, device=x.device)
        ju, jv = [xd, zeros, ones, zeros], [zeros, yd, zeros, ones]
        xb, yb = x * inv_b, y * inv_b
        du = [xb * r2, xb * r4, xy2, r2 + 2 * x * x, xb * r6]
        dv = [yb * r2, yb * r4, r2 + 2 * y * y, xy2, yb * r6]
        if rational:
            xab, yab = -xb * rad, -yb * rad
            du += [xab * r2, xab * r4, xab * r6]
            dv += [yab * r2, yab * r4, yab * r6]
        ju += [fx * du[i] for i in self.coeff_index]
        jv += [fy * dv[i] for i in self.coeff_index]

        # d uv / d Xc = diag(fx, fy) d(xd, yd)/d(x, y) d(x, y)/d Xc
        da = k1 + 2 * k2 * r2 + 3 * k3 * r4
        drad = (da - rad * (k4 + 2 * k5 * r2 + 3 * k6 * r4)) * inv_b if rational else da
        cross = xy2 * drad + 2 * p1 * x + 2 * p2 * y
        gx0 = fx * (rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x) * inv_z
        gx1 = fx * cross * inv_z
        gy0 = fy * cross * inv_z
        gy1 = fy * (rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x) * inv_z
        return uv, ju, jv, [gx0, gx1, -(gx0 * x + gx1 * y)], [gy0, gy1, -(gy0 * x + gy1 * y)]
