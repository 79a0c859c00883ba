"""Calibration with the paper's image-centred radial distortion model (joint Levenberg-Marquardt).

The paper models the lens with a radial distortion about the image centre ``c = ((W-1)/2, (H-1)/2)``:
``p_d = c + (p - c) (1 + k1 r^2 + k2 r^4 + k3 r^6)``, ``r = |p - c| / max(W, H)``, applied to the pinhole
projection ``p`` (:func:`ccs_kornia.geometry.radial.radial_distort_points` with ``k0 = 1``, plus a ``k3`` term; a ``k0``
other than 1 is a zoom about the centre, which belongs to the focal length). Its distortion CNN predicts the
inverse of this map; :func:`radial_from_correction` converts such a correction into these coefficients.

:func:`refine_centred_radial` minimises the reprojection error in the observed image over the intrinsics
``fx, fy, cx, cy``, ``k1, k2, k3`` and every view's pose. OpenCV's model centres the distortion on the
principal point instead; where the two centres differ, strong distortion makes OpenCV's fit trade the principal
point and focal length against its distortion terms, which is what calibrating in the corrected frame avoids.

All cameras are solved together by the one LM core (:func:`~ccs_kornia.modules.calibration.lm.levenberg_marquardt`
with :class:`~ccs_kornia.geometry.models.centred_radial.CentredRadialModel`: analytic derivatives,
poses eliminated by a Schur complement, no loop over cameras).
"""

from __future__ import annotations

import torch

from ccs_kornia.geometry.models.centred_radial import CentredRadialModel
from ccs_kornia.modules.calibration.lm import levenberg_marquardt
from ccs_kornia.modules.correction.radial_warp import corrected_radius
from ccs_kornia.runtime.checks import check_points, check_same_shape, check_tensor

__all__ = ["centred_radial_distort", "radial_from_correction", "radial_from_points", "refine_centred_radial"]


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


def radial_from_points(
    ideal: torch.Tensor, distorted: torch.Tensor, image_size: tuple[int, int], mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Least-squares ``(k1, k2, k3)`` (:math:`(B, 3)`) of the image-centred model mapping ``ideal`` onto ``distorted``.

    The model is linear in its coefficients (``p_d - p = (p - c) (k1 r^2 + k2 r^4 + k3 r^6)``, ``r`` of the ideal
    pixel), so this is one batched solve, and it only uses the radii where points were observed. (Converting a
    fitted correction instead, :func:`radial_from_correction`, extrapolates it to the image corner: a strong
    correction that folds beyond the board gives absurd coefficients there.)

    Args:
        ideal, distorted: :math:`(B, N, 2)` pixels.
        image_size: ``(W, H)``.
        mask: optional :math:`(B, N)` bool of the points to use (non-finite points are never used).

    Returns:
        :math:`(B, 3)`; zeros for a batch entry with fewer than 3 usable points.

    Example:
        >>> p = torch.rand(1, 40, 2, dtype=torch.float64) * torch.tensor([64.0, 48.0])
        >>> k = torch.tensor([[-0.3, 0.1, -0.02]], dtype=torch.float64)
        >>> bool(torch.allclose(radial_from_points(p, centred_radial_distort(p, k, (64, 48)), (64, 48)), k))
        True
    """
    check_points(ideal, "ideal")
    check_same_shape(distorted, "distorted", ideal, "ideal")
    if mask is not None:
        check_tensor(mask, "mask", ideal.shape[:2])
    w, h = int(image_size[0]), int(image_size[1])
    dt = torch.float64
    centre = torch.tensor([(w - 1) / 2.0, (h - 1) / 2.0], device=ideal.device, dtype=dt)
    d = ideal.to(dt) - centre
    r2 = (d * d).sum(-1) / float(max(w, h)) ** 2  # (B, N)
    use = torch.isfinite(ideal).all(-1) & torch.isfinite(distorted).all(-1)
    if mask is not None:
        use = use & mask.to(use.device).bool()
    A = (d.unsqueeze(-1) * torch.stack([r2, r2**2, r2**3], -1).unsqueeze(-2)).reshape(d.shape[0], -1, 3)
    b = (distorted.to(dt) - ideal.to(dt)).reshape(d.shape[0], -1)
    wgt = use.to(dt).repeat_interleave(2, -1)
    A, b = (A * wgt.unsqueeze(-1)).nan_to_num(0.0), (b * wgt).nan_to_num(0.0)
    sol = torch.linalg.lstsq(A, b.unsqueeze(-1)).solution.squeeze(-1)
    ok = (use.sum(-1) >= 3)[:, None] & sol.isfinite()
    return torch.where(ok, sol, torch.zeros_like(sol)).to(ideal.dtype)


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
    covariance: bool = False,
) -> tuple[torch.Tensor, ...]:
    """Levenberg-Marquardt over intrinsics, image-centred radial distortion and poses, batched over cameras.

    Args:
        corners: :math:`(C, V, N, 2)` observed (distorted) pixels.
        valid: :math:`(C, V, N)` bool, the corners to use.
        object_points: :math:`(N, 3)` board points.
        K: :math:`(C, 3, 3)` initial intrinsics (zero skew).
        rvec, tvec: :math:`(C, V, 3)` initial poses.
        radial: :math:`(C, 3)` initial ``(k1, k2, k3)``.
        image_size: ``(W, H)``.
        max_iters: accepted LM steps at most (each may need a few damping increases: the core runs up to
            ``10 * max_iters`` iterations).
        tol: relative cost decrease below which a camera stops.
        free_centre: also estimate the distortion centre (a shift from the image centre). Real lenses centre
            their distortion near the principal point, which need not be the image centre; with strong
            distortion the two are told apart by the data.
        covariance: also return the covariance :math:`(C, 9, 9)` of ``fx, fy, cx, cy, k1, k2, k3, ox, oy``
            (marginalised over the poses; zero rows and columns for the centre unless ``free_centre``).

    Returns:
        ``K`` :math:`(C, 3, 3)`, ``radial`` :math:`(C, 3)`, ``rvec``, ``tvec`` :math:`(C, V, 3)`, the RMS
        reprojection error :math:`(C,)` in px (NaN for a camera with fewer than 8 valid corners, whose inputs are
        returned unchanged), the distortion centre's offset from the image centre :math:`(C, 2)` (zeros unless
        ``free_centre``) and the standard deviations of ``fx, fy, cx, cy`` :math:`(C, 4)`; with ``covariance``,
        the covariance last.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
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
    check_tensor(corners, "corners", ["C", "V", "N", "2"])
    c, v, n = corners.shape[:3]
    check_tensor(valid, "valid", [c, v, n])
    check_tensor(radial, "radial", [c, 3])
    dt, dev = torch.float64, corners.device
    cam = CentredRadialModel(image_size, free_centre)
    K0 = K.to(device=dev, dtype=dt)
    params = cam.params_from(K0, radial.to(device=dev, dtype=dt))
    w = (valid.bool() & corners.isfinite().all(-1)).to(dt)
    enough = w.sum((1, 2)) >= 8
    w = w * enough[:, None, None]
    res = levenberg_marquardt(
        cam, params, rvec, tvec, object_points, corners, w, max_iters=10 * max_iters, ftol=tol, dtype=dt
    )
    e1, e2 = enough[:, None], enough[:, None, None]
    p = torch.where(e1, res.params, params)
    nan = torch.full((c,), float("nan"), dtype=dt, device=dev)
    cov = torch.where(e2, res.param_covariance, float("nan"))
    out = (
        torch.where(e2, _k_matrix(p), K0),
        p[:, 4:7],
        torch.where(e2, res.rvec, rvec.to(dt)),
        torch.where(e2, res.tvec, tvec.to(dt)),
        torch.where(enough, res.rms, nan),
        p[:, 7:9] if free_centre else torch.zeros(c, 2, dtype=dt, device=dev),
        cov.diagonal(dim1=-2, dim2=-1)[:, :4].clamp_min(0).sqrt(),
    )
    return (*out, cov) if covariance else out


def _k_matrix(params: torch.Tensor) -> torch.Tensor:
    K = params.new_zeros(params.shape[0], 3, 3)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = params[:, 0], params[:, 1], params[:, 2], params[:, 3], 1
    return K
