"""Where the real photograph sets are: ``$CCS_REAL_DATA``, else ``../shared/data/real`` beside the repository.

The default is the layout CI uses; from a git worktree elsewhere, point ``CCS_REAL_DATA`` at the sets so the
real-data tests run instead of being skipped.
"""

from __future__ import annotations

import os
from pathlib import Path

REAL_DATA = Path(os.environ.get("CCS_REAL_DATA") or Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real")
