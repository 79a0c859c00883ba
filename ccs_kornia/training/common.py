"""Pieces shared by the LightningModules."""

from __future__ import annotations

import torch

__all__ = ["adamw_one_cycle", "load_exported_weights"]


def _plain(x):
    """Tuples as lists (a config read back from YAML or a file compares equal to the network's own)."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    return [_plain(v) for v in x] if isinstance(x, (list, tuple)) else x


def load_exported_weights(net: torch.nn.Module, path, kind: str, config: dict) -> None:
    """Load an exported weight file (:mod:`ccs_kornia.training.export`) into ``net`` (fine-tuning).

    Raises:
        ValueError: the file holds another network kind or configuration.
    """
    payload = torch.load(str(path), map_location="cpu", weights_only=True)
    if payload.get("kind") != kind or _plain(payload.get("config")) != _plain(config):
        raise ValueError(f"{path} holds {payload.get('kind')} {payload.get('config')}, expected {kind} {config}.")
    net.load_state_dict(payload["state_dict"])


def adamw_one_cycle(module, lr: float, weight_decay: float, pct_start: float = 0.05) -> dict:
    """AdamW with a per-step one-cycle schedule over the trainer's planned steps."""
    opt = torch.optim.AdamW(module.parameters(), lr=lr, weight_decay=weight_decay)
    trainer = getattr(module, "_trainer", None)
    total = trainer.estimated_stepping_batches if trainer is not None else 10_000
    if not isinstance(total, int) or total <= 0 or total > 10**8:
        total = 10_000  # unbounded training (max_steps=-1): a long default cycle
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=total, pct_start=pct_start)
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
