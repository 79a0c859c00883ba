"""``--model``: the names the command line gives, read as camera models (or ``auto``'s model choice)."""

from __future__ import annotations

import argparse

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.modules.calibration.model_selection import ModelChoice, model_or_choice
from ccs_kornia.runtime.errors import UserError

__all__ = ["parse_models", "resolve_model"]


def resolve_model(args: argparse.Namespace) -> None:
    """``args.model``'s name becomes the model (or ``auto``'s choice), where a command takes one model (a rig's list,
    one per camera, is read by :func:`parse_models`)."""
    if isinstance(getattr(args, "model", None), str) and args.command != "calibrate-rig":
        args.model = model_or_choice(args.model)


def parse_models(text: str, cameras: int, choices: tuple[str, ...]) -> list[CameraModel | ModelChoice]:
    """``--model``: one model for every camera or one per camera, comma-separated; each name read as its model (or
    ``auto`` as the automatic choice).

    Example:
        >>> [str(m) for m in parse_models("auto", 2, ("auto", "k1k2"))]
        ['auto', 'auto']
        >>> parse_models("k1k2,auto", 2, ("auto", "k1k2"))[0]
        OpenCVModel('k1k2')
    """
    names = [m.strip() for m in text.split(",")]
    bad = [m for m in names if m not in choices]
    if bad:
        raise UserError(f"--model {text}: unknown model {bad[0]!r} (choose from {', '.join(choices)})")
    if len(names) == 1:
        names = names * cameras
    if len(names) != cameras:
        raise UserError(f"--model {text}: {len(names)} models for {cameras} cameras (give one, or one per camera)")
    return [model_or_choice(n) for n in names]
