"""A binary min-heap on plain arrays, for numba kernels (keys of any numeric dtype).

The heap lives in two arrays (keys, values) and a size. ``push`` and ``pop`` are inlined
into the kernel and return only the new size: a kernel makes room first, where it knows how
many pushes can follow, with ``if size + room > len(keys): keys, vals = grow(...)``, and
returns the arrays it ended with so that its caller keeps them between calls. (Returning
the arrays from every push costs reference-count updates per array and push: a fifth to a
quarter of the planner's and the GVD's kernel time.)
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def grow(keys, vals, size, room):
    """Copies of the heap's arrays with space for at least ``room`` more entries."""
    capacity = max(2 * len(keys), size + room)
    grown_keys = np.empty(capacity, keys.dtype)
    grown_vals = np.empty(capacity, vals.dtype)
    grown_keys[:size] = keys[:size]
    grown_vals[:size] = vals[:size]
    return grown_keys, grown_vals


@numba.njit(cache=True, inline="always")
def push(keys, vals, size, key, val):
    """Adds (key, val) to a heap with room for it (``size < len(keys)``); returns the size."""
    i = size
    while i > 0:  # Sift up: move parents down into the hole until the key fits.
        p = (i - 1) >> 1
        if keys[p] <= key:
            break
        keys[i] = keys[p]
        vals[i] = vals[p]
        i = p
    keys[i] = key
    vals[i] = val
    return size + 1


@numba.njit(cache=True, inline="always")
def pop(keys, vals, size):
    """Removes the smallest key; returns (key, val, size)."""
    key, val = keys[0], vals[0]
    size -= 1
    last_key, last_val = keys[size], vals[size]
    i = 0
    while True:  # Sift the last entry down from the root, moving smaller children up.
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and keys[child + 1] < keys[child]:
            child += 1
        if last_key <= keys[child]:
            break
        keys[i] = keys[child]
        vals[i] = vals[child]
        i = child
    keys[i] = last_key
    vals[i] = last_val
    return key, val, size
