"""Keep freed tensor memory in the process instead of handing it back to the OS after every step.

glibc serves large allocations with fresh mappings (above an mmap threshold that adapts upward
from 128 kB) and trims the freed top of its heap back to the OS (above twice that threshold), so
many of the 4-8 MB activations of a training step or of a 240 x 320 inference are page-faulted in
again, page by page, at every step (tests/model/test_allocator.py counts the faults). Raising the
mmap threshold to 32 MB and the trim threshold to 1 GB lets the heap reuse the freed blocks: the
process keeps its peak memory instead of returning it between steps. The arithmetic is unchanged;
only where memory comes from. No-op where the C library has no `mallopt` (not glibc). Measured by
benchmarks/bench_allocator.py (docs/explanation/models.md).
"""

from __future__ import annotations

import ctypes
import logging

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's own ceiling for the adaptive threshold
TRIM_THRESHOLD_BYTES = 1024 * 1024 * 1024

_done: bool | None = None


def reuse_freed_memory() -> bool:
    """Set glibc's thresholds once per process; True when they are in force."""
    global _done
    if _done is not None:
        return _done
    _done = False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        mallopt = None
    if mallopt is not None:
        mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
        _done = bool(
            mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
            and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
        )
    if not _done:
        logging.getLogger(__name__).debug("mallopt unavailable: allocator left as it is")
    return _done
