"""Random board views with exact projections, shared by the grid organiser and collinearity tests."""

from __future__ import annotations

import math

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import (
    axis_angle_to_rotation_matrix,
    intrinsics_matrix,
    project_points,
    rotation_matrix_to_axis_angle,
)

F64 = torch.float64
W, H = 640, 480
K = intrinsics_matrix(torch.tensor([600.0, 600.0, (W - 1) / 2, (H - 1) / 2], dtype=F64))


def _pose(tilt_deg: float, azimuth: float, roll: float, dist: float, shift=(0.0, 0.0)):
    rz = axis_angle_to_rotation_matrix(torch.tensor([[0.0, 0.0, roll]], dtype=F64))[0]
    t = math.radians(tilt_deg)
    tilt_axis = torch.tensor([[t * math.cos(azimuth), t * math.sin(azimuth), 0.0]], dtype=F64)
    rt = axis_angle_to_rotation_matrix(tilt_axis)[0]
    rvec = rotation_matrix_to_axis_angle((rt @ rz)[None])[0]
    return rvec, torch.tensor([shift[0] * dist, shift[1] * dist, dist], dtype=F64)


def _views(cols, rows, n, seed, tilt=(0.0, 60.0), roll=None, dist_coeffs=None, square=1.0):
    """Random board views (B, N, 2) fully inside a 640x480 image, plus their (rvec, tvec)."""
    g = torch.Generator().manual_seed(seed)
    rnd = lambda: float(torch.rand(1, generator=g))  # noqa: E731
    obj = board_object_points(cols, rows, square, dtype=F64)
    centre = obj.mean(0) * torch.tensor([1.0, 1.0, 0.0], dtype=F64)
    d = None if dist_coeffs is None else torch.tensor(dist_coeffs, dtype=F64)
    out, poses = [], []
    while len(out) < n:
        r = rnd() * 2 * math.pi if roll is None else roll + (rnd() - 0.5) * 0.2
        depth = max(cols, rows) * square * 600.0 / (250 + 250 * rnd())  # board 250-500 px wide
        shift = ((rnd() - 0.5) * 0.3, (rnd() - 0.5) * 0.3)
        rvec, tvec = _pose(tilt[0] + rnd() * (tilt[1] - tilt[0]), rnd() * 2 * math.pi, r, depth, shift)
        # the board's own frame is centred so that poses are about its middle
        tvec = tvec - (axis_angle_to_rotation_matrix(rvec[None])[0] @ centre)
        uv = project_points(obj, K, d, rvec, tvec)
        if uv[:, 0].min() < 8 or uv[:, 0].max() > W - 9 or uv[:, 1].min() < 8 or uv[:, 1].max() > H - 9:
            continue
        out.append(uv)
        poses.append((rvec, tvec))
    return torch.stack(out), poses


def _corrupt(gt, g, missing=0.0, extra=0.0, noise=0.2):
    """Drop a fraction of corners, add false peaks (half near the board), shuffle, pad."""
    b, n, _ = gt.shape
    m = n + int(extra * n)
    pts = torch.zeros(b, m, 2, dtype=gt.dtype)
    mask = torch.zeros(b, m, dtype=torch.bool)
    kept = torch.zeros(b, n, dtype=torch.bool)
    for k in range(b):
        keep = torch.rand(n, generator=g) >= missing
        real = gt[k][keep] + noise * torch.randn(int(keep.sum()), 2, generator=g, dtype=gt.dtype)
        n_extra = int(extra * n)
        lo, hi = gt[k].min(0).values, gt[k].max(0).values
        near = (lo + hi) / 2 + (torch.rand(n_extra // 2, 2, generator=g, dtype=gt.dtype) * 2 - 1) * (hi - lo) * 0.65
        far = torch.rand(n_extra - n_extra // 2, 2, generator=g, dtype=gt.dtype) * torch.tensor([W, H], dtype=gt.dtype)
        allp = torch.cat([real, near, far])
        allp = allp[torch.randperm(len(allp), generator=g)]
        pts[k, : len(allp)] = allp
        mask[k, : len(allp)] = True
        kept[k] = keep
    return pts, mask, kept
