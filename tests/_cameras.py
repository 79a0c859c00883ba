"""Cameras for tests, from ``(model, K, coefficients)`` specifications."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ccs_kornia.geometry.camera import Camera


def cameras(specs: Sequence[tuple], sizes: Sequence[tuple[int, int]] | tuple[int, int]) -> Camera:
    """One value of the cameras ``(model, K (3, 3), coefficients (D,) or None)``, float64, with their image sizes."""
    sizes = [sizes] * len(specs) if len(sizes) == 2 and isinstance(sizes[0], int) else list(sizes)
    return Camera.cat([Camera.from_opencv(m, K.to(torch.float64), None if d is None else d.to(torch.float64), s)
                       for (m, K, d), s in zip(specs, sizes)])
