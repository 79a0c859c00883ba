r"""Corner candidates from the image's own saddle points: the learned detector's second source.

The heatmap network misses corners it was not trained to see, above all the X-junctions beside the marks of ChArUco
and ECoCheck boards (bench section 6: it finds 13-28 of a 40-corner board's corners on 1280x960 ChArUco renders).
A Hessian saddle detector at a scale comparable to the squares does not care what lies inside the white squares:
smoothed at :math:`\sigma \approx 0.28 s`, a white square with a mark reads as a lighter grey, and the junction of two
dark and two lighter squares is still a saddle. On the detector's level (squares of about ``target_square`` px) the
scale is fixed: :data:`SIGMA_PER_SQUARE` x the level's square.

The strength is the scale-normalised saddle measure of :func:`~ccs_kornia.modules.detection.scale.saddle_scale_response`,
:math:`\sigma^2 \sqrt{\max(0, f_{xy}^2 - f_{xx} f_{yy})} - 2 \sigma |\nabla f|` (the gradient term rejects the L- and
T-junctions of clutter), its local maxima (``nms`` px) above ``relative`` x the mean of the ``reference`` strongest
are the candidates. They are whole pixels of the level: the detector's refinement takes them from there.

Measured on the held-out ChArUco / ECoCheck renders of the earlier sessions (squares 34-70 px, level squares ~12 px):
39-40 of 40 true corners within a quarter square, 1-13 other candidates.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d

__all__ = ["SIGMA_PER_SQUARE", "saddle_candidates"]

#: smoothing scale of the candidate detector per square side (0.5-0.75 of the response's peak scale 0.37 s: the
#: marks are averaged away while the neighbouring junctions stay apart)
SIGMA_PER_SQUARE = 0.28


def saddle_candidates(
    images: torch.Tensor,
    sigma: float,
    max_points: int = 256,
    nms: int = 5,
    relative: float = 0.25,
    reference: int = 8,
    edge_penalty: float = 2.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""X-junction candidates of grey images, strongest first.

    Args:
        images: :math:`(B, 1, H, W)` grey images.
        sigma: Gaussian smoothing in px (e.g. ``SIGMA_PER_SQUARE`` x the square side in px).
        max_points: most candidates per image.
        nms: side of the non-maximum suppression window (px).
        relative: candidates weaker than this fraction of the mean of the ``reference`` strongest are dropped.
        reference: see ``relative``.
        edge_penalty: weight of the gradient term.

    Returns:
        points :math:`(B, K, 2)` ``(x, y)`` px (whole pixels) and mask :math:`(B, K)` of the real candidates,
        ``K = min(max_points, H * W)``.

    Example:
        >>> img = torch.zeros(1, 1, 48, 48); img[..., :24, :24] = 1; img[..., 24:, 24:] = 1
        >>> pts, ok = saddle_candidates(img, 3.0)
        >>> found = pts[0][ok[0]]  # the one junction, at (23.5, 23.5): a whole pixel next to it
        >>> found.shape, bool(((found - 23.5).abs() <= 0.5).all())
        (torch.Size([1, 2]), True)
    """
    if images.dim() != 4 or images.shape[1] != 1:
        raise ValueError(f"Expected grey images (B, 1, H, W), got {tuple(images.shape)}.")
    if not sigma > 0 or max_points < 1 or nms < 1:
        raise ValueError(f"sigma, max_points and nms must be positive, got {sigma}, {max_points}, {nms}.")
    b, _, h, w = images.shape
    k = 2 * int(round(3 * sigma)) + 1
    # replicate: works on levels smaller than the kernel (reflection needs the image wider than its pad)
    f = gaussian_blur2d(images.float(), (k, k), (sigma, sigma), border_type="replicate")[:, 0]
    c = f[:, 1:-1, 1:-1]
    right, left, down, up = f[:, 1:-1, 2:], f[:, 1:-1, :-2], f[:, 2:, 1:-1], f[:, :-2, 1:-1]
    fxx, fyy = right + left - 2 * c, down + up - 2 * c
    fxy = 0.25 * (f[:, 2:, 2:] - f[:, 2:, :-2] - f[:, :-2, 2:] + f[:, :-2, :-2])
    gx, gy = 0.5 * (right - left), 0.5 * (down - up)
    strength = (fxy * fxy - fxx * fyy).clamp_min(0).sqrt() * sigma**2 - edge_penalty * sigma * (gx * gx + gy * gy).sqrt()
    strength = F.pad(strength, (1, 1, 1, 1))  # back to (B, H, W); the border pixels are never candidates
    peak = (strength == F.max_pool2d(strength[:, None], nms, 1, nms // 2)[:, 0]) & (strength > 0)
    score = torch.where(peak, strength, torch.zeros_like(strength)).flatten(1)
    top = score.topk(min(max_points, score.shape[1]), dim=-1)
    ref = top.values[:, :reference].mean(-1, keepdim=True)
    mask = (top.values > 0) & (top.values > relative * ref)
    points = torch.stack([top.indices % w, top.indices // w], -1).to(images.dtype if images.is_floating_point() else torch.float32)
    return points, mask
