"""The image files a command line names (files, folders, globs): none is an error, an item that names none is a
warning."""

from __future__ import annotations

from collections.abc import Sequence

from ccs_kornia.commands._printing import warn
from ccs_kornia.io.images import expand_inputs
from ccs_kornia.runtime.errors import UserError

__all__ = ["inputs"]


def inputs(command: str, items: Sequence[str]) -> list[str]:
    """The image files of ``items`` in order (:func:`~ccs_kornia.io.images.expand_inputs`); a :class:`UserError` when
    there are none, a warning per item that gave none."""
    files, problems = expand_inputs(items)
    if not files:
        detail = "; ".join(f"{item}: {reason}" for item, reason in problems) or "nothing given"
        raise UserError(f"no images found ({detail})")
    for item, reason in problems:
        warn(command, f"{item}: {reason}")
    return files
