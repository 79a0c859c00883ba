"""Image-level RANSAC over views (the paper's "simplified RANSAC"), batched over hypotheses and cameras.

1. Draw random view subsets; every hypothesis of every camera is one batch element of Zhang's closed form.
2. For each hypothesis, recover every view's pose from its homography and that K, and measure the view's
   RMS reprojection error (pinhole only: distortion is not modelled yet).
3. A view is an inlier when its RMS is below ``max(abs_threshold, rel_threshold * m)`` where ``m`` is the
   smallest (over hypotheses) median view RMS of the camera: un-modelled distortion inflates every view's
   error, so a fixed pixel threshold would either reject everything on a wide lens or nothing on a good one,
   while a median taken from each hypothesis alone would let a bad hypothesis loosen its own threshold.
4. The best hypothesis has the most inliers, then the lowest mean inlier RMS; K is refitted on its inliers.

Hypothesis 0 always uses all views, so an outlier-free set is never worse off than plain Zhang. It is tried
first: when every candidate view fits it within ``abs_threshold`` (the floor of the threshold), all views are
inliers of it, no hypothesis can have more, and the random ones are skipped (same inliers, same K).
"""

from __future__ import annotations

import torch
from torch import nn

from ccs_kornia.modules.calibration.zhang import zhang_intrinsics
from ccs_kornia.runtime.checks import broadcast_shapes, check_shape, check_tensor

__all__ = ["hypothesis_view_rms", "image_ransac", "ImageRansac"]


def hypothesis_view_rms(
    K: torch.Tensor, H: torch.Tensor, object_xy: torch.Tensor, corners: torch.Tensor, valid: torch.Tensor
) -> torch.Tensor:
    r"""RMS reprojection error of every view under every candidate camera (pinhole, pose from H).

    Args:
        K: :math:`(C, S, 3, 3)` candidate camera matrices.
        H: :math:`(C, V, 3, 3)` board-to-image homographies.
        object_xy: :math:`(C, N, 2)` board coordinates.
        corners: :math:`(C, V, N, 2)` observed pixels (zeros where invalid).
        valid: :math:`(C, V, N)` bool.

    Returns:
        :math:`(C, S, V)` RMS in px (``inf`` where a view has no valid corner or the pose is degenerate).
    """
    # pose from K^-1 H; scoring only needs the first two rotation columns, orthonormalised symmetrically
    # (bisector construction: as good as the SVD's nearest rotation here, and cheaper for C*S*V poses:
    # docs/measurements.md)
    shape = broadcast_shapes(K[:, :, None].shape, H[:, None].shape)
    A = torch.linalg.solve(K[:, :, None].expand(shape), H[:, None].expand(shape))
    a1, a2, a3 = A[..., :, 0], A[..., :, 1], A[..., :, 2]
    lam = 2.0 / (a1.norm(dim=-1) + a2.norm(dim=-1)).clamp_min(1e-300)
    lam = lam * torch.where(a3[..., 2] < 0, -1.0, 1.0)
    c = torch.nn.functional.normalize(a1 + a2, dim=-1)
    d = torch.nn.functional.normalize(a1 - a2, dim=-1)
    r1, r2 = (c + d) * 0.5**0.5, (c - d) * 0.5**0.5
    M = K[:, :, None] @ torch.stack([r1, r2, a3 * lam[..., None]], -1)  # planar projection matrix
    # Scoring only needs ~1e-3 px: float32 halves the memory traffic of this (C, S, V, N) pass. Points are
    # taken relative to the homography's image of the board origin so float32 keeps its precision.
    shift = M[..., :2, 2:3] / M[..., 2:3, 2:3]  # (C, S, V, 2, 1)
    M = torch.cat([M[..., :2, :] - shift * M[..., 2:3, :], M[..., 2:3, :]], -2)
    M = M / M[..., 2:3, 2:3]
    corners = corners[:, None] - shift.squeeze(-1)[..., None, :]  # (C, S, V, N, 2)
    M, corners = M.float(), corners.float()
    xy1 = torch.cat([object_xy, torch.ones_like(object_xy[..., :1])], -1).float()  # (C, N, 3)
    p = torch.einsum("csvij,cnj->csvni", M, xy1)
    uv = p[..., :2] / p[..., 2:]
    sq = (uv - corners).pow(2).sum(-1)
    wf = valid[:, None].to(sq.dtype)
    sq = torch.where(valid[:, None], sq, torch.zeros((), dtype=sq.dtype, device=sq.device))
    n = wf.sum(-1)
    out = (sq.sum(-1) / n.clamp_min(1)).sqrt().to(K.dtype)
    return torch.where((n > 0) & out.isfinite(), out, torch.full_like(out, float("inf")))


def image_ransac(
    H: torch.Tensor,
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    view_mask: torch.Tensor | None = None,
    image_size: tuple[int, int] | None = None,
    num_hypotheses: int = 32,
    sample_size: int = 4,
    abs_threshold: float = 3.0,
    rel_threshold: float = 5.0,
    min_views: int = 3,
    generator: torch.Generator | None = None,
    return_details: bool = False,
    early_accept: bool = True,
):
    r"""Image-level RANSAC; see the module docstring.

    Args:
        H: :math:`(C, V, 3, 3)` homographies (board plane to pixels).
        corners: :math:`(C, V, N, 2)` pixels.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)`, :math:`(C, N, 3)` (planar, z = 0) or their :math:`(…, 2)` x, y.
        view_mask: :math:`(C, V)` candidate views (default: views with >= 4 corners).
        image_size: ``(W, H)``, used by Zhang's normalisation and principal-point fall-back.
        num_hypotheses: hypotheses per camera (including the all-views one).
        sample_size: views per random subset (>= 2; zero skew makes 2 views the minimum).
        abs_threshold: inlier threshold floor in px.
        rel_threshold: inlier threshold as a multiple of the best median view RMS.
        min_views: a camera with fewer candidate views skips RANSAC (all candidates are inliers).
        generator: torch.Generator for the subsets (CPU); default seed 0. The same subsets of view indices serve
            every camera: a camera's result does not depend on the others in the batch.
        return_details: also return a dict with ``view_rms`` (C, V) under the final K and ``threshold`` (C,).
        early_accept: first try the all-views hypothesis alone; when every candidate view of every camera fits
            it within ``abs_threshold``, return it (the same inliers and camera the random hypotheses would give,
            without them).

    Returns:
        inliers :math:`(C, V)` bool and K :math:`(C, 3, 3)` refitted on the inliers (no C dim for unbatched
        :math:`(V, 3, 3)` / :math:`(V, N, 2)` input).
    """
    if H.dim() == 3 and corners.dim() == 3:  # unbatched: one camera
        out = image_ransac(
            H[None], corners[None], valid[None], object_points, None if view_mask is None else view_mask[None],
            image_size, num_hypotheses, sample_size, abs_threshold, rel_threshold, min_views, generator,
            return_details, early_accept,
        )
        squeezed = [out[0][0], out[1][0]]
        if return_details:
            squeezed.append({k: v[0] for k, v in out[2].items()})
        return tuple(squeezed)
    check_shape(H, ["C", "V", "3", "3"], "H must be (C, V, 3, 3) or (V, 3, 3)")
    C, V = H.shape[:2]
    check_tensor(corners, "corners", [C, V, "N", 2])
    N = corners.shape[2]
    check_tensor(valid, "valid", [C, V, N])
    if sample_size < 2:
        raise ValueError(f"sample_size must be >= 2, got {sample_size}.")
    if num_hypotheses < 1:
        raise ValueError(f"num_hypotheses must be >= 1, got {num_hypotheses}.")
    device = H.device
    dtype = H.dtype if H.dtype in (torch.float32, torch.float64) else torch.float64
    H = H.to(dtype)
    obj_xy = object_points[..., :2].to(dtype)
    obj_xy = obj_xy.expand(C, N, 2) if obj_xy.dim() == 2 else obj_xy
    valid = valid.bool() & corners.isfinite().all(-1)
    obs = torch.where(valid[..., None], corners.to(dtype), torch.zeros((), dtype=dtype, device=device))
    if view_mask is None:
        view_mask = valid.sum(-1) >= 4
    view_mask = view_mask.bool() & H.flatten(-2).isfinite().all(-1)
    n_views = view_mask.sum(-1)
    S = num_hypotheses

    if early_accept and not return_details:
        # every candidate view fits the all-views hypothesis within the absolute floor of the threshold: it is a
        # consensus of all candidates, so the random hypotheses could only return the same inliers and camera
        K_all = zhang_intrinsics(H, view_mask, image_size)
        rms_all = hypothesis_view_rms(K_all[:, None], H, obj_xy, obs, valid)[:, 0]
        easy = ((rms_all <= abs_threshold) | ~view_mask).all(-1) | (n_views < min_views)
        if bool(easy.all()):
            return view_mask, K_all

    # random subsets: the k smallest of per-view random keys among the candidate views. The keys are drawn view by
    # view (key[s, v] is draw v * S + s of the stream) and shared by the cameras, so a camera's subsets depend on its
    # own views only, not on the other cameras of the batch or on how many views the batch is padded to
    if generator is None:
        generator = torch.Generator().manual_seed(0)
    keys = torch.rand(V, S, generator=generator, dtype=torch.float64).T.to(device).expand(C, S, V)
    keys = torch.where(view_mask[:, None], keys, torch.full_like(keys, 2.0))
    k = min(sample_size, V)
    idx = keys.topk(k, dim=-1, largest=False).indices
    sample = torch.zeros(C, S, V, dtype=torch.bool, device=device).scatter_(-1, idx, True)
    sample = sample & view_mask[:, None]
    sample[:, 0] = view_mask  # hypothesis 0: all views

    K_hyp = zhang_intrinsics(
        H[:, None].expand(C, S, V, 3, 3).reshape(C * S, V, 3, 3), sample.reshape(C * S, V), image_size
    ).reshape(C, S, 3, 3)

    # per-view RMS of every hypothesis, in chunks of hypotheses to bound memory
    chunk = max(1, int(4_000_000 // max(1, C * V * N)))
    rms = torch.cat(
        [hypothesis_view_rms(K_hyp[:, s : s + chunk], H, obj_xy, obs, valid) for s in range(0, S, chunk)], 1
    )  # (C, S, V)
    rms = torch.where(view_mask[:, None], rms, torch.full_like(rms, float("inf")))

    # adaptive threshold from the best-fitting hypothesis' median view error
    med = rms.masked_fill(~view_mask[:, None], float("nan")).nanmedian(-1).values  # (C, S)
    med = torch.where(med.isfinite(), med, torch.full_like(med, float("inf")))
    best_med = med.amin(-1)
    thr = torch.clamp(rel_threshold * best_med, min=abs_threshold)
    inl = (rms <= thr[:, None, None]) & view_mask[:, None]
    count = inl.sum(-1)
    mean_in = torch.where(inl, rms, torch.zeros_like(rms)).sum(-1) / count.clamp_min(1)
    score = count.to(dtype) - 0.5 * (mean_in / thr[:, None]).clamp(0, 1)
    best = score.argmax(-1)
    inliers = inl[torch.arange(C, device=device), best]

    fallback = (n_views < min_views) | (inliers.sum(-1) < min(min_views, 3))
    inliers = torch.where(fallback[:, None], view_mask, inliers)
    K = zhang_intrinsics(H, inliers, image_size)
    if not return_details:
        return inliers, K
    final_rms = hypothesis_view_rms(K[:, None], H, obj_xy, obs, valid)[:, 0]
    final_rms = torch.where(view_mask, final_rms, torch.full_like(final_rms, float("nan")))
    return inliers, K, {"view_rms": final_rms, "threshold": thr, "best_hypothesis": best}


class ImageRansac(nn.Module):
    r"""Image-level RANSAC module (seeded); see :func:`image_ransac`.

    Args:
        num_hypotheses: hypotheses per camera.
        sample_size: views per subset.
        abs_threshold: inlier threshold floor (px).
        rel_threshold: multiple of the best median view RMS.
        min_views: cameras with fewer candidate views skip RANSAC.
        seed: seed of the subset generator (each forward restarts from it: deterministic).

    Shape:
        H :math:`(C, V, 3, 3)`, corners :math:`(C, V, N, 2)`, valid :math:`(C, V, N)`, object_points
        :math:`(N, 3)` -> inliers :math:`(C, V)`, K :math:`(C, 3, 3)`.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> from ccs_kornia.modules.calibration.homography import find_homographies
        >>> obj = board_object_points(5, 4, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[600., 0, 320], [0, 600, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rvec = 0.3 * torch.randn(6, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        >>> tvec = torch.tensor([-0.2, -0.15, 1.2], dtype=torch.float64).expand(6, 3)
        >>> uv = project_points(obj.expand(6, -1, -1), K.expand(6, 3, 3), None, rvec, tvec)[None]
        >>> valid = torch.ones(1, 6, 20, dtype=torch.bool)
        >>> H = find_homographies(obj[:, :2], uv, valid)
        >>> inliers, K_est = ImageRansac()(H, uv, valid, obj, image_size=(640, 480))
        >>> inliers.all().item()
        True
    """

    def __init__(
        self,
        num_hypotheses: int = 32,
        sample_size: int = 4,
        abs_threshold: float = 3.0,
        rel_threshold: float = 5.0,
        min_views: int = 3,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.num_hypotheses = num_hypotheses
        self.sample_size = sample_size
        self.abs_threshold = abs_threshold
        self.rel_threshold = rel_threshold
        self.min_views = min_views
        self.seed = seed

    def forward(
        self,
        H: torch.Tensor,
        corners: torch.Tensor,
        valid: torch.Tensor,
        object_points: torch.Tensor,
        view_mask: torch.Tensor | None = None,
        image_size: tuple[int, int] | None = None,
        return_details: bool = False,
    ):
        gen = torch.Generator().manual_seed(self.seed)
        return image_ransac(
            H, corners, valid, object_points, view_mask, image_size, self.num_hypotheses, self.sample_size,
            self.abs_threshold, self.rel_threshold, self.min_views, gen, return_details,
        )
