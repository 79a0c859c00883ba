"""Errors a user can fix, and the exit statuses of the command line: raised by any layer, reported in one line.

A :class:`UserError` stops a command with exit status 2 and one line on stderr (no traceback); :class:`NoResult` (exit
status 3) says the inputs were read but gave no result. Any layer may raise them: the command line reports them.
"""

from __future__ import annotations

from typing import Any

__all__ = ["EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_NO_RESULT", "EXIT_OK", "EXIT_USAGE", "NoResult", "UserError"]

#: exit statuses of the command line (``--help`` lists them, ``docs/command_line.md`` explains them)
EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_NO_RESULT = 3
EXIT_INTERRUPTED = 130


class UserError(Exception):
    """A mistake in the user's input that stops the command (exit status :data:`EXIT_USAGE`).

    ``partial`` may hold what was computed before the job had to stop (written by the command).
    """

    partial: dict[str, Any] | None = None
    exit_code: int = EXIT_USAGE


class NoResult(UserError):
    """The inputs were read but gave no result: the board was found in no image, or no calibration could be computed
    from the views (exit status :data:`EXIT_NO_RESULT`)."""

    exit_code = EXIT_NO_RESULT
