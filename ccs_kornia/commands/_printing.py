"""Where the commands' messages go: warnings and progress notes on stderr, each warning naming the program and the
command (``ccs_kornia calibrate: warning: ...``); results go to stdout."""

from __future__ import annotations

import sys

__all__ = ["PROG", "info", "warn"]

#: the program's name in every message
PROG = "ccs_kornia"


def warn(command: str, message: str) -> None:
    """``ccs_kornia COMMAND: warning: MESSAGE`` on stderr."""
    print(f"{PROG} {command}: warning: {message}", file=sys.stderr)


def info(message: str) -> None:
    """A note on stderr (what the command saw or chose), without the program's name."""
    print(message, file=sys.stderr)
