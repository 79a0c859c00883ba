"""The compute floor of the networks and the per-stage profile of the default path (bench section 5).

* :func:`network_flops`: FLOPs of one forward pass (``torch.utils.flop_counter``: convolutions and matrix products;
  normalisation, activations, pooling and resampling are memory-bound and not counted).
* :func:`conv_rate`: the machine's measured GFLOP/s on a plain stack of convolutions of the heatmap UNet's shapes
  (channels-last, float32, the current thread count), so that ``FLOPs / rate`` is the time the network would take
  if every layer ran at the speed of a bare convolution: the floor a network time is compared with.
* :func:`compute_floors`: both networks' FLOPs per image (the heatmap UNet at the detection level that scale
  selection picks for the given images and at full resolution, the DistortionNet at its input size) and their
  floor times.
* :func:`profile_default_path`: exclusive wall time per stage (:mod:`ccs_kornia.modules._timing`) of the default
  :class:`~ccs_kornia.pipeline.CalibrationPipeline` (learned detector, distortion correction on) on image files.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections import Counter

import numpy as np
import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

__all__ = ["network_flops", "conv_rate", "compute_floors", "profile_default_path", "STAGE_ORDER"]

#: the stages of the default path, in the order they run (names of :func:`ccs_kornia.modules._timing.stage`)
STAGE_ORDER: tuple[str, ...] = (
    "image loading", "distortion network", "square-size estimate", "level resize", "heatmap network",
    "peaks + Gaussian fit + sigma rejection", "X-junction check", "grid organiser", "missing corners",
    "saddle refinement", "correction evidence", "solver",
)


def network_flops(net: nn.Module, shape: tuple[int, ...]) -> int:
    """FLOPs of one forward pass of ``net`` on a zero-filled input of ``shape`` (a multiply-add counts 2)."""
    x = torch.zeros(shape)
    with FlopCounterMode(display=False) as counter, torch.inference_mode():
        net(x)
    return int(counter.get_total_flops())


class _ConvStack(nn.Module):
    """Bare 3x3 convolutions + ReLU of the heatmap UNet's widths at its relative resolutions."""

    def __init__(self) -> None:
        super().__init__()
        self.a = nn.Conv2d(8, 8, 3, padding=1)
        self.b = nn.Conv2d(16, 16, 3, padding=1)
        self.c = nn.Conv2d(32, 32, 3, padding=1)
        self.d = nn.Conv2d(24, 8, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = torch.relu(self.a(x))
        z = torch.relu(self.b(torch.cat([y, y], 1)[:, :, ::2, ::2]))
        w = torch.relu(self.c(torch.cat([z, z], 1)[:, :, ::2, ::2]))
        return torch.relu(self.d(torch.cat([y, y, y], 1))) + w.mean()


def conv_rate(size: tuple[int, int] = (240, 320), batch: int = 4, repeats: int = 3) -> dict:
    """The machine's GFLOP/s on :class:`_ConvStack` (channels-last float32, ``torch.get_num_threads()`` threads).

    Returns:
        ``{"gflops": best rate, "flops": per call, "seconds": best time, "input": [B, 8, H, W]}``.
    """
    torch.manual_seed(0)
    net = _ConvStack().eval().to(memory_format=torch.channels_last)
    x = torch.rand(batch, 8, *size).contiguous(memory_format=torch.channels_last)
    with FlopCounterMode(display=False) as counter, torch.inference_mode():
        net(x)
    flops = int(counter.get_total_flops())
    best = float("inf")
    with torch.inference_mode():
        net(x)
        for _ in range(max(1, repeats)):
            t = time.perf_counter()
            net(x)
            best = min(best, time.perf_counter() - t)
    return {"gflops": flops / best / 1e9, "flops": flops, "seconds": best, "input": [batch, 8, *size]}


def compute_floors(images: torch.Tensor, rate_gflops: float) -> dict:
    """FLOPs per image and floor times of the shipped networks for ``images`` :math:`(B, 1, H, W)`.

    The heatmap UNet is counted at each image's detection level (:class:`~ccs_kornia.modules.detection.scale.
    ScaleSelector` of the shipped detector) and at full resolution; the DistortionNet at its input size.
    """
    from ccs_kornia.modules.correction.distortion_net import load_distortion_net
    from ccs_kornia.modules.detection.learned_detector import LearnedChessboardDetector
    from ccs_kornia.modules.detection.patch_refine import level_size

    det = LearnedChessboardDetector()
    h, w = images.shape[-2:]
    with torch.inference_mode():
        _, factor = det.scale_selector(images.float())
    levels = Counter(level_size((w, h), float(f)) for f in factor.tolist())
    per_level = {lv: network_flops(det.net, (1, 1, *lv)) for lv in levels}
    level_flops = sum(per_level[lv] * n for lv, n in levels.items()) / max(1, images.shape[0])
    full_flops = network_flops(det.net, (1, 1, h, w))
    out = {
        "rate_gflops": rate_gflops,
        "image_size": [int(w), int(h)],
        "unet_levels": {f"{lv[1]}x{lv[0]}": n for lv, n in sorted(levels.items(), reverse=True)},
        "unet_gflop_level": level_flops / 1e9,
        "unet_gflop_full": full_flops / 1e9,
        "unet_floor_ms_level": level_flops / rate_gflops / 1e6,
        "unet_floor_ms_full": full_flops / rate_gflops / 1e6,
    }
    try:
        dnet = load_distortion_net(True)
        size = dnet.input_size
        # the network on its letterboxed input (image, mask, x, y); the letterbox itself is preprocessing
        flops = network_flops(nn.Sequential(dnet.encoder, dnet.pool, dnet.head), (1, 4, size, size))
        out.update({"distortion_input": size, "distortion_gflop": flops / 1e9,
                    "distortion_floor_ms": flops / rate_gflops / 1e6})
    except FileNotFoundError as err:
        out["distortion_skipped"] = str(err)
    return out


def _write_pngs(images: torch.Tensor, folder: str) -> list[str]:
    import cv2

    paths = []
    for i, im in enumerate(images):
        path = os.path.join(folder, f"view{i:03d}.png")
        cv2.imwrite(path, np.clip(np.rint(im[0].float().cpu().numpy() * 255.0), 0, 255).astype(np.uint8))
        paths.append(path)
    return paths


def profile_default_path(images: torch.Tensor, board: tuple[int, int], square: float, repeats: int = 2,
                         distortion_weights=True, device: str = "cpu") -> dict:
    """Per-stage exclusive wall time of the default pipeline on ``images`` :math:`(V, 1, H, W)` written as PNG files.

    One warm-up run, then ``repeats`` profiled runs; the run with the shortest wall time is reported.

    Returns:
        ``{"wall_s", "views", "stages": [{"stage", "seconds", "share", "calls"}, ...], "found"}``.
    """
    from ccs_kornia.modules._timing import StageProfile
    from ccs_kornia.pipeline import CalibrationPipeline
    from ccs_kornia.sources import FileSource

    pipe = CalibrationPipeline("learned", distortion_correction=distortion_weights).to(device)
    best = None
    with tempfile.TemporaryDirectory() as folder:
        source = FileSource([_write_pngs(images, folder)])
        with torch.inference_mode():
            out = pipe.run(source, board, square)
            for _ in range(max(1, repeats)):
                with StageProfile() as prof:
                    out = pipe.run(source, board, square)
                if best is None or prof.wall < best.wall:
                    best = prof
    rank = {name: k for k, name in enumerate(STAGE_ORDER)}
    rows = [{"stage": name, "seconds": sec, "share": share, "calls": calls} for name, sec, share, calls in best.table()]
    rows.sort(key=lambda r: rank.get(r["stage"], len(rank)))
    return {"wall_s": best.wall, "views": int(images.shape[0]), "stages": rows,
            "found": int(out.found.sum()), "success": bool(out.success.all())}
