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
    picks = sorted({cand[round(k)] for k in np.linspace(0, len(cand) - 1, count)})
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


def _features(pts: np.ndarray, all_obj: np.ndarray, lo: np.ndarray, span: np.ndarray, size: tuple[int, int],
              grid: int):
    """One view's ``(cells, pose, tilt direction, tilt magnitude, quality, corners)`` or ``None`` (not eligible)."""
    W, H = size
    ok = np.isfinite(pts).all(-1)
    if ok.sum() < 6:
        return None
    q = _quality(all_obj[ok], pts[ok])
    if q is None:
        return None
    score, inl = q
    obj, img = all_obj[ok][inl], pts[ok][inl]
    cols = np.clip((img[:, 0] / (W / grid)).astype(int), 0, grid - 1)
    rows = np.clip((img[:, 1] / (H / grid)).astype(int), 0, grid - 1)
    sx, sy = (img[:, 0].std(ddof=1) / W, img[:, 1].std(ddof=1) / H) if len(img) > 1 else (0.0, 0.0)
    pose = np.array([img[:, 0].mean() / W, img[:, 1].mean() / H, sx, sy, sx / sy if sy > 1e-6 else 1.0])
    direction, magnitude = _tilt(obj, img, lo, span)
    return set(zip(rows.tolist(), cols.tolist())), pose, direction, magnitude, score, len(img)


def coverage_greedy(corners: Sequence[Sequence[np.ndarray | None]], object_points: np.ndarray,
                    image_sizes: Sequence[tuple[int, int]], count: int, grid: int = 5) -> list[int]:
    """caliscope's coverage-greedy choice of ``count`` frames (see the module docstring); a rig's frames score the sum
    over its cameras (each camera's own grid, poses and anchors).

    Args:
        corners: per camera, per frame, its corners :math:`(N, 2)` (NaN where not seen; ``None``: no view).
        object_points: :math:`(N, 3)` the board's corners.
        image_sizes: per camera ``(W, H)``.
        count: frames to choose.
        grid: cells per side of the coverage grid.

    Returns:
        The chosen frames' positions, ascending.
    """
    all_obj = object_points[:, :2].astype(np.float64)
    lo, span = all_obj.min(0), np.maximum(all_obj.max(0) - all_obj.min(0), 1e-6)
    cams = []
    for c, views in enumerate(corners):
        data = {}
        for f, pts in enumerate(views):
            if pts is not None:
                feat = _features(np.asarray(pts, dtype=np.float64), all_obj, lo, span, image_sizes[c], grid)
                if feat is not None:
                    data[f] = feat
        most = max((n for *_, n in data.values()), default=1)
        # the corner count weighs the quality as caliscope's does (0.1 + 0.9 sqrt of the share of the most corners)
        cams.append({f: (cells, pose, d, m, q * (0.1 + 0.9 * math.sqrt(n / max(most, 1))))
                     for f, (cells, pose, d, m, q, n) in data.items()})
    frames = sorted(set().union(*(set(d) for d in cams)))
    if not frames or count < 1:
        return []
    chosen: list[int] = []
    for data in cams:  # each camera's anchors: the most tilted frame of each direction of tilt
        bins: dict[int, list[tuple[float, float, int]]] = {}
        for f, (_, _, direction, magnitude, q) in data.items():
            if magnitude >= 0.02:
                bins.setdefault(min(int(direction / (2 * math.pi) * 8), 7), []).append((-(magnitude * q), -q, f))
        for b in sorted(bins):
            f = min(bins[b])[2]
            if f not in chosen and len(chosen) < count:
                chosen.append(f)
    covered = [set().union(*(d[f][0] for f in chosen if f in d)) for d in cams]
    poses = [[d[f][1] for f in chosen if f in d] for d in cams]
    edge, corner_cells = {0, grid - 1}, {(0, 0), (0, grid - 1), (grid - 1, 0), (grid - 1, grid - 1)}
    remaining = set(frames) - set(chosen)
    while len(chosen) < count and remaining:
        best = None
        for f in sorted(remaining):
            total = 0.0
            for c, d in enumerate(cams):
                if f not in d:
                    continue
                cells, pose, _, _, q = d[f]
                new = cells - covered[c]
                s = len(new) + 0.2 * sum(1 for r, k in new if r in edge or k in edge) + 0.3 * len(new & corner_cells)
                if poses[c]:
                    s += 0.3 * min(float(np.linalg.norm(pose - p)) for p in poses[c])
                total += s * (0.5 + 0.5 * q) + 0.01 * q
            if best is None or total > best[0]:
                best = (total, f)
        if best[0] < 0.01:
            break
        f = best[1]
        chosen.append(f)
        for c, d in enumerate(cams):
            if f in d:
                covered[c] |= d[f][0]
                poses[c].append(d[f][1])
        remaining.discard(f)
    return sorted(chosen)
