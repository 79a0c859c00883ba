"""The compute floor of the networks and the per-stage profile of the default path (bench section 5).

* :func:`network_flops`: FLOPs of one forward pass (``torch.utils.flop_counter``: convolutions and matrix products;
  normalisation, activations, pooling and resampling are memory-bound and not counted).
* :func:`conv_rate`: the machine's measured GFLOP/s on a plain stack of convolutions of the heatmap UNet's shapes
  (channels-last, float32, the current thread count), so that ``FLOPs / rate`` is the time the network would take
  if every layer ran at the speed of a bare convolution: the floor a network time is compared with.
* :func:`compute_floors`: both networks' FLOPs per image (the heatmap UNet at the detection level that scale
  selection picks for the given images and at full resolution, the DistortionNet at its input size) and their
  floor times.
* :func:`profile_default_path`: the wall time of the default :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline`
  (learned detector, distortion correction on) on image files as ``calibrate`` runs it (worker processes), and the
  exclusive wall time per stage (:mod:`ccs_kornia.runtime.timing`) of the same in one process.
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

__all__ = ["network_flops", "conv_rate", "compute_floors", "profile_detector", "profile_default_path", "end_to_end",
           "STAGE_ORDER", "CLI_BATCH_SIZE"]

#: the command line's ``--batch-size`` default (cli.py): views per batch, and per chunk of a worker process
CLI_BATCH_SIZE = 8

#: the stages of the default path, in the order they run (names of :func:`ccs_kornia.runtime.timing.stage`)
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


def conv_rate(size: tuple[int, int] = (240, 320), batch: int = 4, repeats: int = 3,
              dtype: torch.dtype = torch.float32) -> dict:
    """The machine's GFLOP/s on :class:`_ConvStack` (channels-last, ``torch.get_num_threads()`` threads), in
    ``dtype`` (float32, or bfloat16 under CPU autocast as the heatmap network runs on CPUs with native bfloat16).

    Returns:
        ``{"gflops": best rate, "flops": per call, "seconds": best time, "input": [B, 8, H, W], "dtype"}``.
    """
    torch.manual_seed(0)
    net = _ConvStack().eval().to(memory_format=torch.channels_last)
    x = torch.rand(batch, 8, *size).contiguous(memory_format=torch.channels_last)
    with FlopCounterMode(display=False) as counter, torch.inference_mode():
        net(x)
    flops = int(counter.get_total_flops())
    best = float("inf")
    low = dtype != torch.float32
    with torch.inference_mode(), torch.autocast("cpu", dtype=dtype, enabled=low):
        net(x)
        for _ in range(max(1, repeats)):
            t = time.perf_counter()
            net(x)
            best = min(best, time.perf_counter() - t)
    return {"gflops": flops / best / 1e9, "flops": flops, "seconds": best, "input": [batch, 8, *size],
            "dtype": str(dtype).replace("torch.", "")}


def compute_floors(images: torch.Tensor, rates: dict[str, float]) -> dict:
    """FLOPs per image and floor times of the shipped networks for ``images`` :math:`(B, 1, H, W)`.

    The heatmap UNet is counted at each image's detection level (:class:`~ccs_kornia.modules.detection.learned.scale.
    ScaleSelector` of the shipped detector) and at full resolution, the DistortionNet at its input size; each floor
    is ``FLOPs / rate`` for every measured rate of ``rates`` (``{"float32": GFLOP/s, "bfloat16": GFLOP/s}``).
    """
    from ccs_kornia.modules.correction.distortion_net import load_distortion_net
    from ccs_kornia.modules.detection.learned.heatmap_unet import effective_precision
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )
    from ccs_kornia.modules.detection.refine.patch_refine import level_size

    det = LearnedChessboardDetector()
    h, w = images.shape[-2:]
    with torch.inference_mode():
        _, factor = det.scale_selector(images.float())
    levels = Counter(level_size((w, h), float(f)) for f in factor.tolist())
    per_level = {lv: network_flops(det.net, (1, 1, *lv)) for lv in levels}
    gflop = {
        "unet_level": sum(per_level[lv] * n for lv, n in levels.items()) / max(1, images.shape[0]) / 1e9,
        "unet_full": network_flops(det.net, (1, 1, h, w)) / 1e9,
    }
    out: dict = {"image_size": [int(w), int(h)], "rates_gflops": dict(rates),
                 "unet_precision": effective_precision(det.precision, images.device),
                 "unet_levels": {f"{lv[1]}x{lv[0]}": n for lv, n in sorted(levels.items(), reverse=True)}}
    try:
        dnet = load_distortion_net(True)
        size = dnet.input_size
        # the network on its letterboxed input (image, mask, x, y); the letterbox itself is preprocessing
        gflop["distortion"] = network_flops(nn.Sequential(dnet.encoder, dnet.pool, dnet.head), (1, 4, size, size)) / 1e9
        out["distortion_input"] = [size, size]
    except FileNotFoundError as err:
        out["distortion_skipped"] = str(err)
    out["gflop_per_image"] = gflop
    out["floor_ms_per_image"] = {f"{k}@{dt}": 1000.0 * g / r for k, g in gflop.items() for dt, r in rates.items()}
    return out


def profile_detector(images: torch.Tensor, board: tuple[int, int], batch_sizes: tuple[int, ...] = (16, 1),
                     repeats: int = 2) -> dict:
    """Per-stage exclusive time of the shipped learned detector on ``images`` at each batch size (best of
    ``repeats`` after a warm-up): ``{batch: {"images_per_s", "stages": {stage: ms per image}}}``."""
    from ccs_kornia.modules.detection.learned.heatmap_unet import effective_precision
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )
    from ccs_kornia.runtime.timing import StageProfile

    det = LearnedChessboardDetector()
    n = images.shape[0]
    out: dict = {"precision": effective_precision(det.precision, images.device)}
    with torch.inference_mode():
        det(images[: min(n, max(batch_sizes))], board)
        for bs in batch_sizes:
            bs = min(bs, n)
            best = None
            for _ in range(max(1, repeats)):
                with StageProfile() as prof:
                    for i in range(0, n, bs):
                        det(images[i : i + bs], board)
                if best is None or prof.wall < best.wall:
                    best = prof
            out[str(bs)] = {"images_per_s": n / best.wall,
                            "stages": {k: 1000 * v / n for k, v, _, _ in best.table()}}
    return out


def end_to_end(folder: str, board: tuple[int, int], timeout: float = 600.0) -> dict:
    """Wall time of ``python -m ccs_kornia calibrate FOLDER --board CxR --output ...`` in a fresh interpreter (what
    a user waits for: start-up and imports included), and the command's own timing from its JSON."""
    import json
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        out_json = os.path.join(tmp, "calib.json")
        cmd = [sys.executable, "-m", "ccs_kornia", "calibrate", folder, "--board", f"{board[0]}x{board[1]}",
               "--output", out_json]
        t = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        wall = time.perf_counter() - t
        result = {"command": " ".join(["python", *cmd[1:-1], "OUT.json"]), "wall_s": wall, "returncode": proc.returncode}
        if proc.returncode == 0 and os.path.isfile(out_json):
            data = json.load(open(out_json))
            result.update({"views_used": data.get("num_views"), "rms": data.get("rms"),
                           "pipeline_s": (data.get("timings") or {}).get("total_s")})
        else:
            result["error"] = proc.stderr[-500:]
    return result


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
    """Wall time of the default pipeline on ``images`` :math:`(V, 1, H, W)` written as PNG files, as ``calibrate`` runs
    it (``--batch-size`` :data:`CLI_BATCH_SIZE`, ``--jobs auto``: worker processes on CPU), and the exclusive time per
    stage of the same run in one process (a worker's stages are not seen by the profile).

    One warm-up run each, then ``repeats`` timed runs each; the shortest wall time is reported.

    Returns:
        ``{"wall_s", "workers", "serial_wall_s", "views", "stages": [{"stage", "seconds", "share", "calls"}, ...]
        (one process), "found", "success"}``.
    """
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
    from ccs_kornia.pipeline.sources import FileSource
    from ccs_kornia.pipeline.workers import default_workers
    from ccs_kornia.runtime.timing import StageProfile

    workers = default_workers(device)
    best: dict = {}
    with tempfile.TemporaryDirectory() as folder:
        source = FileSource([_write_pngs(images, folder)])
        for n in dict.fromkeys((workers, 1)):
            pipe = CalibrationPipeline("learned", distortion_correction=distortion_weights,
                                       detection_batch_size=CLI_BATCH_SIZE, workers=n).to(device)
            with torch.inference_mode():
                out = pipe.run(source, board, square)
                for _ in range(max(1, repeats)):
                    with StageProfile() as prof:
                        out = pipe.run(source, board, square)
                    if n not in best or prof.wall < best[n].wall:
                        best[n] = prof
    rank = {name: k for k, name in enumerate(STAGE_ORDER)}
    rows = [{"stage": name, "seconds": sec, "share": share, "calls": calls} for name, sec, share, calls in best[1].table()]
    rows.sort(key=lambda r: rank.get(r["stage"], len(rank)))
    return {"wall_s": best[workers].wall, "workers": workers, "serial_wall_s": best[1].wall, "batch_size": CLI_BATCH_SIZE,
            "views": int(images.shape[0]), "stages": rows,
            "found": int(out.found.sum()), "success": bool(out.success.all())}
