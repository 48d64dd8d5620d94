"""A binary min-heap on plain arrays, for numba kernels (keys of any numeric dtype).

The heap lives in two arrays (keys, values) and a size; ``push`` returns the arrays it used,
grown when full, so a caller keeps them between calls.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def push(keys, vals, size, key, val):
    """Adds (key, val); returns (keys, vals, size)."""
    if size == len(keys):
        grown_keys = np.empty(2 * len(keys), keys.dtype)
        grown_vals = np.empty(2 * len(vals), vals.dtype)
        grown_keys[:size] = keys[:size]
        grown_vals[:size] = vals[:size]
        keys, vals = grown_keys, grown_vals
    i = size
    keys[i] = key
    vals[i] = val
    while i > 0:
        p = (i - 1) >> 1
        if keys[p] <= keys[i]:
            break
        keys[p], keys[i] = keys[i], keys[p]
        vals[p], vals[i] = vals[i], vals[p]
        i = p
    return keys, vals, size + 1


@numba.njit(cache=True)
def pop(keys, vals, size):
    """Removes the smallest key; returns (key, val, size)."""
    key, val = keys[0], vals[0]
    size -= 1
    keys[0], vals[0] = keys[size], vals[size]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= size:
            break
        child = left
        if left + 1 < size and keys[left + 1] < keys[left]:
            child = left + 1
        if keys[i] <= keys[child]:
            break
        keys[i], keys[child] = keys[child], keys[i]
        vals[i], vals[child] = vals[child], vals[i]
        i = child
    return key, val, size
