"""Pieces shared by the LightningModules."""

from __future__ import annotations

import torch

__all__ = ["adamw_one_cycle"]


def adamw_one_cycle(module, lr: float, weight_decay: float, pct_start: float = 0.05) -> dict:
    """AdamW with a per-step one-cycle schedule over the trainer's planned steps."""
    opt = torch.optim.AdamW(module.parameters(), lr=lr, weight_decay=weight_decay)
    trainer = getattr(module, "_trainer", None)
    total = trainer.estimated_stepping_batches if trainer is not None else 10_000
    if not isinstance(total, int) or total <= 0 or total > 10**8:
        total = 10_000  # unbounded training (max_steps=-1): a long default cycle
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=total, pct_start=pct_start)
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
