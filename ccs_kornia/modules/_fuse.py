"""Inference-friendly networks: batch normalisation folded into the convolution before it.

In eval mode a ``BatchNorm2d`` after a convolution is a per-channel affine map, so it can be folded into the
convolution's weights and bias: one pass over the activations less per layer (about 15 % of the heatmap UNet's CPU
time), the same outputs up to float rounding.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["fold_batchnorm", "has_batchnorm"]


def has_batchnorm(module: nn.Module) -> bool:
    """Whether ``module`` contains a ``BatchNorm2d``."""
    return any(isinstance(m, nn.BatchNorm2d) for m in module.modules())


@torch.no_grad()
def _fold(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> None:
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps) if bn.affine else 1.0 / torch.sqrt(bn.running_var + bn.eps)
    shift = (bn.bias if bn.affine else 0.0) - bn.running_mean * scale
    conv.weight.mul_(scale.reshape(-1, 1, 1, 1).to(conv.weight))
    bias = shift if conv.bias is None else conv.bias * scale + shift
    conv.bias = nn.Parameter(bias.to(conv.weight), requires_grad=conv.weight.requires_grad)


def fold_batchnorm(module: nn.Module) -> nn.Module:
    """Fold every ``Conv2d -> BatchNorm2d`` pair of the ``nn.Sequential`` containers of ``module`` (in place).

    Each folded ``BatchNorm2d`` becomes an ``nn.Identity``; the module is put in eval mode (the folding uses the
    running statistics, so it is for inference only). Normalisation layers that do not directly follow a
    convolution are left as they are.

    Args:
        module: a network (e.g. :class:`~ccs_kornia.modules.detection.learned.heatmap_unet.CornerUNet`).

    Returns:
        ``module``, folded and in eval mode.

    Example:
        >>> net = nn.Sequential(nn.Conv2d(1, 4, 3, bias=False), nn.BatchNorm2d(4), nn.ReLU()).eval()
        >>> net[1].running_mean.uniform_(); net[1].running_var.uniform_(0.5, 2.0)  # doctest: +ELLIPSIS
        tensor(...)
        >>> x = torch.rand(2, 1, 8, 8); y = net(x)
        >>> folded = fold_batchnorm(net)
        >>> type(folded[1]).__name__, torch.allclose(folded(x), y, atol=1e-6)
        ('Identity', True)
    """
    module.eval()
    for seq in [m for m in module.modules() if isinstance(m, nn.Sequential)]:
        for k in range(len(seq) - 1):
            conv, bn = seq[k], seq[k + 1]
            if (isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d) and bn.track_running_stats
                    and bn.running_mean is not None and conv.out_channels == bn.num_features):
                _fold(conv, bn)
                seq[k + 1] = nn.Identity()
    return module
