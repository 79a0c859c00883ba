"""Fixtures shared by every test: the devices and dtypes the stage tests run on.

``device``: ``cpu`` always, ``cuda`` too where ``torch.cuda.is_available()``; ``dtype``: float32 and float64.
A test takes them as arguments; it then runs once per device (and dtype), so the batched stages are checked on
the GPU wherever one is present.
"""

from __future__ import annotations

import os

# sleeping OpenMP waits (see ccs_kornia/__main__.py): on shared cores a spinning pool makes every small tensor op
# wait for a time slice; read when torch loads, so before the import below
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest  # noqa: E402
import torch  # noqa: E402

# run by pytest-xdist (``-n N``), the workers share the machine's cores: each worker's torch pool gets its share, as
# an oversubscribed pool waits for time slices
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
if _WORKERS > 1:
    torch.set_num_threads(max(1, (os.cpu_count() or 1) // _WORKERS))

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
DTYPES = [torch.float32, torch.float64]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    """The device a stage test runs on (cpu, and cuda when present)."""
    return torch.device(request.param)


@pytest.fixture(params=DTYPES, ids=["float32", "float64"])
def dtype(request) -> torch.dtype:
    """The floating dtype a stage test runs in (float32 and float64)."""
    return request.param
