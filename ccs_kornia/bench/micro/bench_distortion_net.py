"""Speed of the distortion-correction network (``DistortionNet``): parameters and ms per 640x480 image on the CPU.

Best of ``--repeats`` single-image calls in eval mode (the test machine's cores are shared, so the fastest run is
the network's own cost; this used to be a timing assert in the tests).

    python -m ccs_kornia.bench.micro.bench_distortion_net
    python -m ccs_kornia.bench.micro.bench_distortion_net --device cuda --batch 16
"""

from __future__ import annotations

import argparse
import time

import torch

from ccs_kornia.modules.correction.distortion_net import DistortionNet


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    device = torch.device(args.device)
    net = DistortionNet().eval().to(device)
    x = torch.rand(args.batch, 1, 480, 640, device=device)
    times = []
    with torch.no_grad():
        net(x)
        for _ in range(args.repeats):
            if device.type == "cuda":
                torch.cuda.synchronize(device)
            t0 = time.perf_counter()
            net(x)
            if device.type == "cuda":
                torch.cuda.synchronize(device)
            times.append(time.perf_counter() - t0)
    ms = min(times) * 1e3 / args.batch
    print(f"DistortionNet: {net.num_parameters()} parameters, {ms:.1f} ms per 640x480 image on {device} "
          f"(batch {args.batch}, best of {args.repeats})")


if __name__ == "__main__":
    main()
