"""A binary min-heap on plain arrays, for numba kernels (keys of any numeric dtype).

The heap lives in two arrays (keys, values) and a size. ``push`` and ``pop`` are inlined
into the kernel and return only the new size: a kernel makes room first, where it knows how
many pushes can follow, with ``if size + room > len(keys): keys, vals = grow(...)``, and
returns the arrays it ended with so that its caller keeps them between calls. (Returning
the arrays from every push costs reference-count updates per array and push: a fifth to a
quarter of the planner's and the GVD's kernel time.)

Equal keys pop in the order of the textbook binary heap: the planner's paths depend on it,
so a faster heap must keep that order (tests/test_heap.py checks it).
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
    """Removes the smallest key of a heap with ``size > 0``; returns (key, val, size)."""
    key, val = keys[0], vals[0]
    size -= 1
    last_key, last_val = keys[size], vals[size]
    # Unsigned positions: numba indexes with them without the wraparound of negative
    # indices, two instructions on the sift's critical path. (All arithmetic on them stays
    # uint64: mixed with int64, numba would compute in float64.)
    end, one, i = np.uint64(size), np.uint64(1), np.uint64(0)
    while True:  # Sift the last entry down from the root, moving smaller children up.
        child = i + i + one
        if child >= end:
            break
        if child + one < end:
            # Branch-free pick of the smaller child (the left one on a tie): as a branch,
            # this comparison goes either way about half the time and mispredicts.
            child += np.uint64(keys[child + one] < keys[child])
        if last_key <= keys[child]:
            break
        keys[i] = keys[child]
        vals[i] = vals[child]
        i = child
    keys[i] = last_key
    vals[i] = last_val
    return key, val, size
