"""The frame choices the ``video`` benchmark compares ours with: uniformly spaced frames, and a coverage-greedy choice
as caliscope makes it.

:func:`coverage_greedy` follows caliscope's intrinsic frame selector (``caliscope.core.frame_selector``, 2025): a
frame is eligible when a RANSAC homography of its board explains at least 85 % of its corners with a planar RMS of
at most 8 % of the corner spacing; one *anchor* per direction of tilt (eight 45-degree sectors of the homography's
perspective row, tilt at least 0.02), the most tilted; then greedily the frame that covers most new cells of a 5x5
grid of the image (edge cells +0.2, corner cells +0.3) plus 0.3 times its distance to the nearest chosen frame in
(centroid, spread, aspect) of its corners, weighted by its planar quality, until the count is reached or no frame
scores 0.01. Written from that description, not copied.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

__all__ = ["coverage_greedy", "uniform_frames"]


def uniform_frames(candidates: Sequence[int], count: int) -> list[int]:
    """``count`` of ``candidates`` (frame positions in time order) spaced evenly from the first to the last.

    Example:
        >>> uniform_frames(list(range(10)), 4)
        [0, 3, 6, 9]
    """
    cand = list(candidates)
    if count >= len(cand):
        return cand
    if count <= 1:
        return cand[:max(0, count)]
    picks = sorted({cand[int(round(k))] for k in np.linspace(0, len(cand) - 1, count)})
    return picks


def _quality(obj: np.ndarray, img: np.ndarray) -> tuple[float, np.ndarray] | None:
    """caliscope's planar gate: ``(score, inlier mask)`` or ``None`` (not eligible)."""
    if len(obj) < 6:
        return None
    lo, span = obj.min(0), np.maximum(obj.max(0) - obj.min(0), 1e-6)
    on = ((obj - lo) / span).astype(np.float32)
    H, mask = cv2.findHomography(on, img.astype(np.float32), cv2.RANSAC, 3.0)
    if H is None or mask is None:
        return None
    inl = mask.reshape(-1).astype(bool)
    if inl.sum() < 6 or inl.mean() < 0.85:
        return None
    H, _ = cv2.findHomography(on[inl], img[inl].astype(np.float32), 0)
    if H is None:
        return None
    proj = cv2.perspectiveTransform(on[inl, None], H)[:, 0]
    rms = float(np.sqrt(np.mean(np.sum((proj - img[inl]) ** 2, -1))))
    d = np.linalg.norm(img[inl][:, None] - img[inl][None], axis=-1)
    np.fill_diagonal(d, np.inf)
    pitch = float(np.median(d.min(1)))
    if not np.isfinite(pitch) or pitch < 1.0 or rms / pitch > 0.08:
        return None
    return float(inl.mean() / (1.0 + rms / pitch)), inl


def _tilt(obj: np.ndarray, img: np.ndarray, lo: np.ndarray, span: np.ndarray) -> tuple[float, float]:
    """``(direction, magnitude)`` of the board's tilt from the homography's perspective row."""
    if len(obj) < 12:
        return 0.0, 0.0
    H, _ = cv2.findHomography(((obj - lo) / span).astype(np.float32), img.astype(np.float32), 0)
    if H is None or not np.isfinite(H).all() or abs(H[2, 2]) < 1e-12:
        return 0.0, 0.0
    H = H / H[2, 2]
    return float(math.atan2(H[2, 1], H[2, 0]) % (2 * math.pi)), float(math.hypot(H[2, 0], H[2, 1]))


def coverage_greedy(corners: Sequence[np.ndarray], object_points: np.ndarray, image_size: tuple[int, int],
                    count: int, grid: int = 5) -> list[int]:
    """caliscope's coverage-greedy choice of ``count`` frames (see the module docstring).

    Args:
        corners: per frame its corners :math:`(N, 2)` (NaN where not seen).
        object_points: :math:`(N, 3)` the board's corners.
        image_size: ``(W, H)``.
        count: frames to choose.
        grid: cells per side of the coverage grid.

    Returns:
        The chosen frames' positions in ``corners``, ascending.
    """
    W, H = image_size
    data = {}
    all_obj = object_points[:, :2].astype(np.float64)
    lo, span = all_obj.min(0), np.maximum(all_obj.max(0) - all_obj.min(0), 1e-6)
    for f, pts in enumerate(corners):
        ok = np.isfinite(pts).all(-1)
        if ok.sum() < 6:
            continue
        q = _quality(all_obj[ok], pts[ok])
        if q is None:
            continue
        score, inl = q
        obj, img = all_obj[ok][inl], pts[ok][inl]
        cols = np.clip((img[:, 0] / (W / grid)).astype(int), 0, grid - 1)
        rows = np.clip((img[:, 1] / (H / grid)).astype(int), 0, grid - 1)
        cells = set(zip(rows.tolist(), cols.tolist()))
        sx, sy = (img[:, 0].std(ddof=1) / W, img[:, 1].std(ddof=1) / H) if len(img) > 1 else (0.0, 0.0)
        pose = np.array([img[:, 0].mean() / W, img[:, 1].mean() / H, sx, sy, sx / sy if sy > 1e-6 else 1.0])
        direction, magnitude = _tilt(obj, img, lo, span)
        data[f] = (cells, pose, direction, magnitude, score)
    if not data:
        return []
    most = max(len(c) for c, *_ in data.values())
    # corner count weighs the quality as caliscope's does (0.1 + 0.9 sqrt of the share of the most corners)
    data = {f: (c, p, d, m, s * (0.1 + 0.9 * math.sqrt(len(c) / max(most, 1)))) for f, (c, p, d, m, s) in data.items()}
    bins: dict[int, list[tuple[float, float, int]]] = {}
    for f, (_, _, direction, magnitude, score) in data.items():
        if magnitude >= 0.02:
            b = min(int(direction / (2 * math.pi) * 8), 7)
            bins.setdefault(b, []).append((-(magnitude * score), -score, f))
    anchors = [min(bins[b])[2] for b in sorted(bins)][:count]
    chosen = list(anchors)
    covered = set().union(*(data[f][0] for f in chosen)) if chosen else set()
    poses = [data[f][1] for f in chosen]
    edge, corner_cells = {0, grid - 1}, {(0, 0), (0, grid - 1), (grid - 1, 0), (grid - 1, grid - 1)}
    remaining = set(data) - set(chosen)
    while len(chosen) < count and remaining:
        best = None
        for f in sorted(remaining):
            cells, pose, _, _, q = data[f]
            new = cells - covered
            s = len(new) + 0.2 * sum(1 for r, c in new if r in edge or c in edge) + 0.3 * len(new & corner_cells)
            if poses:
                s += 0.3 * min(float(np.linalg.norm(pose - p)) for p in poses)
            s = s * (0.5 + 0.5 * q) + 0.01 * q
            if best is None or s > best[0]:
                best = (s, f)
        if best[0] < 0.01:
            break
        chosen.append(best[1])
        covered |= data[best[1]][0]
        poses.append(data[best[1]][1])
        remaining.discard(best[1])
    return sorted(chosen)
