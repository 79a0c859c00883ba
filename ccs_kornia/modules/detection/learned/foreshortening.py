r"""Last look for boards seen at a grazing angle: detection on levels compressed along one direction.

A board tilted 60-75 degrees away from the camera shows squares foreshortened 2-4:1. The heatmap network was
trained on nearly square cells and misses many of such corners on every isotropic level (``docs/measurements.md``),
so no pyramid level finds the board. Compressing the image by ``ratio`` along the squares' long side makes them
nearly square again: on the levels of :func:`compress_along` the same network finds them. The direction is not known
in advance; :func:`detect_foreshortened` tries a few in turn on the images still missed, maps the corners back exactly
(a :class:`Compression` warp: one affine map) and lets the caller refine them at full resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch
import torch.nn.functional as F
from kornia.geometry.linalg import transform_points
from kornia.geometry.transform import warp_affine

from ccs_kornia.modules.detection.base import DetectionResult, image_rows
from ccs_kornia.modules.detection.warps.warped_detection import Level, Warp, map_back
from ccs_kornia.runtime.checks import check_board_size, check_grey_images
from ccs_kornia.runtime.timing import stage

__all__ = ["FORESHORTENING_DIRECTIONS", "FORESHORTENING_RATIO", "compress_along", "map_from_level", "Compression",
           "detect_foreshortened"]

#: directions (degrees, image x towards y) along which the image is compressed, tried in this order (the axis-aligned
#: ones need no rotation)
FORESHORTENING_DIRECTIONS = (0.0, 90.0, 45.0, 135.0)
#: compression of those levels (it finds every board a stronger one finds, and more: ``docs/measurements.md``)
FORESHORTENING_RATIO = 2.0


def _compression(size: tuple[int, int], angle: float, ratio: float) -> tuple[torch.Tensor | None, tuple[int, int],
                                                                              tuple[int, int], torch.Tensor]:
    """Of images ``size`` ``(H, W)``: the rotation :math:`(3, 3)` (``None`` for a multiple of 90 degrees), the rotated
    canvas ``(height, width)``, the compressed level's ``(h, w)`` and the whole map ``A`` :math:`(3, 3)` float64."""
    h, w = size
    a = math.radians(float(angle) % 180.0)
    quarter = round(a / (math.pi / 2))
    eye = torch.eye(3, dtype=torch.float64)
    if abs(a - quarter * math.pi / 2) < 1e-9:
        # axis-aligned: compress x (0 degrees) or y (90 degrees) directly
        vertical = quarter % 2 == 1
        out = (max(8, round(h / ratio)), w) if vertical else (h, max(8, round(w / ratio)))
        s = torch.tensor([w / out[1], h / out[0]], dtype=torch.float64)
        A = eye.clone()
        A[0, 0], A[1, 1] = 1 / s[0], 1 / s[1]
        A[:2, 2] = 0.5 / s - 0.5  # pixel centres: (x + 0.5) / s - 0.5
        return None, (h, w), out, A
    c, s = math.cos(a), math.sin(a)
    rot = torch.tensor([[c, s], [-s, c]], dtype=torch.float64)  # direction (c, s) -> x axis
    cw, ch = abs(c) * w + abs(s) * h, abs(s) * w + abs(c) * h
    width, height = int(math.ceil(cw)), int(math.ceil(ch))
    R = eye.clone()
    R[:2, :2] = rot
    R[:2, 2] = torch.tensor([(width - 1) / 2, (height - 1) / 2], dtype=torch.float64) - rot @ torch.tensor(
        [(w - 1) / 2, (h - 1) / 2], dtype=torch.float64)
    out_w = max(8, round(width / ratio))
    C = eye.clone()
    C[0, 0] = out_w / width
    C[0, 2] = 0.5 * out_w / width - 0.5
    return R, (height, width), (height, out_w), C @ R


def compress_along(images: torch.Tensor, angle: float, ratio: float = FORESHORTENING_RATIO) -> tuple[torch.Tensor, torch.Tensor]:
    r"""``images`` compressed by ``ratio`` along the direction ``angle`` (degrees), and the map to that level.

    The image is rotated by ``-angle`` (bilinear, on a canvas that holds all of it, zeros outside; no rotation for
    multiples of 90 degrees) so that the direction becomes the level's x axis, then area-averaged by ``ratio`` along x
    (anti-aliased, as the pyramid levels).

    Args:
        images: :math:`(B, 1, H, W)`.
        angle: direction in degrees, from the image's x axis towards its y axis.
        ratio: compression factor (``>= 1``).

    Returns:
        level :math:`(B, 1, h, w)` and :math:`(3, 3)` float64 ``A`` mapping pixel coordinates of ``images`` (pixel
        centres at integers) to those of the level (homogeneous).

    Example:
        >>> level, A = compress_along(torch.rand(2, 1, 48, 64), 0.0, 2.0)
        >>> level.shape, A[0].tolist()
        (torch.Size([2, 1, 48, 32]), [0.5, 0.0, -0.25])
    """
    check_grey_images(images)
    if not ratio >= 1:
        raise ValueError(f"ratio must be >= 1, got {ratio}.")
    R, canvas, size, A = _compression(tuple(images.shape[-2:]), angle, ratio)
    if R is None:
        return F.interpolate(images.float(), size=size, mode="area"), A
    rotated = warp_affine(images.float(), R[:2].to(images.device, torch.float32)[None].expand(images.shape[0], -1, -1),
                          canvas, align_corners=True)
    return F.interpolate(rotated, size=size, mode="area"), A


def map_from_level(points: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    r"""Points :math:`(B, N, 2)` of a level of :func:`compress_along` mapped back to the image (``A`` inverted,
    kornia's ``transform_points``)."""
    inv = torch.linalg.inv(A.double()).to(points.device)[None].expand(points.shape[0], 3, 3)
    return transform_points(inv, points.double()).to(points.dtype)


@dataclass(frozen=True)
class Compression(Warp):
    """The pyramid level ``level`` compressed by ``ratio`` along the direction ``angle`` (degrees,
    :func:`compress_along`); points map back to the full-resolution images exactly (one affine map, inverted once).

    Example:
        >>> warp = Compression(90.0, 2.0, Level(2.0, (64, 96)))
        >>> warp.apply(torch.rand(1, 1, 64, 96)).shape, warp.coarseness
        (torch.Size([1, 1, 16, 48]), 4.0)
        >>> warp.back(torch.tensor([[[10.0, 5.0]]]))[0].tolist()
        [[[20.5, 21.5]]]
    """

    angle: float
    ratio: float
    level: Level

    @property
    def coarseness(self) -> float:
        """Full-resolution px per px of the compressed level along the compression (where a refinement starts)."""
        return self.ratio * self.level.coarseness

    def compress(self, level: torch.Tensor) -> torch.Tensor:
        """The second step of :meth:`apply` alone, on images of the level :math:`(B, 1, h, w)`."""
        return compress_along(level, self.angle, self.ratio)[0]

    def apply(self, images: torch.Tensor) -> torch.Tensor:
        return self.compress(self.level.apply(images))

    def back(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # full resolution -> level (pixel centres: (x + 0.5) / s - 0.5) -> compressed level, inverted at once
        scale = self.level.scale()
        to_level = torch.eye(3, dtype=torch.float64)
        to_level[[0, 1], [0, 1]] = 1.0 / scale
        to_level[:2, 2] = 0.5 / scale - 0.5
        A = _compression(self.level.size, self.angle, self.ratio)[3]
        ok = torch.ones(points.shape[0], dtype=torch.bool, device=points.device)
        return map_from_level(points.double(), A @ to_level).to(points.dtype), ok


def detect_foreshortened(
    detect: Callable[[torch.Tensor, tuple[int, int]], DetectionResult],
    images: torch.Tensor,
    board_size: tuple[int, int],
    refine: Callable[[torch.Tensor, torch.Tensor, float], torch.Tensor],
    factor: float = 1.0,
    directions: tuple[float, ...] = FORESHORTENING_DIRECTIONS,
    ratio: float = FORESHORTENING_RATIO,
) -> DetectionResult:
    r"""Look for the boards of ``images`` on levels compressed along each of ``directions`` in turn.

    The images are first brought to the level ``factor`` (:func:`~ccs_kornia.modules.detection.refine.patch_refine.resize_to_level`),
    then compressed by ``ratio`` along one direction (:func:`compress_along`; together a :class:`Compression` warp);
    corners found there are mapped back to full resolution and refined there
    (:func:`~ccs_kornia.modules.detection.warps.warped_detection.map_back`).

    Args:
        detect: ``detect(level (b, 1, h, w), board_size) -> DetectionResult`` on the level.
        images: :math:`(B, 1, H, W)` full-resolution images.
        board_size: ``(cols, rows)``.
        refine: ``refine(images (b, 1, H, W), corners (b, N, 2), factor) -> corners`` refines at full resolution
            corners mapped back from a level ``factor`` times coarser.
        factor: full-resolution px per px of the level that is compressed (``>= 1``).
        directions: degrees, tried in order; an image leaves the loop once its board is found.
        ratio: compression (:func:`compress_along`).

    Returns:
        :class:`~ccs_kornia.modules.detection.base.DetectionResult`: corners :math:`(B, N, 2)` at full resolution
        (zeros where not found), found :math:`(B,)`, a reason each.

    Example:
        >>> def detect(x, board):  # a stand-in detector: finds nothing
        ...     return DetectionResult(torch.zeros(x.shape[0], board[0] * board[1], 2),
        ...                            torch.zeros(x.shape[0], dtype=torch.bool), ["board not found"] * x.shape[0])
        >>> out = detect_foreshortened(detect, torch.rand(2, 1, 64, 64), (4, 3), lambda im, p, s: p)
        >>> out.corners.shape, out.found.tolist(), out.reasons[0]
        (torch.Size([2, 12, 2]), [False, False], 'board not found')
    """
    check_grey_images(images)
    if not factor >= 1:
        raise ValueError(f"factor must be >= 1, got {factor}.")
    b = images.shape[0]
    cols, rows = check_board_size(board_size, min_side=1)
    n = cols * rows
    out = DetectionResult(torch.zeros(b, n, 2, dtype=torch.float32, device=images.device),
                          torch.zeros(b, dtype=torch.bool, device=images.device), ["board not found"] * b)
    level = Level(factor, tuple(images.shape[-2:]))
    with stage("level resize"):
        base = level.apply(images)
    for angle in directions:
        todo = (~out.found).nonzero().flatten()
        if not todo.numel():
            break
        warp = Compression(angle, ratio, level)
        with stage("level resize"):
            compressed = warp.compress(base[todo])
        got = detect(compressed, board_size)
        if not bool(got.found.any()):
            continue
        got = map_back(warp, DetectionResult(got.corners.to(images.device), got.found.to(images.device), got.reasons),
                       lambda x, pts, bs: refine(x, pts, warp.coarseness), image_rows(images, todo), board_size)
        got.reasons = [f"{why or 'found'} (level compressed along {angle:g} degrees)"
                       for why in (got.reasons or [""] * len(todo))]
        out.fill(todo, got)
    return out
