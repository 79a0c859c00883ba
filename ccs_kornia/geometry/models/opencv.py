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

import math

import torch
from kornia.geometry.calibration import undistort_points

from ccs_kornia.geometry.models.base import (
    CameraModel,
    broadcast_params,
    check_projection_inputs,
    unit_columns,
)

__all__ = ["OPENCV_VARIANTS", "OpenCVModel"]

#: indices (in OpenCV's 8-coefficient order) estimated by each variant
OPENCV_VARIANTS: dict[str, tuple[int, ...]] = {
    "none": (),
    "k1k2": (0, 1),
    "opencv5": (0, 1, 2, 3, 4),
    "rational": (0, 1, 2, 3, 4, 5, 6, 7),
}
_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
#: fixed-point steps of kornia's inverse that start :meth:`OpenCVModel.undistort`'s Newton steps
FIXED_POINT_STEPS = 20
#: radii sampled by :meth:`OpenCVModel.monotonic_radius`
MONOTONIC_SAMPLES = 4096


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
        self._coeff_index = OPENCV_VARIANTS[variant]
        self.param_names = ("fx", "fy", "cx", "cy", *(_NAMES[i] for i in self.coeff_index))

    @property
    def coeff_index(self) -> tuple[int, ...]:
        """Indices (in OpenCV's 8-coefficient order) the variant estimates."""
        return self._coeff_index

    @property
    def num_coeffs(self) -> int:
        """Coefficients a calibration stores: none for ``none``, five for ``k1k2`` (``p1 = p2 = k3 = 0``) and
        ``opencv5``, eight for ``rational``."""
        return 0 if not self._coeff_index else (5 if max(self._coeff_index) < 5 else 8)

    @property
    def max_coeffs(self) -> int:
        """Eight (``k1 .. k6`` with the tangential terms)."""
        return 8

    def opencv_length(self, n: int) -> int:
        """Five (OpenCV's default layout) up to five coefficients, eight above (the rational model)."""
        if n > 8:
            raise ValueError(f"OpenCV's polynomial model takes at most 8 coefficients here, got {n}.")
        return 5 if n <= 5 else 8

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

    def undistort_start(self, pixels: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """kornia's fixed-point inverse (``undistort_points``): close to the answer under strong barrel distortion,
        where the pinhole start would leave Newton's method outside the model's monotonic range."""
        K = torch.zeros(*params.shape[:-1], 3, 3, dtype=params.dtype, device=params.device)
        K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2], K[..., 2, 2] = params[..., 0], params[..., 1], \
            params[..., 2], params[..., 3], 1.0
        eye = torch.eye(3, dtype=params.dtype, device=params.device).expand_as(K)
        shape = pixels.shape
        flat = pixels.reshape(shape[0], -1, 2)
        d = self.dist8(params)
        return undistort_points(flat, K, d, eye, num_iters=FIXED_POINT_STEPS).reshape(shape)

    def undistort(self, pixels: torch.Tensor, params: torch.Tensor, jacobians: bool = False):
        """See :meth:`CameraModel.undistort`; the pinhole (``none``) is inverted in closed form."""
        if not self.coeff_index:
            xy = CameraModel.undistort_start(self, pixels, params)
            if not jacobians:
                return xy
            inv_f = broadcast_params(params, pixels)[..., 0:2].reciprocal().expand_as(xy)
            return xy, torch.diag_embed(inv_f)
        return super().undistort(pixels, params, jacobians)

    def monotonic_radius(self, params: torch.Tensor, max_angle: float) -> torch.Tensor:
        r"""Where ``r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)`` stops increasing or its
        denominator reaches zero, as a radius on the normalized plane, at most ``tan(max_angle)``.

        The mapping is sampled at :data:`MONOTONIC_SAMPLES` radii up to ``tan(max_angle)``; the answer is the sample
        two before the first that does not increase (the turning point lies between the samples before and after
        that one). Tangential terms are small and left out. See :meth:`CameraModel.monotonic_radius`.

        Example:
            >>> params = torch.tensor([[500., 500., 320., 240., -0.3, 0., 0., 0., 0.]], dtype=torch.float64)
            >>> round(OpenCVModel("opencv5").monotonic_radius(params, math.radians(80)).item(), 2)  # 1 / sqrt(0.9)
            1.05
        """
        d = self.dist8(params)
        top = math.tan(max_angle)
        r = torch.linspace(0.0, top, MONOTONIC_SAMPLES + 1, dtype=params.dtype, device=params.device)[None]
        r2 = r * r
        num = 1 + r2 * (d[:, 0, None] + r2 * (d[:, 1, None] + r2 * d[:, 4, None]))
        den = 1 + r2 * (d[:, 5, None] + r2 * (d[:, 6, None] + r2 * d[:, 7, None]))
        r_d = r * num / den
        bad = torch.zeros_like(r_d, dtype=torch.bool)
        bad[:, 1:] = (r_d[:, 1:] <= r_d[:, :-1]) | (den[:, 1:] <= 0)
        index = torch.arange(MONOTONIC_SAMPLES + 1, device=params.device)
        first_bad = torch.where(bad, index, MONOTONIC_SAMPLES + 2).amin(-1)  # the top where it never stops
        return r[0, (first_bad - 2).clamp(min=0)]

    def fit_coeffs(
        self, ideal: torch.Tensor, distorted: torch.Tensor, K: torch.Tensor, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Closed-form coefficients of this variant mapping ``ideal`` pixels onto ``distorted`` pixels for a fixed ``K``.

        The model is linear in its coefficients once the ideal normalized points are known (the rational model is
        linearised by multiplying through by its denominator), so this is one batched least-squares solve. It turns a
        measured displacement field (e.g. the distortion network's correction) into this model, to start a refinement.

        Args:
            ideal: :math:`(B, N, 2)` undistorted pixels.
            distorted: :math:`(B, N, 2)` distorted pixels.
            K: :math:`(B, 3, 3)`.
            mask: optional :math:`(B, N)` weights (non-finite points are never used).

        Returns:
            :math:`(B, D)` coefficients in OpenCV's layout (:attr:`num_coeffs`; ``none``: zero columns).

        Example:
            >>> K = torch.tensor([[[500., 0, 320], [0, 500, 240], [0, 0, 1]]], dtype=torch.float64)
            >>> ideal = torch.rand(1, 50, 2, dtype=torch.float64) * 600
            >>> m = OpenCVModel("k1k2")
            >>> distorted = m.distort((ideal - K[:, None, :2, 2]) / 500, m.params_from(K, torch.tensor([[-0.2, 0.05]])))
            >>> m.fit_coeffs(ideal, distorted, K).round(decimals=6).tolist()
            [[-0.2, 0.05, 0.0, 0.0, 0.0]]
        """
        if not self.coeff_index:
            return ideal.new_zeros(ideal.shape[0], 0)
        fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]
        cx, cy = K[:, 0, 2, None], K[:, 1, 2, None]
        x = (ideal[..., 0] - cx) / fx
        y = (ideal[..., 1] - cy) / fy
        xd = (distorted[..., 0] - cx) / fx
        yd = (distorted[..., 1] - cy) / fy
        r2 = x * x + y * y
        # residual rows: xd - x = x*(k1 r2 + k2 r4 + k3 r6) + 2 p1 x y + p2 (r2 + 2x^2)   (rational: times denominator)
        cols_x = [x * r2, x * r2**2, 2 * x * y, r2 + 2 * x * x, x * r2**3]
        cols_y = [y * r2, y * r2**2, r2 + 2 * y * y, 2 * x * y, y * r2**3]
        bx, by = xd - x, yd - y
        if 5 in self.coeff_index:
            cols_x += [-xd * r2, -xd * r2**2, -xd * r2**3]
            cols_y += [-yd * r2, -yd * r2**2, -yd * r2**3]
        elif 2 not in self.coeff_index:
            cols_x, cols_y = cols_x[:2], cols_y[:2]
        A = torch.cat([torch.stack(cols_x, -1), torch.stack(cols_y, -1)], -2)  # (B, 2N, P)
        b = torch.cat([bx, by], -1).unsqueeze(-1)
        # points that are not finite (the hidden corners of a partial board) never count
        use = (ideal.isfinite().all(-1) & distorted.isfinite().all(-1)).to(A.dtype)
        wgt = use if mask is None else use * mask.to(A.dtype)
        wgt = torch.cat([wgt, wgt], -1).unsqueeze(-1)  # one weight per x row and per y row of A
        A, b = (A * wgt).nan_to_num(0.0), (b * wgt).nan_to_num(0.0)
        sol = torch.linalg.lstsq(A, b).solution.squeeze(-1)
        if sol.shape[-1] == 2:
            sol = torch.cat([sol, torch.zeros_like(sol[:, :1]).expand(-1, 3)], -1)
        return sol

    def columns(self, points: torch.Tensor, params: torch.Tensor, jacobians: bool = True) -> tuple:
        """See :meth:`CameraModel.columns` (terms of coefficients outside the variant are skipped, not zeroed).

        (Written with in-place ops on fresh tensors: the LM core calls it once per iteration, and on small
        problems the cost is the number of tensor ops. No fused multiply-adds: their vectorised and scalar paths
        round differently, which would make a camera's result depend on its place in the batch.)
        """
        check_projection_inputs(points, params, self.num_params)
        p = broadcast_params(params, points)
        inv_z = points[..., 2:3].reciprocal()
        xy = points[..., :2] * inv_z  # (C, *, 2) normalised coordinates
        f, c = p[..., 0:2], p[..., 2:4]
        k = {i: p[..., 4 + j : 5 + j] for j, i in enumerate(self.coeff_index)}  # (C, 1.., 1) each
        radial, tangential, k3on, rational = 0 in k, 2 in k, 4 in k, 5 in k
        x, y = xy[..., 0:1], xy[..., 1:2]
        sq = xy * xy
        r2 = sq.sum(-1, keepdim=True)
        drad = inv_b = None
        if radial:
            if k3on:
                rad = (r2 * k[4]).add_(k[1]).mul_(r2).add_(k[0]).mul_(r2).add_(1.0)
                drad = (r2 * (3 * k[4])).add_(2 * k[1]).mul_(r2).add_(k[0])
            else:
                rad = (r2 * k[1]).add_(k[0]).mul_(r2).add_(1.0)
                drad = (r2 * (2 * k[1])).add_(k[0])
            if rational:
                inv_b = (r2 * k[7]).add_(k[6]).mul_(r2).add_(k[5]).mul_(r2).add_(1.0).reciprocal_()
                rad = rad.mul_(inv_b)
                dden = (r2 * (3 * k[7])).add_(2 * k[6]).mul_(r2).add_(k[5])
                drad = drad.sub_(dden.mul_(rad)).mul_(inv_b)
            pd = xy * rad
        else:
            pd = xy.clone()
        if tangential:
            xy2 = (x * y).mul_(2.0)
            r2p = (sq * 2.0).add_(r2)
            t1 = torch.cat([xy2, r2p[..., 1:2]], -1)  # d (xd, yd) / d p1
            t2 = torch.cat([r2p[..., 0:1], xy2], -1)  # d (xd, yd) / d p2
            pd.add_(k[2] * t1).add_(k[3] * t2)
        uv = (pd * f).add_(c)
        if not jacobians:
            return uv, None, None

        ex, ey = unit_columns(uv)
        cols = {}
        if radial:
            cols[0] = (f * (xy if inv_b is None else xy * inv_b)).mul_(r2)
            cols[1] = cols[0] * r2
            if k3on:
                cols[4] = cols[1] * r2
            if rational:
                cols[5] = (cols[0] * rad).neg_()
                cols[6] = cols[5] * r2
                cols[7] = cols[6] * r2
        if tangential:
            cols[2], cols[3] = f * t1, f * t2
        dp = [pd * ex, pd * ey, ex, ey, *(cols[i] for i in self.coeff_index)]

        # d uv / d Xc = diag(fx, fy) d(xd, yd)/d(x, y) d(x, y)/d Xc, with d(xd, yd)/d(x, y) = [[a00, a01], [a01, a11]]
        fz = f * inv_z
        if not (radial or tangential):
            dx, dy = fz * ex, fz * ey
            return uv, dp, [dx, dy, (dx * x).add_(dy * y).neg_()]
        if radial:
            diag = (sq * drad).mul_(2.0).add_(rad)
            off = (xy2 if tangential else (x * y).mul_(2.0)) * drad
        else:
            diag, off = torch.ones_like(xy), torch.zeros_like(x)
        if tangential:
            p1y, p2x = k[2] * y, k[3] * x
            diag.add_(torch.cat([(p2x * 3.0).add_(p1y), (p1y * 3.0).add_(p2x)], -1).mul_(2.0))
            off.add_((k[2] * x).add_(k[3] * y).mul_(2.0))
        dx = fz * torch.cat([diag[..., 0:1], off], -1)
        dy = fz * torch.cat([off, diag[..., 1:2]], -1)
        return uv, dp, [dx, dy, (dx * x).add_(dy * y).neg_()]
