import ctypes
import subprocess
import sys

import pytest

from ccs_kornia.runtime.allocator import keep_freed_memory


def _has_mallopt() -> bool:
    try:
        return sys.platform.startswith("linux") and hasattr(ctypes.CDLL(None), "mallopt")
    except OSError:
        return False


# a fresh interpreter (the settings are per process): page faults of ten rounds of three 8 MiB tensors written and
# freed together, after one warm-up round, under this module's settings or under glibc's starting thresholds made
# fixed (128 KiB: every such tensor mapped afresh and unmapped when freed, as the detector's regions were; glibc's own
# adaptive default lies in between and depends on the address layout, so it is not what is compared)
_FAULTS = """
import resource, sys, torch
from ccs_kornia.runtime.allocator import keep_freed_memory
took = keep_freed_memory() if sys.argv[1] == "keep" else keep_freed_memory(128 << 10, 128 << 10)
def cycle():
    for _ in range(10):
        xs = [torch.empty(2 << 20).fill_(1.0) for _ in range(3)]
        del xs
cycle()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
cycle()
print(took, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", _FAULTS, mode], capture_output=True, text=True, check=True)
    took, faults = out.stdout.split()
    return took, int(faults)


@pytest.mark.skipif(not _has_mallopt(), reason="needs a C library with mallopt (glibc on Linux)")
def test_freed_memory_is_reused_without_page_faults():
    took, kept = _faults("keep")
    assert took == "True"
    # 3 x 8 MiB written ten times is 61,440 pages: reused memory faults none of them again
    assert kept < 500
    took, mapped = _faults("map")
    assert took == "True"
    assert mapped > 50_000  # each tensor's pages faulted in again, every round


def test_keep_freed_memory_says_whether_it_applied():
    # (this process gets the command line's settings, which the CLI tests give it anyway)
    assert keep_freed_memory() is (_has_mallopt())
