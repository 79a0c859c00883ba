"""UNet that turns a chessboard image into a corner heatmap (paper Sec. III-B, "learning heatmap detection").

The network is the classic UNet of Ronneberger et al.: per level two ``conv3x3 -> norm -> ReLU`` blocks, max-pool
down, bilinear upsampling (or a transposed convolution) up, skip connections by channel concatenation and a final
``1x1`` convolution. Its output is a one-channel heatmap in ``[0, 1]`` in which every inner corner of the board is a
2-D Gaussian blob (the training target), ready for :mod:`ccs_kornia.modules.detection.learned.peaks`.

Any input size is accepted: the image is padded (edge replication, so the pad does not create artificial step
edges that could look like board edges) up to a multiple of ``2 ** depth`` and the output is cropped back, so the
heatmap pixel ``(x, y)`` is exactly the image pixel ``(x, y)``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ccs_kornia.runtime.checks import check_tensor

__all__ = ["CornerUNet", "DoubleConv", "cpu_has_native_bf16", "effective_precision", "run_heatmap", "PRECISIONS",
           "BATCH_PIXELS", "TILE_PIXELS", "TILE_SIDE", "TILE_MARGIN"]

#: network precisions of :func:`run_heatmap`
PRECISIONS = ("auto", "float32", "bfloat16")

_NORMS = ("batch", "group", "none")
_UP_MODES = ("bilinear", "transposed")
_OUT_ACTIVATIONS = ("sigmoid", "none")


def _num_groups(channels: int) -> int:
    """Groups for GroupNorm: at most 8, at least 2 channels per group where possible, always a divisor."""
    for groups in (8, 4, 2):
        if channels % groups == 0 and channels // groups >= 2:
            return groups
    return 1


def _norm_layer(norm: str, channels: int) -> nn.Module:
    if norm == "batch":
        return nn.BatchNorm2d(channels)
    if norm == "group":
        return nn.GroupNorm(_num_groups(channels), channels)
    return nn.Identity()


class DoubleConv(nn.Sequential):
    """Two ``conv3x3 -> norm -> ReLU`` blocks (one UNet level).

    Args:
        in_channels: input channels.
        out_channels: output channels of both convolutions.
        norm: ``"batch"``, ``"group"`` or ``"none"``.
        mid_channels: channels between the two convolutions (default ``out_channels``).
    """

    def __init__(
        self, in_channels: int, out_channels: int, norm: str = "batch", mid_channels: int | None = None
    ) -> None:
        mid = out_channels if mid_channels is None else mid_channels
        # a bias is redundant in front of a normalisation layer (it is absorbed by the norm's shift)
        bias = norm == "none"
        super().__init__(
            nn.Conv2d(in_channels, mid, 3, padding=1, bias=bias),
            _norm_layer(norm, mid),
            nn.ReLU(inplace=True),
            nn.Conv2d(mid, out_channels, 3, padding=1, bias=bias),
            _norm_layer(norm, out_channels),
            nn.ReLU(inplace=True),
        )


class _Up(nn.Module):
    """Upsample by 2, concatenate the skip connection, then a :class:`DoubleConv`."""

    def __init__(self, in_channels: int, skip_channels: int, out_channels: int, norm: str, up_mode: str) -> None:
        super().__init__()
        if up_mode == "transposed":
            self.up: nn.Module = nn.ConvTranspose2d(in_channels, in_channels // 2, kernel_size=2, stride=2)
            up_channels = in_channels // 2
        else:
            self.up = nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False)
            up_channels = in_channels
        self.conv = DoubleConv(up_channels + skip_channels, out_channels, norm)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        up = self.up(x)
        first = self.conv[0]
        if self.training or torch.is_grad_enabled() or up.device.type != "cpu":
            return self.conv(torch.cat([skip, up], dim=1))
        # the first convolution of the concatenation is the sum of one convolution per part: on CPU the channels-last
        # concatenation costs as much as the convolution after it (docs/measurements.md)
        c = skip.shape[1]
        # summed in place: a new tensor for the sum cost more than the addition
        y = F.conv2d(up, first.weight[:, c:], first.bias, padding=1)
        y.add_(F.conv2d(skip, first.weight[:, :c], None, padding=1))
        for layer in list(self.conv)[1:]:
            y = layer(y)
        return y


class CornerUNet(nn.Module):
    r"""Classic UNet producing a corner heatmap of the same size as the input.

    Channels double at every level: ``base_channels * 2**i`` for ``i = 0..depth`` (the last one is the
    bottleneck). The shipped default (``base_channels=8, depth=4``) has about 0.53 M parameters and runs on a
    CPU; wider or deeper variants are for GPU training.

    Args:
        in_channels: image channels (1 for the grey images of this project).
        base_channels: channels of the first level.
        depth: number of down-sampling steps; the input is padded internally to a multiple of ``2**depth``.
        norm: ``"batch"`` (BatchNorm2d), ``"group"`` (GroupNorm, batch-size independent) or ``"none"``.
        out_activation: ``"sigmoid"`` (heatmap in ``[0, 1]``) or ``"none"`` (raw logits).
        up_mode: ``"bilinear"`` (upsample then convolve, no checkerboard artefacts) or ``"transposed"``.
        out_bias: initial bias of the output convolution; the default ``-4`` makes the untrained network start
            from an almost empty heatmap (``sigmoid(-4) ~ 0.018``), which is what nearly every target pixel is, so
            early training is spent on the corners rather than on unlearning a grey background.

    Shape:
        - Input: :math:`(B, C_{in}, H, W)`, any :math:`H, W \ge 1`.
        - Output: :math:`(B, 1, H, W)`.

    Example:
        >>> net = CornerUNet().eval()
        >>> net(torch.rand(2, 1, 61, 97)).shape
        torch.Size([2, 1, 61, 97])
    """

    def __init__(
        self,
        in_channels: int = 1,
        base_channels: int = 8,
        depth: int = 4,
        norm: str = "batch",
        out_activation: str | None = "sigmoid",
        up_mode: str = "bilinear",
        out_bias: float = -4.0,
    ) -> None:
        super().__init__()
        if in_channels < 1 or base_channels < 1:
            raise ValueError(f"in_channels and base_channels must be >= 1, got {in_channels} and {base_channels}.")
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}.")
        if norm not in _NORMS:
            raise ValueError(f"Unknown norm {norm!r}; expected one of {_NORMS}.")
        if out_activation is None:
            out_activation = "none"
        if out_activation not in _OUT_ACTIVATIONS:
            raise ValueError(f"Unknown out_activation {out_activation!r}; expected one of {_OUT_ACTIVATIONS}.")
        if up_mode not in _UP_MODES:
            raise ValueError(f"Unknown up_mode {up_mode!r}; expected one of {_UP_MODES}.")
        self.in_channels = in_channels
        self.base_channels = base_channels
        self.depth = depth
        self.norm = norm
        self.out_activation = out_activation
        self.up_mode = up_mode

        channels = [base_channels * 2**i for i in range(depth + 1)]
        self.inc = DoubleConv(in_channels, channels[0], norm)
        self.downs = nn.ModuleList(DoubleConv(channels[i], channels[i + 1], norm) for i in range(depth))
        self.ups = nn.ModuleList(
            _Up(channels[i + 1], channels[i], channels[i], norm, up_mode) for i in reversed(range(depth))
        )
        self.head = nn.Conv2d(channels[0], 1, kernel_size=1)
        nn.init.constant_(self.head.bias, out_bias)

    @property
    def multiple(self) -> int:
        """Input sizes are padded internally to a multiple of this."""
        return 2**self.depth

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        check_tensor(image, "image", ["B", self.in_channels, "H", "W"])
        height, width = image.shape[-2:]
        pad_h = (-height) % self.multiple
        pad_w = (-width) % self.multiple
        x = F.pad(image, (0, pad_w, 0, pad_h), mode="replicate") if (pad_h or pad_w) else image

        x = self.inc(x)
        skips = [x]
        for down in self.downs:
            x = down(F.max_pool2d(x, 2))
            skips.append(x)
        skips.pop()  # the bottleneck output is x itself
        for up in self.ups:
            x = up(x, skips.pop())
        x = self.head(x)
        if self.out_activation == "sigmoid":
            x = torch.sigmoid(x)
        return x[..., :height, :width]

    def extra_repr(self) -> str:
        return (
            f"in_channels={self.in_channels}, base_channels={self.base_channels}, depth={self.depth}, "
            f"norm={self.norm!r}, out_activation={self.out_activation!r}, up_mode={self.up_mode!r}"
        )


def cpu_has_native_bf16() -> bool:
    """Whether this CPU computes bfloat16 natively (AVX512-BF16 or AMX; read from ``/proc/cpuinfo`` on Linux).

    Where it does, oneDNN's bfloat16 convolutions run faster than float32 ones (``docs/measurements.md``); elsewhere
    they are emulated and slower, so ``precision="auto"`` stays in float32.
    """
    global _NATIVE_BF16
    if _NATIVE_BF16 is None:
        flags: set[str] = set()
        try:
            with open("/proc/cpuinfo", encoding="utf-8") as f:
                for line in f:
                    if line.startswith("flags"):
                        flags = set(line.split(":", 1)[1].split())
                        break
        except OSError:
            pass
        _NATIVE_BF16 = bool(flags & {"avx512_bf16", "amx_bf16"}) and torch.backends.mkldnn.is_available()
    return _NATIVE_BF16


_NATIVE_BF16: bool | None = None


def effective_precision(precision: str, device: torch.device | str = "cpu") -> str:
    """The dtype :func:`run_heatmap` computes in for ``precision`` on ``device``: ``"float32"`` or ``"bfloat16"``."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}.")
    cpu = torch.device(device).type == "cpu"
    low = precision == "bfloat16" or (precision == "auto" and cpu and cpu_has_native_bf16())
    return "bfloat16" if low else "float32"


#: inputs above this many pixels run through the network in tiles (:func:`run_heatmap`): in one piece, the detection
#: level of a 24 Mpx photograph takes a large share of the memory budget (``docs/measurements.md``)
TILE_PIXELS = 2_000_000
#: on CPU, batches above this many pixels run through the network a few whole images at a time (:func:`run_heatmap`):
#: its activations then stay in the processor's cache between layers, faster (``docs/measurements.md``); the
#: same heatmaps: each image's convolutions do not depend on the others in the batch
BATCH_PIXELS = 600_000
#: core side of a tile (px, a multiple of every network depth's ``2 ** depth`` up to 6)
TILE_SIDE = 1024
#: context around each tile's core (px, a multiple of ``2 ** depth``): more than the shipped network's receptive
#: radius (about 92 px: two 3x3 convolutions per level, 4 levels down and up), so a core's output equals the
#: untiled one's up to float rounding
TILE_MARGIN = 128


def run_heatmap(net: nn.Module, images: torch.Tensor, precision: str = "float32",
                tile_pixels: int | None = TILE_PIXELS, batch_pixels: int | None = BATCH_PIXELS) -> torch.Tensor:
    """The heatmap of ``images`` :math:`(B, 1, H, W)` as float32 :math:`(B, 1, H, W)`, run the fast way for the device.

    On CPU the network runs channels-last (oneDNN's fast layout); with ``precision="bfloat16"`` (or ``"auto"`` on a
    CPU with native bfloat16, :func:`cpu_has_native_bf16`) its convolutions run in bfloat16 under autocast. On other
    devices it runs as it is (float32; ``"bfloat16"`` autocasts there too). Inputs of more than ``tile_pixels`` pixels
    (``None``: never) run in tiles of :data:`TILE_SIDE` px with :data:`TILE_MARGIN` px of context, aligned to the
    network's pooling grid, and batches of more pixels a few images at a time, so memory stays bounded whatever the
    size (the network's normalisation must be per pixel at inference, as batch norm is, for the tiles to agree with
    the whole). On CPU, batches of more than ``batch_pixels`` pixels (``None``: never) run a few whole images at a
    time (:data:`BATCH_PIXELS`: faster, the same heatmaps).

    Example:
        >>> net = CornerUNet().eval()
        >>> run_heatmap(net, torch.rand(1, 1, 32, 48)).shape
        torch.Size([1, 1, 32, 48])
    """
    if images.device.type == "cpu":
        # converted once (re-applying ``to`` walks every module on every call)
        if not all(p.is_contiguous(memory_format=torch.channels_last) for p in net.parameters() if p.dim() == 4):
            net.to(memory_format=torch.channels_last)
    b, _, h, w = images.shape
    # a batch of more pixels than a tile runs a few images at a time (the memory of many one-megapixel views at
    # once), and on CPU one of more than ``batch_pixels`` too (the cache); the images do not interact, so the
    # heatmaps are the same
    limits = [p for p in (tile_pixels, batch_pixels if images.device.type == "cpu" else None) if p is not None]
    if b > 1 and limits and b * h * w > min(limits):
        # as few chunks as the limit allows, of sizes differing by one at most (8 levels of 240x320: 4 + 4, not 7 + 1)
        chunks = math.ceil(b / max(1, min(limits) // (h * w)))
        return torch.cat([run_heatmap(net, part, precision, tile_pixels, batch_pixels)
                          for part in images.tensor_split(chunks)])
    if tile_pixels is None or b * h * w <= tile_pixels:
        return _run_whole(net, images, precision)
    out = torch.empty(images.shape[0], 1, h, w, dtype=torch.float32, device=images.device)
    for y0 in range(0, h, TILE_SIDE):
        for x0 in range(0, w, TILE_SIDE):
            y1, x1 = min(y0 + TILE_SIDE, h), min(x0 + TILE_SIDE, w)
            ya, xa = max(0, y0 - TILE_MARGIN), max(0, x0 - TILE_MARGIN)
            heat = _run_whole(net, images[..., ya:min(h, y1 + TILE_MARGIN), xa:min(w, x1 + TILE_MARGIN)], precision)
            out[..., y0:y1, x0:x1] = heat[..., y0 - ya:y1 - ya, x0 - xa:x1 - xa]
    return out


def _run_whole(net: nn.Module, images: torch.Tensor, precision: str) -> torch.Tensor:
    """:func:`run_heatmap` on the whole input at once."""
    low = effective_precision(precision, images.device) == "bfloat16"
    if images.device.type == "cpu":
        images = images.contiguous(memory_format=torch.channels_last)
    if low:
        with torch.autocast(images.device.type, dtype=torch.bfloat16):
            heat = net(images)
    else:
        heat = net(images)
    return heat.float().contiguous()
