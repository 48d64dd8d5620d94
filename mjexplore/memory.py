"""Keeping a long run's memory bounded.

Maps of millions of cells make every decision allocate and free multi-megabyte temporaries
(masks, distance fields). glibc's malloc raises its mmap threshold after each large free
(up to 32 MB), after which such blocks come from the heap, where fragmentation keeps them:
a 100 x 100 m office episode grew from 1.7 to 2.9 GB resident by its end
(tools/bench_long_episode.py). Fixing the threshold at 128 KiB (which also turns off the
dynamic adjustment) returns every large block to the system when freed: the same episode
peaked at 1.0 GB. No-op where the C library is not glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
THRESHOLD_BYTES = 128 * 1024


def bound_heap_growth() -> bool:
    """Sets glibc's mmap and trim thresholds (see the module docstring); True if set."""
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        ok = bool(libc.mallopt(M_MMAP_THRESHOLD, THRESHOLD_BYTES)) and \
            bool(libc.mallopt(M_TRIM_THRESHOLD, THRESHOLD_BYTES))
    except (OSError, AttributeError):
        return False
    log.debug("malloc thresholds set: %s", ok)
    return ok
