r"""Each dot of a circle grid measured on the image: the centre and area of its image from grey-level moments.

Around each dot's rough centre, in a window of its distance to the nearest dot (cut by the image's frame), the image is thresholded halfway
between the local print and dot levels; the dot's connected region, widened by :data:`EDGE_PX` pixels to hold its
blurred edge (and cut where another dot's region is nearer), weighs each pixel by how dark it is
(:math:`w = \mathrm{clip}((b - I) / (b - d), 0, 1)`, ``b`` the print's level as a plane fitted to the window's
pixels outside every dot, ``d`` the dot's inner level). The weights' centroid is the centre of the dot's image (for
an ellipse, the centre of its conic; blur does not move it) and their sum its area in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["EDGE_PX", "DotMoments", "dot_moments"]

#: how far (px) a dot's thresholded region is widened to hold its blurred edge
EDGE_PX = 3


@dataclass
class DotMoments:
    """Dots measured on one image: ``centres`` :math:`(N, 2)` px, ``areas`` :math:`(N,)` px² and ``ok`` :math:`(N,)`
    (False where the dot could not be measured: no dark region at its centre, or cut by the image's frame, whose
    area is then what the image shows of it; NaN where not measured)."""

    centres: np.ndarray
    areas: np.ndarray
    ok: np.ndarray


def _nearest(centres: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    d[np.arange(len(centres)), np.arange(len(centres))] = np.inf
    return d.min(1)


def dot_moments(gray: np.ndarray, centres: np.ndarray, dark: bool = True) -> DotMoments:
    """Measure the dots near ``centres`` :math:`(N, 2)` (rough, px) on ``gray`` :math:`(H, W)` (any real dtype);
    ``dark``: dark dots on a light print (else the inverse).

    Example:
        >>> img = np.full((64, 90), 200.0)
        >>> _ = cv2.circle(img, (30, 30), 6, 30.0, -1)
        >>> _ = cv2.circle(img, (55, 30), 6, 30.0, -1)
        >>> m = dot_moments(img, np.array([[29.0, 31.0], [56.0, 30.0]]))
        >>> np.round(m.centres, 2).tolist(), bool(m.ok.all())
        ([[30.0, 30.0], [55.0, 30.0]], True)
    """
    img = np.asarray(gray, dtype=np.float64)
    img = img if dark else img.max() + img.min() - img
    h, w = img.shape
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    n = len(centres)
    out_c, out_a, ok = np.full((n, 2), np.nan), np.full(n, np.nan), np.zeros(n, dtype=bool)
    if n == 0:
        return DotMoments(out_c, out_a, ok)
    near = _nearest(centres) if n > 1 else np.full(n, 20.0)
    for k, (u, v) in enumerate(centres):
        if not (np.isfinite(u) and np.isfinite(v)) or not (0 <= u <= w - 1 and 0 <= v <= h - 1):
            continue
        half = int(np.ceil(0.8 * near[k])) + EDGE_PX
        x0, y0 = max(round(u) - half, 0), max(round(v) - half, 0)
        x1, y1 = min(round(u) + half + 1, w), min(round(v) + half + 1, h)
        win = img[y0:y1, x0:x1]
        lo, hi = np.percentile(win, 2), np.percentile(win, 98)
        if not hi - lo > 1e-6:
            continue
        mask = (win < 0.5 * (lo + hi)).astype(np.uint8)
        _, labels = cv2.connectedComponents(mask, connectivity=8)
        cx, cy = round(u) - x0, round(v) - y0
        own = labels[cy, cx]
        if own == 0:  # the rough centre off the dot: the nearest dark region
            ys, xs = np.nonzero(labels)
            if not len(xs):
                continue
            j = np.argmin((xs - cx) ** 2 + (ys - cy) ** 2)
            if (xs[j] - cx) ** 2 + (ys[j] - cy) ** 2 > (0.3 * near[k]) ** 2:
                continue
            own = labels[ys[j], xs[j]]
        region = labels == own
        others = (labels > 0) & ~region
        # the distance of every pixel to this dot's region and to the others': a pixel belongs to the nearer
        d_own = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, 5)
        d_other = cv2.distanceTransform((~others).astype(np.uint8), cv2.DIST_L2, 5) if others.any() else \
            np.full_like(d_own, np.inf)
        support = (d_own <= EDGE_PX) & (d_own < d_other)
        edges = (region[0].any(), region[-1].any(), region[:, 0].any(), region[:, -1].any())
        frame = (y0 == 0, y1 == h, x0 == 0, x1 == w)
        if any(e and not f for e, f in zip(edges, frame)):
            continue  # the dot reaches the window's edge inside the image: not a dot of the grid's size
        cut = any(edges)  # cut by the image's frame: its area is a lower bound, its centre unknown
        outside = (d_own > EDGE_PX + 1) & (d_other > EDGE_PX + 1)
        if outside.sum() < 8:
            continue
        yy, xx = np.mgrid[0:win.shape[0], 0:win.shape[1]].astype(np.float64)
        design = np.stack([np.ones(int(outside.sum())), xx[outside], yy[outside]], -1)
        plane = np.linalg.lstsq(design, win[outside], rcond=None)[0]
        bright = plane[0] + plane[1] * xx + plane[2] * yy
        inner = cv2.erode(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        level = np.median(win[inner]) if inner.sum() >= 3 else win[region].min()
        wts = np.clip((bright - win) / np.maximum(bright - level, 1e-6), 0.0, 1.0) * support
        total = wts.sum()
        if not total > 0:
            continue
        out_a[k] = total
        if not cut:
            out_c[k] = ((wts * xx).sum() / total + x0, (wts * yy).sum() / total + y0)
            ok[k] = True
    return DotMoments(out_c, out_a, ok)
