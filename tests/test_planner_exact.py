"""The planner's lookups return exactly what the computations they replace return."""

import math

import numba
import numpy as np
import pytest

from mjexplore.navigation.planner import _hypot_table, _nearest_traversable


@numba.njit
def _signed_hypot(rows, cols):
    """(2 rows - 1, 2 cols - 1) math.hypot of every signed offset, as the kernel's old
    heuristic computed it."""
    out = np.empty((2 * rows - 1, 2 * cols - 1))
    for dr in range(-rows + 1, rows):
        for dc in range(-cols + 1, cols):
            out[dr + rows - 1, dc + cols - 1] = math.hypot(dr, dc)
    return out


def test_hypot_table_holds_the_heuristic_of_every_signed_offset_bitwise():
    rows, cols = 37, 61
    table = _hypot_table(rows, cols).reshape(rows, cols)
    dr = np.abs(np.arange(-rows + 1, rows))[:, None]
    dc = np.abs(np.arange(-cols + 1, cols))[None, :]
    assert np.array_equal(table[dr, dc], _signed_hypot(rows, cols))
    assert table[3, 4] == 5.0


def _nearest_reference(cost, r, c, k):
    """The numpy form: the first (row-major) of the nearest cost >= 0 cells, -1 if none
    lies within k cells."""
    rows, cols = cost.shape
    r0, r1, c0, c1 = max(r - k, 0), min(r + k + 1, rows), max(c - k, 0), min(c + k + 1, cols)
    if r0 >= r1 or c0 >= c1:
        return -1
    rr, cc = np.nonzero(cost[r0:r1, c0:c1] >= 0)
    if len(rr) == 0:
        return -1
    d = (rr + r0 - r) ** 2 + (cc + c0 - c) ** 2
    i = int(np.argmin(d))
    return -1 if d[i] > k * k else int((rr[i] + r0) * cols + cc[i] + c0)


@pytest.mark.parametrize("k", [1, 4, 20])
def test_nearest_traversable_matches_the_numpy_form(k):
    rng = np.random.default_rng(k)
    cost = np.where(rng.random((30, 40)) < 0.93, -1.0, rng.random((30, 40)))
    found = 0
    for r, c in rng.integers(-25, 60, (400, 2)):
        got = _nearest_traversable(cost.reshape(-1), 30, 40, int(r), int(c), k)
        assert got == _nearest_reference(cost, int(r), int(c), k)
        found += got >= 0
    assert 0 < found < 400  # Both outcomes were exercised.


@pytest.mark.parametrize("seed", range(4))
def test_distances_near_nodes_equal_the_whole_maps_least_over_each_square(seed):
    from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
    from mjexplore.navigation.planner import Costmap, PlannerConfig
    from mjexplore.topology.gvd import DynamicGVD

    rng = np.random.default_rng(seed)
    data = np.full((70, 90), FREE, np.int8)
    for r, c in rng.integers(5, 60, (6, 2)):  # Walls the paths must go round.
        data[r:r + 3, c:c + 25] = OCCUPIED
    data[:, 60:] = UNKNOWN  # Unreached cells beside reached ones.
    grid = GridMap(data, 0.1)
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    costmap = Costmap(grid, gvd.distance2, PlannerConfig())
    costmap.update(None)
    cells = np.column_stack([rng.integers(0, 70, 40), rng.integers(0, 90, 40)])
    cells[:3] = [[0, 0], [69, 89], [35, 59]]  # Squares clipped at the edges; half unknown.
    start = np.array([1.0, 1.5])
    for half in (0, 3, 10):
        whole = costmap.distances_from(start)
        offsets = np.arange(-half, half + 1)
        r = np.clip(cells[:, 0, None] + offsets, 0, 69)
        c = np.clip(cells[:, 1, None] + offsets, 0, 89)
        reference = whole[r[:, :, None], c[:, None, :]].reshape(len(cells), -1).min(axis=1)
        near = costmap.distances_near(start, cells, half)
        assert np.array_equal(near, reference)  # Bit for bit, inf included.
        assert np.isfinite(near).sum() > 10 and np.isinf(near).any()
