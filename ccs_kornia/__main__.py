"""``python -m ccs_kornia ...``: see :mod:`ccs_kornia.cli`."""

from __future__ import annotations

import os

# OpenMP threads that spin while they wait for work take the CPU from the thread doing it when other processes share
# the cores (docs/measurements.md). Read once, when torch loads; an explicit setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from ccs_kornia.cli import run  # noqa: E402

if __name__ == "__main__":
    run()
