"""Where the real photograph sets are: ``$CCS_REAL_DATA``, else ``shared/data/real`` beside the repository.

The default is the layout CI uses (``../shared`` beside the clone). A checkout further down (a git worktree in a
folder of worktrees) finds the nearest ``shared/data/real`` beside one of its parent folders, so the real-data tests
run there too instead of being skipped.
"""

from __future__ import annotations

import os
from pathlib import Path


def _beside_a_parent(root: Path) -> Path:
    """The first ``shared/data/real`` beside ``root`` or one of its parents (``root/../shared`` when none is)."""
    for folder in root.parents:
        candidate = folder / "shared" / "data" / "real"
        if candidate.is_dir():
            return candidate
    return root.parent / "shared" / "data" / "real"


REAL_DATA = Path(os.environ.get("CCS_REAL_DATA") or _beside_a_parent(Path(__file__).resolve().parents[1]))
