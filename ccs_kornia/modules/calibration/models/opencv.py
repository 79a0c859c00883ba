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
        """See :meth:`CameraModel.columns` (terms of coefficients outside the variant are skipped, not zeroed)."""
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        X, Y, Z = points.unbind(-1)
        inv_z = 1.0 / Z
        x, y = X * inv_z, Y * inv_z
        fx, fy, cx, cy = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
        k = dict(zip(self.coeff_index, p[..., 4:].unbind(-1)))
        radial, tangential, k3on, rational = 0 in k, 2 in k, 4 in k, 5 in k
        xx, yy, xy = x * x, y * y, x * y
        r2 = xx + yy
        rad, drad, inv_b = 1.0, 0.0, None
        if radial:
            if k3on:
                rad = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
                drad = k[0] + r2 * (2 * k[1] + 3 * k[4] * r2)
            else:
                rad = 1 + r2 * (k[0] + r2 * k[1])
                drad = k[0] + 2 * k[1] * r2
            if rational:
                inv_b = 1.0 / (1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7])))
                rad = rad * inv_b
                drad = (drad - rad * (k[5] + r2 * (2 * k[6] + 3 * k[7] * r2))) * inv_b
        xd, yd = (x * rad, y * rad) if radial else (x, y)
        if tangential:
            xy2 = 2 * xy
            xd = xd + k[2] * xy2 + k[3] * (r2 + 2 * xx)
            yd = yd + k[2] * (r2 + 2 * yy) + k[3] * xy2
        uv = torch.stack([fx * xd + cx, fy * yd + cy], -1)
        if not jacobians:
            return uv, None, None, None, None

        zeros, ones = torch.zeros((), dtype=x.dtype, device=x.device), torch.ones((), dtype=x.dtype, device=x.device)
        ju, jv = [xd, zeros, ones, zeros], [zeros, yd, zeros, ones]
        cu, cv = {}, {}
        if radial:
            xs, ys = (x, y) if inv_b is None else (x * inv_b, y * inv_b)
            cu[0], cv[0] = fx * xs * r2, fy * ys * r2
            cu[1], cv[1] = cu[0] * r2, cv[0] * r2
            if k3on:
                cu[4], cv[4] = cu[1] * r2, cv[1] * r2
            if rational:
                cu[5], cv[5] = -cu[0] * rad, -cv[0] * rad
                cu[6], cv[6] = cu[5] * r2, cv[5] * r2
                cu[7], cv[7] = cu[6] * r2, cv[6] * r2
        if tangential:
            cu[2], cv[2] = fx * xy2, fy * (r2 + 2 * yy)
            cu[3], cv[3] = fx * (r2 + 2 * xx), fy * xy2
        ju += [cu[i] for i in self.coeff_index]
        jv += [cv[i] for i in self.coeff_index]

        # d uv / d Xc = diag(fx, fy) d(xd, yd)/d(x, y) d(x, y)/d Xc
        fxz, fyz = fx * inv_z, fy * inv_z
        if radial:
            a00, a01, a11 = rad + 2 * xx * drad, 2 * xy * drad, rad + 2 * yy * drad
        else:
            a00, a01, a11 = ones, zeros, ones
        if tangential:
            a00 = a00 + 2 * k[2] * y + 6 * k[3] * x
            a01 = a01 + 2 * k[2] * x + 2 * k[3] * y
            a11 = a11 + 6 * k[2] * y + 2 * k[3] * x
        gx0, gx1, gy0, gy1 = fxz * a00, fxz * a01, fyz * a01, fyz * a11
        return uv, ju, jv, [gx0, gx1, -(gx0 * x + gx1 * y)], [gy0, gy1, -(gy0 * x + gy1 * y)]
