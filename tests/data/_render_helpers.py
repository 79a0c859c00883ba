"""Cameras and poses shared by the renderer tests."""

from __future__ import annotations

import torch

from ccs_kornia.data.scenes.sampling import sample_poses

W, H = 160, 120


def _K(fx=200.0, fy=205.0, cx=80.3, cy=59.2, dtype=torch.float32):
    return torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)


def _poses(n, K=None, board=(5, 4), square=0.03, size=(W, H), seed=0, **kw):
    K = _K() if K is None else K
    return sample_poses(K, board, square, size, n, torch.Generator().manual_seed(seed), **kw)
