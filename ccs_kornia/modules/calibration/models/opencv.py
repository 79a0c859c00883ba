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

from ccs_kornia.modules.calibration.models.base import CameraModel, broadcast_params, check_projection_inputs, unit_columns

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
        inv_z = 1.0 / points[..., 2:3]
        xy = points[..., :2] * inv_z  # (C, *, 2) normalised coordinates
        f, c = p[..., 0:2], p[..., 2:4]
        k = {i: p[..., 4 + j : 5 + j] for j, i in enumerate(self.coeff_index)}  # (C, 1.., 1) each
        radial, tangential, k3on, rational = 0 in k, 2 in k, 4 in k, 5 in k
        x, y = xy[..., 0:1], xy[..., 1:2]
        sq = xy * xy
        r2 = sq.sum(-1, keepdim=True)
        pd, drad, inv_b = xy, None, None
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
            pd = xy * rad
        if tangential:
            xy2 = 2 * x * y
            r2p = r2 + 2 * sq
            t1 = torch.cat([xy2, r2p[..., 1:2]], -1)  # d (xd, yd) / d p1
            t2 = torch.cat([r2p[..., 0:1], xy2], -1)  # d (xd, yd) / d p2
            pd = pd + k[2] * t1 + k[3] * t2
        uv = pd * f + c
        if not jacobians:
            return uv, None, None

        ex, ey = unit_columns(uv)
        cols = {}
        if radial:
            cols[0] = f * (xy if inv_b is None else xy * inv_b) * r2
            cols[1] = cols[0] * r2
            if k3on:
                cols[4] = cols[1] * r2
            if rational:
                cols[5] = -cols[0] * rad
                cols[6] = cols[5] * r2
                cols[7] = cols[6] * r2
        if tangential:
            cols[2], cols[3] = f * t1, f * t2
        dp = [pd * ex, pd * ey, ex, ey, *(cols[i] for i in self.coeff_index)]

        # d uv / d Xc = diag(fx, fy) d(xd, yd)/d(x, y) d(x, y)/d Xc, with d(xd, yd)/d(x, y) = [[a00, a01], [a01, a11]]
        fz = f * inv_z
        if not (radial or tangential):
            dx, dy = fz * ex, fz * ey
            return uv, dp, [dx, dy, -(dx * x + dy * y)]
        diag, off = (rad + 2 * sq * drad, (xy2 if tangential else 2 * x * y) * drad) if radial else (1.0, 0.0)
        if tangential:
            p1y, p2x = k[2] * y, k[3] * x
            diag = diag + 2 * torch.cat([p1y + 3 * p2x, 3 * p1y + p2x], -1)
            off = off + 2 * (k[2] * x + k[3] * y)
        dx = fz * torch.cat([diag[..., 0:1], off], -1)
        dy = fz * torch.cat([off, diag[..., 1:2]], -1)
        return uv, dp, [dx, dy, -(dx * x + dy * y)]
