"""Speed of the corner UNet and of the sub-pixel stages (peaks, Gaussian fit, sigma rejection).

Prints the parameter count and images/s of ``CornerUNet`` at 640x480 for batch 1 and 8 (inference mode), then
images/s of the sub-pixel stages on a synthetic 9x6-corner heatmap.

    python -m ccs_kornia.bench.micro.bench_unet                       # CPU, shipped default net
    python -m ccs_kornia.bench.micro.bench_unet --device cuda --batches 1 8 32
    python -m ccs_kornia.bench.micro.bench_unet --base-channels 16 --compile
"""

from __future__ import annotations

import argparse
import time

import torch

from ccs_kornia.modules.detection.learned.gaussian_fit import gaussian_fit
from ccs_kornia.modules.detection.learned.heatmap_unet import CornerUNet
from ccs_kornia.modules.detection.learned.peaks import heatmap_peaks
from ccs_kornia.modules.detection.learned.sigma_rejection import sigma_outlier_rejection


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _time(fn, device: torch.device, warmup: int, repeats: int) -> float:
    """Median seconds per call."""
    for _ in range(warmup):
        fn()
    _sync(device)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - start)
    return sorted(times)[len(times) // 2]


def _synthetic_heatmap(batch: int, height: int, width: int, device: torch.device) -> torch.Tensor:
    """Heatmaps with 9x6 unit Gaussians (sigma 1.5) at sub-pixel positions, plus mild noise."""
    gen = torch.Generator().manual_seed(0)
    gx, gy = torch.meshgrid(torch.arange(9), torch.arange(6), indexing="xy")
    grid = torch.stack([gx, gy], -1).reshape(-1, 2).float() * 50 + torch.tensor([120.0, 110.0])
    mu = grid[None] + 5 * torch.rand(batch, 54, 2, generator=gen)
    ys, xs = torch.meshgrid(torch.arange(height).float(), torch.arange(width).float(), indexing="ij")
    heat = torch.zeros(batch, 1, height, width)
    for n in range(54):  # setup only, not timed
        d2 = (xs - mu[:, n, 0, None, None]) ** 2 + (ys - mu[:, n, 1, None, None]) ** 2
        heat = torch.maximum(heat, torch.exp(-d2 / 4.5)[:, None])
    heat = (heat + 0.01 * torch.randn(heat.shape, generator=gen)).clamp(0, 1)
    return heat.to(device)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--base-channels", type=int, default=8)
    parser.add_argument("--depth", type=int, default=4)
    parser.add_argument("--norm", default="batch")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--compile", action="store_true", help="torch.compile the UNet (inductor) first")
    parser.add_argument("--channels-last", action="store_true", help="NHWC weights and activations")
    parser.add_argument("--half", action="store_true", help="float16 autocast (CUDA only)")
    args = parser.parse_args()

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    net = CornerUNet(base_channels=args.base_channels, depth=args.depth, norm=args.norm).to(device).eval()
    params = sum(p.numel() for p in net.parameters())
    memory_format = torch.channels_last if args.channels_last else torch.contiguous_format
    net = net.to(memory_format=memory_format)
    model = torch.compile(net) if args.compile else net
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu, {torch.get_num_threads()} threads"
    print(f"CornerUNet base={args.base_channels} depth={args.depth} norm={args.norm}: {params:,} parameters")
    print(
        f"device: {name}; torch {torch.__version__}; input {args.width}x{args.height}; "
        f"compile={args.compile}; channels_last={args.channels_last}"
    )

    for batch in args.batches:
        image = torch.rand(batch, 1, args.height, args.width, device=device).contiguous(memory_format=memory_format)

        def forward() -> torch.Tensor:
            with torch.inference_mode(), torch.autocast(device.type, torch.float16, enabled=args.half):
                return model(image)

        seconds = _time(forward, device, args.warmup + (2 if args.compile else 0), args.repeats)
        print(f"  UNet     batch {batch:3d}: {seconds * 1e3:9.1f} ms/batch  {batch / seconds:9.1f} images/s")

    for batch in args.batches:
        heat = _synthetic_heatmap(batch, args.height, args.width, device)

        def subpixel() -> torch.Tensor:
            with torch.inference_mode():
                seeds, _, mask = heatmap_peaks(heat, threshold=0.3, max_peaks=256)
                _, sigma, ok = gaussian_fit(heat, seeds, mask)
                return sigma_outlier_rejection(sigma, mask & ok, 1.5, 0.5)

        kept = subpixel()
        seconds = _time(subpixel, device, args.warmup, args.repeats)
        print(
            f"  subpixel batch {batch:3d}: {seconds * 1e3:9.1f} ms/batch  {batch / seconds:9.1f} images/s"
            f"  ({kept.sum().item() / batch:.0f} of 54 corners kept per image)"
        )


if __name__ == "__main__":
    main()
