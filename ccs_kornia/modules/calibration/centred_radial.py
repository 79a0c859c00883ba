"""Calibration with the paper's image-centred radial distortion model (joint Levenberg-Marquardt).

The paper models the lens with a radial distortion about the image centre ``c = ((W-1)/2, (H-1)/2)``:
``p_d = c + (p - c) (1 + k1 r^2 + k2 r^4 + k3 r^6)``, ``r = |p - c| / max(W, H)``, applied to the pinhole
projection ``p`` (:func:`ccs_kornia.camera.radial_distort_points` with ``k0 = 1``, plus a ``k3`` term; a ``k0``
other than 1 is a zoom about the centre, which belongs to the focal length). Its distortion CNN predicts the
inverse of this map; :func:`radial_from_correction` converts such a correction into these coefficients.

:func:`refine_centred_radial` minimises the reprojection error in the observed image over the intrinsics
``fx, fy, cx, cy``, ``k1, k2, k3`` and every view's pose. OpenCV's model centres the distortion on the
principal point instead; where the two centres differ, strong distortion makes OpenCV's fit trade the principal
point and focal length against its distortion terms, which is what calibrating in the corrected frame avoids.

Cameras are solved one after the other (dense normal equations with ``7 + 6 V`` unknowns each, Jacobian by
forward-mode autodiff).
"""

from __future__ import annotations

import torch
from torch.func import jacfwd

from ccs_kornia import camera
from ccs_kornia.modules.correction.radial_warp import corrected_radius

__all__ = ["centred_radial_distort", "radial_from_correction", "refine_centred_radial"]


def centred_radial_distort(
    points: torch.Tensor, coeffs: torch.Tensor, image_size: tuple[int, int], centre_offset: torch.Tensor | None = None
) -> torch.Tensor:
    """Apply the image-centred radial distortion ``(k1, k2, k3)`` to ideal pixels.

    Args:
        points: :math:`(B, N, 2)` ideal pixels.
        coeffs: :math:`(B, 3)`.
        image_size: ``(W, H)``.
        centre_offset: optional :math:`(B, 2)` shift (px) of the distortion centre from the image centre.

    Returns:
        :math:`(B, N, 2)` distorted pixels.

    Example:
        >>> centred_radial_distort(torch.tensor([[[31.5, 23.5]]]), torch.tensor([[-0.3, 0.0, 0.0]]), (64, 48))
        tensor([[[31.5000, 23.5000]]])
    """
    w, h = int(image_size[0]), int(image_size[1])
    centre = torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], device=points.device, dtype=points.dtype)
    if centre_offset is not None:
        centre = centre + centre_offset[:, None, :]
    d = points - centre
    r2 = (d * d).sum(-1, keepdim=True) / float(max(w, h)) ** 2
    k1, k2, k3 = (coeffs[:, None, i : i + 1] for i in range(3))
    return centre + d * (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))


def radial_from_correction(correction: torch.Tensor, image_size: tuple[int, int], samples: int = 64) -> torch.Tensor:
    """Distortion coefficients ``(k1, k2, k3)`` (:math:`(B, 3)`) best inverting a correction :math:`(B, 5)`.

    Samples distorted radii up to the image corner, corrects them, and fits ``r_d / r_c - 1`` as a polynomial in
    ``r_c^2`` (least squares); the correction's scale at the centre is divided out (a zoom, see module doc).

    Example:
        >>> k = radial_from_correction(torch.tensor([[1.0, 0.0, -0.2, 0.0, 0.0]]), (640, 480))
        >>> bool(k[0, 0] > 0.19)  # a pincushion correction undoes a barrel distortion
        True
    """
    w, h = int(image_size[0]), int(image_size[1])
    r_corner = 0.5 * ((w - 1) ** 2 + (h - 1) ** 2) ** 0.5 / float(max(w, h))
    c = correction.to(torch.float64)
    rd = torch.linspace(r_corner / samples, r_corner, samples, device=c.device, dtype=torch.float64)
    rc = corrected_radius(rd.expand(c.shape[0], -1), c) / c[:, 0:1]  # (B, S), the centre's scale divided out
    ratio = rd / rc.clamp_min(1e-9) - 1.0
    A = torch.stack([rc**2, rc**4, rc**6], -1)
    return torch.linalg.lstsq(A, ratio.unsqueeze(-1)).solution.squeeze(-1).to(correction.dtype)


def _residuals(params: torch.Tensor, observed: torch.Tensor, weight: torch.Tensor, obj: torch.Tensor,
               image_size: tuple[int, int], num_views: int) -> torch.Tensor:
    fx, fy, cx, cy = params[0], params[1], params[2], params[3]
    free_centre = params.shape[0] == 9 + 6 * num_views
    start = 9 if free_centre else 7
    poses = params[start:].reshape(num_views, 6)
    zero, one = torch.zeros_like(fx), torch.ones_like(fx)
    K = torch.stack([torch.stack([fx, zero, cx]), torch.stack([zero, fy, cy]), torch.stack([zero, zero, one])])
    proj = camera.project_points(obj.expand(num_views, -1, -1), K.expand(num_views, 3, 3), None, poses[:, :3], poses[:, 3:])
    offset = params[7:9][None] if free_centre else None
    dist = centred_radial_distort(proj.reshape(1, -1, 2), params[4:7][None], image_size, offset).reshape(proj.shape)
    return ((dist - observed) * weight[..., None]).reshape(-1)


def refine_centred_radial(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    K: torch.Tensor,
    rvec: torch.Tensor,
    tvec: torch.Tensor,
    radial: torch.Tensor,
    image_size: tuple[int, int],
    max_iters: int = 50,
    tol: float = 1e-12,
    free_centre: bool = False,
) -> tuple[torch.Tensor, ...]:
    """Levenberg-Marquardt over intrinsics, image-centred radial distortion and poses, camera by camera.

    Args:
        corners: :math:`(C, V, N, 2)` observed (distorted) pixels.
        valid: :math:`(C, V, N)` bool, the corners to use.
        object_points: :math:`(N, 3)` board points.
        K: :math:`(C, 3, 3)` initial intrinsics (zero skew).
        rvec, tvec: :math:`(C, V, 3)` initial poses.
        radial: :math:`(C, 3)` initial ``(k1, k2, k3)``.
        image_size: ``(W, H)``.
        max_iters: LM iterations at most.
        tol: relative cost decrease below which a camera stops.
        free_centre: also estimate the distortion centre (a shift from the image centre). Real lenses centre
            their distortion near the principal point, which need not be the image centre; with strong
            distortion the two are told apart by the data.

    Returns:
        ``K`` :math:`(C, 3, 3)`, ``radial`` :math:`(C, 3)`, ``rvec``, ``tvec`` :math:`(C, V, 3)`, the RMS
        reprojection error :math:`(C,)` in px (NaN for a camera with fewer than 8 valid corners), the
        distortion centre's offset from the image centre :math:`(C, 2)` (zeros unless ``free_centre``) and the
        standard deviations of ``fx, fy, cx, cy`` :math:`(C, 4)` (from the Gauss-Newton covariance).

    Example:
        >>> from ccs_kornia.camera import board_object_points, project_points
        >>> obj = board_object_points(6, 5, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[[300., 0, 160], [0, 300, 120], [0, 0, 1]]], dtype=torch.float64)
        >>> g = torch.Generator().manual_seed(0)
        >>> rvec = 0.5 * (torch.rand(1, 6, 3, generator=g, dtype=torch.float64) - 0.5)
        >>> tvec = torch.tensor([-0.25, -0.2, 1.2], dtype=torch.float64).expand(1, 6, 3)
        >>> uv = project_points(obj.expand(1, 6, -1, -1), K[:, None].expand(1, 6, 3, 3), None, rvec, tvec)
        >>> k = torch.tensor([[-0.3, 0.05, 0.0]], dtype=torch.float64)
        >>> uv = centred_radial_distort(uv.reshape(1, -1, 2), k, (320, 240)).reshape(1, 6, 30, 2)
        >>> K_start = torch.diag(torch.tensor([1.02, 0.99, 1.0], dtype=torch.float64)) @ K
        >>> valid = torch.ones(1, 6, 30, dtype=torch.bool)
        >>> K1, k1, _, _, rms, _, _ = refine_centred_radial(uv, valid, obj, K_start, rvec, tvec, torch.zeros(1, 3), (320, 240))
        >>> bool((K1 - K).abs().max() < 1e-4), bool((k1 - k).abs().max() < 1e-4), bool(rms < 1e-6)
        (True, True, True)
    """
    if corners.dim() != 4 or corners.shape[-1] != 2:
        raise ValueError(f"corners must be (C, V, N, 2), got {tuple(corners.shape)}.")
    c, v, n = corners.shape[:3]
    if valid.shape != (c, v, n):
        raise ValueError(f"valid must be {(c, v, n)}, got {tuple(valid.shape)}.")
    if radial.shape != (c, 3):
        raise ValueError(f"radial must be {(c, 3)}, got {tuple(radial.shape)}.")
    dt = torch.float64
    obj = object_points.to(corners.device, dt)
    K_out, rad_out = K.to(dt).clone(), radial.to(device=corners.device, dtype=dt).clone()
    rv_out, tv_out = rvec.to(dt).clone(), tvec.to(dt).clone()
    rms_out = torch.full((c,), float("nan"), dtype=dt, device=corners.device)
    centre_out = torch.zeros(c, 2, dtype=dt, device=corners.device)
    std_out = torch.full((c, 4), float("nan"), dtype=dt, device=corners.device)
    for ci in range(c):
        weight = (valid[ci] & corners[ci].isfinite().all(-1)).to(dt)
        if int(weight.sum()) < 8:
            continue
        observed = corners[ci].to(dt).nan_to_num(0.0)
        p = torch.cat([
            torch.stack([K_out[ci, 0, 0], K_out[ci, 1, 1], K_out[ci, 0, 2], K_out[ci, 1, 2]]),
            rad_out[ci],
            torch.zeros(2 if free_centre else 0, dtype=dt, device=corners.device),
            torch.cat([rv_out[ci], tv_out[ci]], -1).reshape(-1),
        ])

        def fun(q: torch.Tensor) -> torch.Tensor:
            return _residuals(q, observed, weight, obj, image_size, v)

        r = fun(p)
        cost = float(r @ r)
        lam = 1e-3
        for _ in range(max_iters):
            J = jacfwd(fun)(p)
            A, g = J.T @ J, J.T @ r
            diag = A.diagonal().clamp_min(1e-12)
            step, r_new, cost_new = None, r, cost
            for _ in range(10):
                trial = torch.linalg.solve(A + lam * torch.diag(diag), -g)
                r_try = fun(p + trial)
                c_try = float(r_try @ r_try)
                if c_try < cost:
                    step, r_new, cost_new = trial, r_try, c_try
                    break
                lam *= 10.0
            if step is None:
                break
            p, r = p + step, r_new
            rel = (cost - cost_new) / max(cost, 1e-300)
            cost = cost_new
            lam = max(lam / 10.0, 1e-12)
            if rel < tol:
                break
        K_out[ci, 0, 0], K_out[ci, 1, 1], K_out[ci, 0, 2], K_out[ci, 1, 2] = p[0], p[1], p[2], p[3]
        rad_out[ci] = p[4:7]
        if free_centre:
            centre_out[ci] = p[7:9]
        poses = p[9 if free_centre else 7 :].reshape(v, 6)
        rv_out[ci], tv_out[ci] = poses[:, :3], poses[:, 3:]
        rms_out[ci] = (cost / weight.sum()) ** 0.5
        # covariance of the estimate: sigma^2 (J^T J)^-1 with sigma^2 from the residual (dof-corrected)
        J = jacfwd(fun)(p)
        dof = max(int(2 * weight.sum()) - p.numel(), 1)
        cov = torch.linalg.pinv(J.T @ J) * (cost / dof)
        std_out[ci] = cov.diagonal()[:4].clamp_min(0).sqrt()
    return K_out, rad_out, rv_out, tv_out, rms_out, centre_out, std_out
