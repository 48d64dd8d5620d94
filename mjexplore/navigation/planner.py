"""Grid path planning on the known map (the global planner of the navigation stack).

Traversable cells are known free cells farther than ``lethal_radius`` from the nearest
occupied cell; unknown cells are not traversable (the robot plans through what it has
seen, as move_base does with ``allow_unknown`` off). Each step costs its length plus a
penalty that grows as the path nears walls (``soft_radius``), which keeps paths in the
middle of corridors and doors. A* and Dijkstra run in numba over 8-connected cells.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np

from mjexplore.maps import GridMap

_DR = np.array([-1, -1, -1, 0, 0, 1, 1, 1], np.int64)
_DC = np.array([-1, 0, 1, -1, 1, -1, 0, 1], np.int64)
_STEP = np.array([math.sqrt(2), 1, math.sqrt(2), 1, 1, math.sqrt(2), 1, math.sqrt(2)])


@dataclasses.dataclass(frozen=True, kw_only=True)
class PlannerConfig:
    """Costmap settings, in metres.

    Attributes:
        lethal_radius: Cells closer than this to an occupied cell are not traversable
            (about the robot's inscribed radius plus a margin).
        soft_radius: Within this distance of walls, steps cost extra.
        wall_penalty: Extra cost per step at the lethal radius, falling linearly to 0 at
            the soft radius.
    """

    lethal_radius: float = 0.2
    soft_radius: float = 0.6
    wall_penalty: float = 4.0


@numba.njit(cache=True)
def _push(keys, vals, size, key, val):
    if size == len(keys):
        nk = np.empty(2 * len(keys))
        nv = np.empty(2 * len(vals), np.int64)
        nk[:size] = keys[:size]
        nv[:size] = vals[:size]
        keys, vals = nk, nv
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
def _pop(keys, vals, size):
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


@numba.njit(cache=True)
def _search(cost, start, goal, rows, cols, with_heuristic):
    """Dijkstra (goal < 0: to every cell) or A* (goal >= 0) over cells with cost >= 0.

    ``cost`` is the extra cost per step into a cell (-1: not traversable). Returns
    (distance, parent): path cost from ``start`` (inf where unreached) and each cell's
    predecessor (-1 for none).
    """
    n = rows * cols
    dist = np.full(n, np.inf)
    parent = np.full(n, -1, np.int64)
    closed = np.zeros(n, np.uint8)
    keys = np.empty(1024)
    vals = np.empty(1024, np.int64)
    size = 0
    dist[start] = 0.0
    gr, gc = (goal // cols, goal % cols) if goal >= 0 else (0, 0)
    keys, vals, size = _push(keys, vals, size, 0.0, start)
    while size > 0:
        _, s, size = _pop(keys, vals, size)
        if closed[s]:
            continue
        closed[s] = 1
        if s == goal:
            break
        r0, c0 = s // cols, s % cols
        for k in range(8):
            rr, cc = r0 + _DR[k], c0 + _DC[k]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                continue
            y = rr * cols + cc
            if cost[y] < 0 or closed[y]:
                continue
            if k in (0, 2, 5, 7):  # No corner cutting past a blocked cell.
                if cost[r0 * cols + cc] < 0 or cost[rr * cols + c0] < 0:
                    continue
            d = dist[s] + _STEP[k] * (1.0 + cost[y])
            if d < dist[y]:
                dist[y] = d
                parent[y] = s
                h = 0.0
                if with_heuristic:
                    h = math.hypot(rr - gr, cc - gc)
                keys, vals, size = _push(keys, vals, size, d + h, y)
    return dist, parent


class Costmap:
    """Step costs over a map, from its free cells and the distance to occupied cells.

    Args:
        grid: The map.
        clearance: (rows, cols) distance in metres from each cell to the nearest occupied
            cell (e.g. from the GVD's distance field); inf where none is known.
        config: Costmap settings.
    """

    def __init__(self, grid: GridMap, clearance: np.ndarray,
                 config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()
        self.grid = grid
        cfg = self.config
        extra = cfg.wall_penalty * np.clip(
            (cfg.soft_radius - clearance) / (cfg.soft_radius - cfg.lethal_radius), 0.0, 1.0)
        cost = np.where(grid.free & (clearance >= cfg.lethal_radius), extra, -1.0)
        self.cost = np.ascontiguousarray(cost.reshape(-1))

    @property
    def traversable(self) -> np.ndarray:
        return (self.cost >= 0).reshape(self.grid.shape)

    def nearest_traversable(self, xy: np.ndarray, radius: float = 1.0) -> int:
        """Flat index of the traversable cell nearest to ``xy`` within ``radius``, or -1."""
        grid = self.grid
        r, c = grid.world_to_cell(np.asarray(xy, float))
        k = int(math.ceil(radius / grid.resolution))
        r0, r1 = max(r - k, 0), min(r + k + 1, grid.shape[0])
        c0, c1 = max(c - k, 0), min(c + k + 1, grid.shape[1])
        if r0 >= r1 or c0 >= c1:
            return -1
        window = self.cost.reshape(grid.shape)[r0:r1, c0:c1] >= 0
        rows, cols = np.nonzero(window)
        if len(rows) == 0:
            return -1
        d = (rows + r0 - r) ** 2 + (cols + c0 - c) ** 2
        i = int(np.argmin(d))
        if d[i] > k * k:
            return -1
        return int((rows[i] + r0) * grid.shape[1] + cols[i] + c0)

    def distances_from(self, xy: np.ndarray) -> np.ndarray:
        """Path cost (metres, wall penalty included) from ``xy`` to every cell; inf if none."""
        start = self.nearest_traversable(xy)
        if start < 0:
            return np.full(self.grid.shape, np.inf)
        dist, _ = _search(self.cost, start, -1, *self.grid.shape, False)
        return dist.reshape(self.grid.shape) * self.grid.resolution

    def plan(self, start_xy: np.ndarray, goal_xy: np.ndarray,
             goal_radius: float = 1.0) -> np.ndarray | None:
        """A* path from ``start_xy`` to the traversable cell nearest ``goal_xy``.

        Returns:
            (k, 2) waypoints in the ``map`` frame (start to goal), or None if no path.
        """
        start = self.nearest_traversable(start_xy)
        goal = self.nearest_traversable(goal_xy, goal_radius)
        if start < 0 or goal < 0:
            return None
        dist, parent = _search(self.cost, start, goal, *self.grid.shape, True)
        if not np.isfinite(dist[goal]):
            return None
        cells = [goal]
        while cells[-1] != start:
            cells.append(int(parent[cells[-1]]))
        cells = np.array(cells[::-1])
        rc = np.column_stack(np.divmod(cells, self.grid.shape[1]))
        return self.grid.cell_to_world(rc)


def path_length(path: np.ndarray) -> float:
    """Length of a polyline (k, 2) in metres."""
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0
