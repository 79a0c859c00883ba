"""Export a Lightning checkpoint to the small weight file shipped in ``ccs_kornia/weights/``.

    python -m ccs_kornia.training.export runs/detector/checkpoints/last.ckpt ccs_kornia/weights/corner_unet.pt
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

__all__ = ["export_checkpoint"]


def export_checkpoint(ckpt_path: str | Path, out_path: str | Path) -> dict:
    """Load a detector (also an end-to-end fine-tune) or distortion checkpoint and write its network config and weights only."""
    ckpt = torch.load(str(ckpt_path), map_location="cpu", weights_only=False)
    if any(k.startswith("net.encoder.") for k in ckpt.get("state_dict", {})):
        from ccs_kornia.training.distortion import DistortionLitModule as lit_class
    elif "heatmap_views" in ckpt.get("hyper_parameters", {}):  # the end-to-end fine-tune of the detector
        from ccs_kornia.training.end_to_end import EndToEndLitModule as lit_class
    else:
        from ccs_kornia.training.detector import DetectorLitModule as lit_class
    module = lit_class.load_from_checkpoint(str(ckpt_path), map_location="cpu")
    payload = module.export()
    payload["trained_steps"] = int(ckpt.get("global_step", -1))
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(payload, out)
    return payload


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint")
    parser.add_argument("output")
    args = parser.parse_args(argv)
    payload = export_checkpoint(args.checkpoint, args.output)
    n = sum(v.numel() for v in payload["state_dict"].values())
    print(f"wrote {args.output}: {payload['kind']} {payload['config']}, {n} values, step {payload['trained_steps']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
