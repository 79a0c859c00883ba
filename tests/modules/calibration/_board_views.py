"""Exact board projections shared by the solver tests."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import axis_angle_to_rotation_matrix, project_points

F64 = torch.float64


def synthetic(C=1, V=15, cols=9, rows=6, square=0.03, dist=None, noise=0.0, seed=0):
    """Random cameras and board poses (board inside a 640x480 image); float64 ground truth."""
    g = torch.Generator().manual_seed(seed)

    def rand(*s):
        return torch.rand(*s, generator=g, dtype=F64)

    fx = 500 + 400 * rand(C)
    K = torch.zeros(C, 3, 3, dtype=F64)
    K[:, 0, 0], K[:, 1, 1] = fx, fx * (0.95 + 0.1 * rand(C))
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = 320 + 30 * (rand(C) - 0.5), 240 + 30 * (rand(C) - 0.5), 1
    obj = board_object_points(cols, rows, square, dtype=F64)
    axis = torch.nn.functional.normalize(torch.randn(C, V, 3, generator=g, dtype=F64), dim=-1)
    rvec = axis * (0.15 + 0.55 * rand(C, V))[..., None]
    R = axis_angle_to_rotation_matrix(rvec.reshape(-1, 3)).reshape(C, V, 3, 3)
    depth = (fx[:, None] / 500) * 0.5 * (0.8 + 0.5 * rand(C, V)) * (cols * square / 0.27)
    tvec = torch.cat([(rand(C, V, 2) - 0.5) * 0.1, depth[..., None]], -1) - R @ obj.mean(0)
    d = None if dist is None else dist.to(F64).expand(C, -1)[:, None].expand(C, V, -1)
    uv = project_points(obj.expand(C, V, -1, -1), K[:, None].expand(C, V, 3, 3), d, rvec, tvec)
    uv = uv + noise * torch.randn(uv.shape, generator=g, dtype=F64)
    return K, obj, uv, rvec, tvec


def all_valid(uv):
    return torch.ones(uv.shape[:-1], dtype=torch.bool)
