"""``--device``: the torch device a command runs on, refused at once where this machine has none of it."""

from __future__ import annotations

import torch

from ccs_kornia.runtime.errors import UserError

__all__ = ["resolve_device"]


def resolve_device(text: str):
    """The :class:`torch.device` of ``--device`` (``cpu``, ``cuda``, ``cuda:N``); a :class:`UserError` where CUDA or
    that GPU is not there."""
    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            raise UserError(f"--device {text} requested but CUDA is not available on this machine; use --device cpu")
        index = int(text[5:]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise UserError(f"--device {text}: only {torch.cuda.device_count()} CUDA device(s) present")
    return torch.device(text)
