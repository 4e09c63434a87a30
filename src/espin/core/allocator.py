"""glibc's allocator in worker processes: keep freed numpy temporaries instead of unmapping them.

glibc serves an allocation above its mmap threshold (128 KiB at start) with a fresh ``mmap``,
whose pages fault in one by one when written, and unmaps it on free. By default the
threshold adapts: once such a block is freed, blocks of its size come from the heap and are
reused. Setting any ``MALLOC_*`` tuning variable disables that adaptation, and Dask's nanny
sets ``MALLOC_TRIM_THRESHOLD_=65536`` in every worker, so there every numpy temporary over
128 KiB is mapped, faulted in and unmapped again: plla-size tensile tests ran 2.1-2.2 times
slower on Dask workers than on local process workers (3.8 million minor page faults against
6 thousand at 16k DOF).

:func:`keep_freed_memory` fixes both thresholds, so that temporaries up to 32 MiB are reused
from the heap and at most 64 MiB of free heap top is kept, whatever the environment says.
The task pool calls it in every worker process before the first task.
"""

from __future__ import annotations

import ctypes
import logging
import platform
import sys
from functools import cache

__all__ = ["MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "keep_freed_memory"]

log = logging.getLogger(__name__)

MMAP_THRESHOLD_BYTES = 32 * 2**20
"""Blocks up to this size come from the heap (glibc's adaptive threshold stops here too)."""
TRIM_THRESHOLD_BYTES = 64 * 2**20
"""Free memory at the heap top kept for reuse before it is given back to the system."""

_M_TRIM_THRESHOLD = -1  # mallopt parameters, from glibc's malloc.h
_M_MMAP_THRESHOLD = -3


@cache
def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds in this process (once); False where not glibc.

    Returns
    -------
    bool
        True if both thresholds were set.
    """
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        done = (
            libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
            and libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
        )
    except (OSError, AttributeError):  # no libc.so.6 or no mallopt: leave the allocator alone
        done = False
    if not done:
        log.debug("could not set glibc's malloc thresholds; numpy temporaries may be slow")
    return done
