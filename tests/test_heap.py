"""The array heap of the numba kernels: order, and the kernels' growth of it when full."""

import numba
import numpy as np

from mjexplore.heap import grow, pop, push
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.topology.gvd import DynamicGVD


@numba.njit
def _heap_sort(keys_in):
    """Pushes every key (growing the heap from one entry as needed), then pops them all."""
    keys = np.empty(1, keys_in.dtype)
    vals = np.empty(1, np.int64)
    size = 0
    for i in range(len(keys_in)):
        if size + 1 > len(keys):
            keys, vals = grow(keys, vals, size, 1)
        size = push(keys, vals, size, keys_in[i], i)
    out_keys = np.empty(len(keys_in), keys_in.dtype)
    out_vals = np.empty(len(keys_in), np.int64)
    for i in range(len(keys_in)):
        out_keys[i], out_vals[i], size = pop(keys, vals, size)
    return out_keys, out_vals, size


def test_heap_pops_every_key_in_order_with_its_value():
    keys = np.random.default_rng(0).integers(0, 50, 500).astype(float)  # Many ties.
    out_keys, out_vals, size = _heap_sort(keys)
    assert size == 0
    assert np.array_equal(out_keys, np.sort(keys))
    assert np.array_equal(keys[out_vals], out_keys)  # Each value stayed with its key.
    assert sorted(out_vals) == list(range(len(keys)))


@numba.njit
def _push_pop(ops, keys_in):
    """Pushes keys_in[i] (value i) where ops[i] is True, else pops; returns popped values."""
    keys = np.empty(len(keys_in), keys_in.dtype)
    vals = np.empty(len(keys_in), np.int64)
    out = np.full(len(ops), -1)
    size = 0
    for i in range(len(ops)):
        if ops[i]:
            size = push(keys, vals, size, keys_in[i], i)
        elif size > 0:
            _, out[i], size = pop(keys, vals, size)
    return out


def _textbook_push_pop(ops, keys_in):
    """:func:`_push_pop` on the textbook binary heap: sift up while the parent is larger;
    sift down to the smaller child (the left one on a tie) while it is smaller."""
    heap, out = [], np.full(len(ops), -1)
    for i, op in enumerate(ops):
        if op:
            heap.append((keys_in[i], i))
            j = len(heap) - 1
            while j > 0 and heap[(j - 1) // 2][0] > heap[j][0]:
                heap[j], heap[(j - 1) // 2] = heap[(j - 1) // 2], heap[j]
                j = (j - 1) // 2
        elif heap:
            out[i] = heap[0][1]
            last = heap.pop()
            if heap:
                heap[0], j = last, 0
                while 2 * j + 1 < len(heap):
                    c = 2 * j + 1
                    if c + 1 < len(heap) and heap[c + 1][0] < heap[c][0]:
                        c += 1
                    if heap[j][0] <= heap[c][0]:
                        break
                    heap[j], heap[c] = heap[c], heap[j]
                    j = c
    return out


def test_ties_pop_in_the_textbook_heap_order():
    # The planner's paths depend on which of equal keys pops first: that order is part of
    # the heap's contract, so that a faster heap changes no episode.
    rng = np.random.default_rng(1)
    for dtype in (np.float64, np.int64):
        ops = rng.random(3000) < 0.6
        keys = rng.integers(0, 30, 3000).astype(dtype)
        out = _push_pop(ops, keys)
        assert np.array_equal(out, _textbook_push_pop(ops, keys))
        assert (out >= 0).sum() > 1000


def test_gvd_grows_a_full_heap_and_stays_exact():
    rng = np.random.default_rng(3)
    obst = np.zeros((40, 50), bool)
    obst[0, :] = obst[-1, :] = obst[:, 0] = obst[:, -1] = True
    gvd = DynamicGVD(obst.shape)
    gvd._keys, gvd._vals = np.empty(1, np.int64), np.empty(1, np.int64)
    for _ in range(4):
        obst |= rng.random(obst.shape) < 0.02
        obst &= rng.random(obst.shape) > 0.2  # Clears some too: raise waves.
        gvd.update(obst)
    fresh = DynamicGVD(obst.shape)
    fresh.update(obst)
    assert len(gvd._keys) > 1
    assert np.array_equal(gvd.distance2, fresh.distance2)
    assert np.array_equal(gvd.nearest, fresh.nearest)
    assert np.array_equal(gvd.voronoi, fresh.voronoi)


def test_planner_grows_a_full_heap_and_finds_the_same_path():
    data = np.full((60, 100), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    data[:45, 50:53] = OCCUPIED
    grid = GridMap(data, 0.1)
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    roomy = Costmap(grid, gvd.distance2, PlannerConfig())
    tight = Costmap(grid, gvd.distance2, PlannerConfig())
    tight._keys, tight._vals = np.empty(1), np.empty(1, np.int64)
    start, goal = np.array([2.0, 1.0]), np.array([8.0, 1.0])
    path = tight.plan(start, goal)
    assert len(tight._keys) > 1
    assert path is not None and np.array_equal(path, roomy.plan(start, goal))
