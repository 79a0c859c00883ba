"""CNN that regresses the paper's radial correction from a distorted chessboard image (paper Sec. III-A).

Architecture (the paper's "8 layers encoder with 3 regression layers"): eight ``conv3x3 -> norm -> ReLU``
layers, five of them with stride 2, then adaptive average pooling to a small ``pool x pool`` map (which keeps
the coarse layout: curvature near the border means more than near the centre) and three linear layers.

Input handling. Radii of the paper's model are measured from the image centre in units of ``max(W, H)``, so the
image is *letterboxed*: padded symmetrically to a ``max(W, H)`` square (aspect ratio kept, a radius of 0.5 then
reaches the middle of the longer side whatever the image size), resized to ``input_size`` with kornia
(antialiased), and standardised per image. Three fixed channels are appended: a mask of real (not padded) pixels
and the ``x`` and ``y`` coordinates in the model's radius unit (CoordConv), so the convolutions know how far from
the centre a curved edge is.

Output parameterisation. The correction factor ``f(r) = k0' + k1' r + ... + k4' r^4`` is represented by its
values at five Chebyshev nodes on ``[0, 0.75]`` (covering every distorted radius of any aspect ratio); the head
predicts ``f(node) - 1`` divided by ``output_scale``, and a fixed inverse Vandermonde matrix turns node values
into monomial coefficients. Node values are well conditioned (they are what the grid loss feels) while the
monomial coefficients of typical corrections span several orders of magnitude. The last layer starts at zero,
so an untrained network returns exactly the identity correction ``(1, 0, 0, 0, 0)``.
"""

from __future__ import annotations

import copy
import math
import os
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from kornia.color import rgb_to_grayscale
from kornia.filters import get_gaussian_kernel1d
from torch import nn

from ccs_kornia.modules._fuse import fold_batchnorm, has_batchnorm
from ccs_kornia.modules._resize import separable_product
from ccs_kornia.runtime.checks import check_tensor

__all__ = [
    "DistortionNet",
    "letterbox",
    "correction_from_node_values",
    "CORRECTION_NODES",
    "DEFAULT_DISTORTION_WEIGHTS",
    "load_distortion_net",
]

#: the shipped distortion-correction network
DEFAULT_DISTORTION_WEIGHTS = Path(__file__).resolve().parents[2] / "weights" / "distortion_net.pt"

_NORMS = ("batch", "group", "none")
#: radius range covered by the node parameterisation (units of max(W, H)); the image corner is at <= 0.7071
_R_MAX = 0.75
#: Chebyshev nodes of the first kind on [0, _R_MAX]
CORRECTION_NODES: tuple[float, ...] = tuple(
    0.5 * _R_MAX * (1.0 - math.cos((2 * k + 1) * math.pi / 10.0)) for k in range(5)
)


def _node_to_coeff_matrix(dtype=torch.float64) -> torch.Tensor:
    """``M`` with ``coeffs = M @ node_values`` (inverse Vandermonde of :data:`CORRECTION_NODES`)."""
    r = torch.tensor(CORRECTION_NODES, dtype=torch.float64)
    vander = torch.stack([r**p for p in range(5)], -1)  # f(node_i) = sum_p c_p node_i^p
    return torch.linalg.inv(vander).to(dtype)


def correction_from_node_values(node_values: torch.Tensor) -> torch.Tensor:
    """Monomial correction coefficients :math:`(B, 5)` from the factor ``f`` at :data:`CORRECTION_NODES`.

    Example:
        >>> correction_from_node_values(torch.ones(1, 5, dtype=torch.float64)).round(decimals=6).abs()
        tensor([[1., 0., 0., 0., 0.]], dtype=torch.float64)
    """
    check_tensor(node_values, "node_values", ["*", "5"])
    m = _node_to_coeff_matrix().to(device=node_values.device, dtype=node_values.dtype)
    return node_values @ m.T


def _resize_matrix(n: int, left: int, side: int, size: int, device: torch.device) -> torch.Tensor:
    """One axis of :func:`letterbox` as a :math:`(size, n)` matrix: a signal of length ``n`` placed at ``left`` in
    zeros of length ``side``, then resized to ``size`` as kornia's ``resize`` (``antialias=True``) does it: a Gaussian
    of sigma ``(side / size - 1) / 2`` (reflect border) and bilinear interpolation (``align_corners=False``)."""
    factor = side / size
    if factor > 1:
        sigma = max((factor - 1.0) / 2.0, 0.001)
        k = int(max(4.0 * sigma, 3))
        k = k if k % 2 else k + 1
        g = get_gaussian_kernel1d(k, sigma, device=device, dtype=torch.float64)[0]
    else:
        k, g = 1, torch.ones(1, device=device, dtype=torch.float64)
    m = k // 2
    dst = torch.arange(size, device=device, dtype=torch.float64)
    real = (factor * (dst + 0.5) - 0.5).clamp_min(0.0)  # torch's bilinear source index (align_corners=False)
    i0 = real.floor().long().clamp_max(side - 1)
    i1 = torch.where(i0 < side - 1, i0 + 1, i0)
    l1 = real - i0.double()
    pos = torch.cat([i0[:, None], i1[:, None]], 1)[:, :, None] + torch.arange(-m, m + 1, device=device)  # (S, 2, k)
    if side > 1:  # reflect (no edge repeat) at the padded square's border
        pos = torch.where(pos < 0, -pos, pos)
        pos = torch.where(pos > side - 1, 2 * (side - 1) - pos, pos)
    weight = torch.stack([1.0 - l1, l1], 1)[:, :, None] * g  # (S, 2, k)
    index = pos - left
    inside = (index >= 0) & (index < n)  # taps in the zero padding add nothing
    rows = torch.arange(size, device=device)[:, None, None].expand_as(index)
    out = torch.zeros(size, n, device=device, dtype=torch.float64)
    return out.index_put_((rows[inside], index[inside]), weight[inside], accumulate=True)


def letterbox(images: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pad images symmetrically to a ``max(H, W)`` square and resize to ``size x size`` (antialiased).

    The result is kornia's ``resize(pad(images), antialias=True)`` (Gaussian prefilter, bilinear), computed as two
    matrix products (the separable linear map of each axis) instead of blurring the padded full-size square: the
    padding is never materialised. Images larger than ``8 * size`` are first area-averaged by an integer factor to at most
    ``8 * size`` px a side (memory and time bounded on 24 Mpx photographs; area averaging is the anti-aliased
    shrink the Gaussian prefilter approximates).

    Args:
        images: :math:`(B, C, H, W)`.
        size: output side.

    Returns:
        letterboxed images :math:`(B, C, size, size)` and the mask of real pixels :math:`(B, 1, size, size)`.

    Example:
        >>> out, mask = letterbox(torch.ones(1, 1, 30, 60), 32)
        >>> out.shape, float(mask[0, 0, :, 16].sum())
        (torch.Size([1, 1, 32, 32]), 16.0)
    """
    check_tensor(images, "images", ["B", "C", "H", "W"])
    b, c, h, w = images.shape
    if max(h, w) > 8 * size:
        f = max(h, w) // (4 * size)
        images = F.interpolate(images, size=(max(1, round(h / f)), max(1, round(w / f))), mode="area")
        h, w = images.shape[-2:]
    side = max(h, w)
    left, top = (side - w) // 2, (side - h) // 2
    mx = _resize_matrix(w, left, side, size, images.device).to(images.dtype)
    my = _resize_matrix(h, top, side, size, images.device).to(images.dtype)
    out = separable_product(my, mx, images)
    mask = (my.sum(-1)[:, None] * mx.sum(-1)[None, :]).expand(b, 1, size, size)
    return out, mask.contiguous()


def _norm_layer(norm: str, channels: int) -> nn.Module:
    if norm == "batch":
        return nn.BatchNorm2d(channels)
    if norm == "group":
        groups = next(g for g in (8, 4, 2, 1) if channels % g == 0)
        return nn.GroupNorm(groups, channels)
    return nn.Identity()


class DistortionNet(nn.Module):
    """Regresses correction coefficients ``(k0', ..., k4')`` of :func:`ccs_kornia.geometry.radial.radial_correct_points`.

    Args:
        base_channels: width of the first layer; the eight layers use ``c, 2c, 2c, 4c, 4c, 8c, 8c, 8c``.
        input_size: side of the letterboxed network input.
        norm: ``batch``, ``group`` or ``none``.
        pool: side of the pooled feature map fed to the head.
        hidden: widths of the two hidden layers of the head.
        output_scale: change of the correction factor at a node per unit of network output.

    Shape:
        - Input: :math:`(B, C, H, W)` with ``C`` = 1 (grey) or 3 (RGB), any ``H, W``, values in ``[0, 1]``.
        - Output: :math:`(B, 5)` correction coefficients for images of that size.

    Example:
        >>> net = DistortionNet(base_channels=4, input_size=64).eval()
        >>> with torch.no_grad():
        ...     net(torch.rand(2, 1, 48, 64))
        tensor([[1., 0., 0., 0., 0.],
                [1., 0., 0., 0., 0.]])
    """

    _STRIDES = (2, 2, 1, 2, 1, 2, 1, 2)
    _WIDTHS = (1, 2, 2, 4, 4, 8, 8, 8)

    def __init__(
        self,
        base_channels: int = 16,
        input_size: int = 256,
        norm: str = "batch",
        pool: int = 4,
        hidden: tuple[int, int] = (256, 64),
        output_scale: float = 0.25,
    ) -> None:
        super().__init__()
        if norm not in _NORMS:
            raise ValueError(f"norm must be one of {_NORMS}, got {norm!r}.")
        if input_size < 32:
            raise ValueError(f"input_size must be >= 32, got {input_size}.")
        if len(hidden) != 2:
            raise ValueError(f"hidden must hold two layer widths, got {hidden}.")
        self.config: dict[str, Any] = {
            "base_channels": int(base_channels),
            "input_size": int(input_size),
            "norm": norm,
            "pool": int(pool),
            "hidden": [int(hidden[0]), int(hidden[1])],
            "output_scale": float(output_scale),
        }
        self.input_size, self.output_scale = int(input_size), float(output_scale)
        layers: list[nn.Module] = []
        cin = 4  # grey, real-pixel mask, x, y
        for stride, mult in zip(self._STRIDES, self._WIDTHS):
            cout = base_channels * mult
            layers += [
                nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=norm == "none"),
                _norm_layer(norm, cout),
                nn.ReLU(inplace=True),
            ]
            cin = cout
        self.encoder = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d(pool)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(cin * pool * pool, hidden[0]),
            nn.ReLU(inplace=True),
            nn.Linear(hidden[0], hidden[1]),
            nn.ReLU(inplace=True),
            nn.Linear(hidden[1], 5),
        )
        last = self.head[-1]
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        s = torch.linspace(-0.5, 0.5, self.input_size)
        yy, xx = torch.meshgrid(s, s, indexing="ij")
        self.register_buffer("coords", torch.stack([xx, yy]).unsqueeze(0), persistent=False)
        self.register_buffer("node_to_coeff", _node_to_coeff_matrix(torch.float32), persistent=False)

    def preprocess(self, images: torch.Tensor) -> torch.Tensor:
        """Grey, standardised, letterboxed network input :math:`(B, 4, S, S)` (image, mask, x, y)."""
        check_tensor(images, "images", ["B", "1", "H", "W"], ["B", "3", "H", "W"])
        x = images.float()
        if x.shape[1] == 3:
            x = rgb_to_grayscale(x)
        # per-image standardisation before padding, so the zero padding equals the image mean; the letterbox is
        # linear, so it is applied to the small letterboxed image: letterbox((x - m) / s) = (letterbox(x) - m mask) / s
        if x.shape[-1] * x.shape[-2] > 1:
            # from the sum and the sum of squares (one fast reduction each): std_mean's result within 5e-7 relative at
            # a fifth of its time (docs/measurements.md; where the image is nearly flat and the difference cancels,
            # the 1e-3 below dominates anyway)
            flat = x.flatten(-2)
            n = flat.shape[-1]
            total = flat.sum(-1)
            mean = total / n
            std = ((torch.linalg.vecdot(flat, flat) - total * mean) / (n - 1)).clamp_min(0).sqrt()
            mean, std = mean[..., None, None], std[..., None, None]
        else:
            mean = x.mean(dim=(-1, -2), keepdim=True)
            std = torch.ones_like(mean)
        x, mask = letterbox(x, self.input_size)
        x = (x - mean * mask) / (std + 1e-3)
        return torch.cat([x, mask, self.coords.to(x.dtype).expand(x.shape[0], -1, -1, -1)], 1)

    def node_values(self, images: torch.Tensor) -> torch.Tensor:
        """Correction factor at :data:`CORRECTION_NODES`, :math:`(B, 5)`."""
        feats = self.pool(self.encoder(self.preprocess(images)))
        return 1.0 + self.output_scale * self.head(feats)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = self.preprocess(images)
        if x.device.type == "cpu" and not self.training:
            # channels-last convolutions are faster on CPU (oneDNN); the weights follow the input's layout
            x = x.contiguous(memory_format=torch.channels_last)
        z = self.output_scale * self.head(self.pool(self.encoder(x)))
        identity = torch.zeros_like(z)
        identity[:, 0] = 1.0
        # M @ 1 = (1, 0, 0, 0, 0): residual around the identity correction
        return identity + z @ self.node_to_coeff.to(z.dtype).T

    @classmethod
    def from_export(cls, source: str | Path | dict, map_location: str | torch.device = "cpu") -> DistortionNet:
        """Network in eval mode from an exported weight file (or its loaded dict) with ``config`` and ``state_dict``."""
        if isinstance(source, dict):
            payload = source
        else:
            payload = torch.load(str(source), map_location=map_location, weights_only=True)
        if payload.get("kind", "DistortionNet") != "DistortionNet":
            raise ValueError(f"Not a DistortionNet export: kind={payload.get('kind')!r}.")
        cfg = dict(payload["config"])
        cfg["hidden"] = tuple(cfg.get("hidden", (256, 64)))
        net = cls(**cfg)
        net.load_state_dict(payload["state_dict"])
        return net.eval()

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def load_distortion_net(spec: bool | str | Path | DistortionNet | None = True) -> DistortionNet | None:
    """The distortion network a pipeline runs: ``True`` the shipped one, ``False``/``None`` none, a path or a net
    (for inference: batch normalisation folded into the convolutions, :func:`~ccs_kornia.modules._fuse.fold_batchnorm`).

    Raises:
        FileNotFoundError: no weight file at the path.

    Example:
        >>> load_distortion_net(False) is None, type(load_distortion_net(True)).__name__
        (True, 'DistortionNet')
    """
    if spec is False or spec is None:
        return None
    if isinstance(spec, DistortionNet):
        # inference only: a copy with batch normalisation folded into the convolutions (the caller's is untouched)
        return fold_batchnorm(copy.deepcopy(spec) if has_batchnorm(spec) else spec)
    path = DEFAULT_DISTORTION_WEIGHTS if spec is True else spec
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"distortion correction weights not found at {path}; pass distortion_correction=False to calibrate "
            "without the correction network"
        )
    return fold_batchnorm(DistortionNet.from_export(path))
