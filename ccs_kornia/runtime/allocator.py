"""Keep freed memory in the process for the next tensor of that size, instead of handing it back at every free.

glibc serves allocations above a threshold (128 KiB at first, then raised to the largest size freed) by mapping fresh
pages and unmaps them when freed, and hands the heap's free top back once it exceeds twice that threshold: such a
tensor pays a page fault per 4 KiB page, the kernel zeroing each page, on its first write. The detector and
the refiners allocate thousands of short-lived tensors of a few MB (one batch's regions, windows, index arrays): on
real photographs many page faults per refinement pass, none with these settings, and the learned detector faster
with the same corners (``docs/measurements.md``; a float64 solve can differ in its 15th digit,
as between any two runs). The command line
applies them at start (the process is ours); library users may call :func:`keep_freed_memory` in their own program,
or not.
"""

from __future__ import annotations

import ctypes
import sys

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "keep_freed_memory"]

#: allocations below this come from the process's heap, reused once freed (glibc's largest allowed value, 32 MiB)
MMAP_THRESHOLD = 32 << 20
#: free memory at the top of the heap kept by the process before it is returned to the system
TRIM_THRESHOLD = 1 << 30

# glibc's mallopt parameter numbers (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory(mmap_threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD) -> bool:
    """Set the C allocator's thresholds for this process (glibc's ``mallopt``); elsewhere, nothing.

    The memory a run holds at its peak stays with the process until it exits (up to ``trim_threshold`` free bytes),
    which suits a command that runs one job and ends.

    Args:
        mmap_threshold: allocations of at least this many bytes are mapped, and unmapped when freed.
        trim_threshold: free bytes at the top of the heap that trigger returning memory to the system.

    Returns:
        Whether the allocator took both settings (False off Linux, or with a C library without ``mallopt``).

    Example:
        >>> keep_freed_memory() in (True, False)
        True
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library this process runs on
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))) & bool(mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))
