"""``python -m ccs_kornia fit|validate|test|predict --config lightning_configs/<x>.yaml`` (LightningCLI)."""

from __future__ import annotations

from lightning.pytorch.cli import LightningCLI

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Run LightningCLI with the given arguments (subcommand first), model/data as class paths."""
    LightningCLI(
        subclass_mode_model=True,
        subclass_mode_data=True,
        save_config_kwargs={"overwrite": True},
        args=argv,
    )
    return 0
