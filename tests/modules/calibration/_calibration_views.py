"""Random board poses shared by the calibration tests."""

from __future__ import annotations

import torch


def _views(K: torch.Tensor, num: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    rvec = 0.6 * (torch.rand(num, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.stack([0.1 * (torch.rand(num, generator=g, dtype=torch.float64) - 0.5) - 0.1,
                        0.1 * (torch.rand(num, generator=g, dtype=torch.float64) - 0.5) - 0.06,
                        0.35 + 0.1 * torch.rand(num, generator=g, dtype=torch.float64)], -1)
    return rvec, tvec
