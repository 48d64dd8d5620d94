"""Grid path planning on the known map (the global planner of the navigation stack).

Traversable cells are known free cells at least ``lethal_radius`` from the nearest
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

from mjexplore.heap import grow as _heap_grow
from mjexplore.heap import pop as _heap_pop
from mjexplore.heap import push as _heap_push
from mjexplore.maps import GridMap, is_free

_DR = np.array([-1, -1, -1, 0, 0, 1, 1, 1], np.int64)
_DC = np.array([-1, 0, 1, -1, 1, -1, 0, 1], np.int64)
_STEP = np.array([math.sqrt(2), 1, math.sqrt(2), 1, 1, math.sqrt(2), 1, math.sqrt(2)])


@dataclasses.dataclass(frozen=True, kw_only=True)
class PlannerConfig:
    """Costmap settings, in metres.

    Attributes:
        lethal_radius: Cells closer than this to an occupied cell are not traversable: the
            robot's footprint radius about ``base_link`` (0.26 m), so that it can turn in
            place anywhere on a path without its rear swinging into a wall.
        soft_radius: Within this distance of walls, steps cost extra.
        wall_penalty: Extra cost per step at the lethal radius, falling linearly to 0 at
            the soft radius.
        heuristic_weight: A* heuristic factor; 1 gives optimal paths, more (weighted A*)
            expands fewer cells for paths at most that factor longer (training mode).
    """

    lethal_radius: float = 0.26
    soft_radius: float = 0.7
    wall_penalty: float = 4.0
    heuristic_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.heuristic_weight < 1.0:
            raise ValueError("heuristic_weight must be >= 1 (1: optimal A*)")


@numba.njit(cache=True)
def _hypot_table(rows, cols):
    """(rows * cols,) ``math.hypot(r, c)`` at ``r * cols + c``: the A* heuristic's
    distances in cells, looked up rather than computed per push (a libm call), with the
    very same values (hypot(x, y) = hypot(|x|, |y|), C99 Annex F)."""
    table = np.empty(rows * cols)
    for r in range(rows):
        for c in range(cols):
            table[r * cols + c] = math.hypot(r, c)
    return table


@numba.njit(cache=True)
def _search(cost, start, goal, rows, cols, heuristic_weight, hypot_table, dist, parent, stamp,
            search_id, keys, vals, is_target, stop_after):
    """Dijkstra (goal < 0: to every cell) or A* (goal >= 0) over cells with cost >= 0.

    ``cost`` is the extra cost per step into a cell (-1: not traversable). The heuristic is
    ``heuristic_weight`` times the straight-line distance in cells, read from
    ``hypot_table`` (:func:`_hypot_table`; unused when the weight is 0). ``dist`` and
    ``parent`` hold results for cells whose ``stamp`` equals ``search_id`` (reused buffers,
    so a search touches only the cells it reaches); the heap arrays are returned, grown.
    A stamp of -search_id marks a closed cell. With ``stop_after > 0`` the search ends
    once that many cells flagged in ``is_target`` are closed.
    """
    size = 0
    found = 0
    stamp[start] = search_id
    dist[start] = 0.0
    parent[start] = -1
    gr, gc = (goal // cols, goal % cols) if goal >= 0 else (0, 0)
    size = _heap_push(keys, vals, size, 0.0, start)
    while size > 0:
        _, s, size = _heap_pop(keys, vals, size)
        if size + 8 > len(keys):  # Room for this cell's neighbours.
            keys, vals = _heap_grow(keys, vals, size, 8)
        if stamp[s] == -search_id:
            continue
        stamp[s] = -search_id
        if s == goal:
            break
        if stop_after > 0 and is_target[s]:
            found += 1
            if found >= stop_after:
                break
        r0, c0 = s // cols, s % cols
        ds = dist[s]
        for k in range(8):
            rr, cc = r0 + _DR[k], c0 + _DC[k]
            if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                continue
            y = rr * cols + cc
            if cost[y] < 0 or stamp[y] == -search_id:
                continue
            if k in (0, 2, 5, 7):  # No corner cutting past a blocked cell.
                if cost[r0 * cols + cc] < 0 or cost[rr * cols + c0] < 0:
                    continue
            d = ds + _STEP[k] * (1.0 + cost[y])
            if stamp[y] != search_id or d < dist[y]:
                stamp[y] = search_id
                dist[y] = d
                parent[y] = s
                h = 0.0
                if heuristic_weight > 0.0:
                    h = heuristic_weight * hypot_table[abs(rr - gr) * cols + abs(cc - gc)]
                size = _heap_push(keys, vals, size, d + h, y)
    return keys, vals


@numba.njit(cache=True)
def _bucket_search(cost, start, rows, cols, dist, stamp, search_id, cells, nexts, heads):
    """Dijkstra from ``start`` to every reachable cell with a circular bucket queue (Dial's
    algorithm): bucket k holds the open cells whose cost lies in [k, k + 1) (in cells), and
    since every step costs at least 1, the cells of the lowest bucket are final, in any
    order. O(1) per push instead of the heap's O(log n); the distances are :func:`_search`'s
    (up to rounding where two paths cost the same). ``dist`` and ``stamp`` as there;
    ``cells`` and ``nexts`` hold the buckets' linked entries (returned, grown); ``heads``
    (more buckets than the costliest step, in cells, plus one) is all -1 on entry and exit.
    """
    nb = len(heads)
    stamp[start] = search_id
    dist[start] = 0.0
    cells[0] = start
    nexts[0] = -1
    heads[0] = 0
    size = 1
    live = 1
    k = 0
    while live > 0:
        e = heads[k % nb]
        heads[k % nb] = -1
        while e >= 0:
            s = cells[e]
            e = nexts[e]
            live -= 1
            if stamp[s] == -search_id:
                continue
            stamp[s] = -search_id
            if size + 8 > len(cells):  # Room for this cell's neighbours.
                cells, nexts = _heap_grow(cells, nexts, size, 8)
            r0, c0 = s // cols, s % cols
            ds = dist[s]
            # _search's relaxation, written out: with an inlined helper shared by both,
            # A* timed up to 10 % slower.
            for j in range(8):
                rr, cc = r0 + _DR[j], c0 + _DC[j]
                if rr < 0 or rr >= rows or cc < 0 or cc >= cols:
                    continue
                y = rr * cols + cc
                if cost[y] < 0 or stamp[y] == -search_id:
                    continue
                if j in (0, 2, 5, 7):  # No corner cutting past a blocked cell.
                    if cost[r0 * cols + cc] < 0 or cost[rr * cols + c0] < 0:
                        continue
                d = ds + _STEP[j] * (1.0 + cost[y])
                if stamp[y] != search_id or d < dist[y]:
                    stamp[y] = search_id
                    dist[y] = d
                    b = int(d) % nb
                    cells[size] = y
                    nexts[size] = heads[b]
                    heads[b] = size
                    size += 1
                    live += 1
        k += 1
    return cells, nexts


@numba.njit(cache=True)
def _trace_back(parent, start, goal):
    """Cells from ``start`` to ``goal`` following ``parent`` links back from the goal."""
    n = 1
    c = goal
    while c != start:
        c = parent[c]
        n += 1
    out = np.empty(n, np.int64)
    c = goal
    for i in range(n - 1, -1, -1):
        out[i] = c
        if i > 0:
            c = parent[c]
    return out


@numba.njit(cache=True)
def _update_cost(cost, cells, free, dist2, resolution, lethal, soft, penalty):
    """Costs of ``cells``; ``free[i]`` says whether ``cells[i]`` is known free."""
    for i in range(len(cells)):
        c = cells[i]
        d = math.sqrt(dist2[c]) * resolution
        if not free[i] or d < lethal:
            cost[c] = -1.0
        else:
            x = (soft - d) / (soft - lethal)
            cost[c] = penalty * min(max(x, 0.0), 1.0)


@numba.njit(cache=True)
def _nearest_traversable(cost, rows, cols, r, c, k):
    """Flat index of the cell with cost >= 0 nearest to cell (r, c) within k cells (the
    first in row-major order of equally near ones), or -1."""
    best, best_d2 = -1, k * k + 1
    for rr in range(max(r - k, 0), min(r + k + 1, rows)):
        for cc in range(max(c - k, 0), min(c + k + 1, cols)):
            d2 = (rr - r) ** 2 + (cc - c) ** 2
            if d2 < best_d2 and cost[rr * cols + cc] >= 0:
                best, best_d2 = rr * cols + cc, d2
    return best


@numba.njit(cache=True)
def _window_min(dist, stamp, search_id, rows, cols, cells, half, resolution, out):
    """``out[i]``: the least ``dist * resolution`` over the cells reached by search
    ``search_id`` in the square of half-side ``half`` around ``cells[i]`` (clipped)."""
    for i in range(len(cells)):
        r, c = cells[i, 0], cells[i, 1]
        for rr in range(max(r - half, 0), min(r + half, rows - 1) + 1):
            for cc in range(max(c - half, 0), min(c + half, cols - 1) + 1):
                y = rr * cols + cc
                if abs(stamp[y]) == search_id:
                    v = dist[y] * resolution
                    if v < out[i]:
                        out[i] = v


@numba.njit(cache=True)
def _fill_windows(mask, rows, cols, cells, half, value):
    """Sets the flat ``mask`` to ``value`` on the square of half-side ``half`` around each
    (row, col) of ``cells``, clipped to the grid."""
    for i in range(len(cells)):
        r, c = cells[i, 0], cells[i, 1]
        for rr in range(max(r - half, 0), min(r + half + 1, rows)):
            for cc in range(max(c - half, 0), min(c + half + 1, cols)):
                mask[rr * cols + cc] = value


class Costmap:
    """Step costs over a map, kept up to date cell by cell.

    The cost of a cell follows from whether it is known free and from its distance to the
    nearest occupied cell (the GVD's distance field); :meth:`update` recomputes the cells
    the last scans changed.

    Args:
        grid: The map (its data array is read live).
        distance2: (rows, cols) squared distance in cells to the nearest occupied cell
            (read live, e.g. ``DynamicGVD.distance2``).
        config: Costmap settings.
    """

    def __init__(self, grid: GridMap, distance2: np.ndarray,
                 config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()
        self.grid = grid
        self._dist2 = distance2.reshape(-1)
        n = grid.data.size
        self.cost = np.empty(n)
        self._dist = np.empty(n)
        self._parent = np.empty(n, np.int64)
        self._stamp = np.zeros(n, np.int64)
        self._search_id = 0
        self._keys = np.empty(4096)
        self._vals = np.empty(4096, np.int64)
        self._bucket_cells = np.empty(4096, np.int64)
        self._bucket_nexts = np.empty(4096, np.int64)
        # More buckets than the costliest step spans (sqrt(2) (1 + wall_penalty) cells).
        self._bucket_heads = np.full(
            int(math.ceil(math.sqrt(2) * (1.0 + self.config.wall_penalty))) + 2, -1, np.int64)
        self._no_targets = np.zeros(1, np.bool_)
        self._windows: np.ndarray | None = None  # distances_to_windows' targets, all False.
        self._hypot_table = np.zeros(0)  # Built by the first A* search.
        self.version = 0  # Counts the updates: costs are unchanged while it stays.
        self.update(None)

    def update(self, cells: np.ndarray | None) -> None:
        """Recomputes the cost of ``cells`` (flat indices); None: every cell."""
        self.version += 1
        cfg = self.config
        cells = np.arange(self.cost.size) if cells is None else np.asarray(cells, np.int64)
        free = is_free(self.grid.data.reshape(-1)[cells])
        _update_cost(self.cost, cells, free, self._dist2, self.grid.resolution,
                     cfg.lethal_radius, cfg.soft_radius, cfg.wall_penalty)

    @property
    def traversable(self) -> np.ndarray:
        return (self.cost >= 0).reshape(self.grid.shape)

    def nearest_traversable(self, xy: np.ndarray, radius: float = 1.0) -> int:
        """Flat index of the traversable cell nearest to ``xy`` within ``radius``, or -1."""
        grid = self.grid
        r, c = grid.world_to_cell(np.asarray(xy, float))
        k = int(math.ceil(radius / grid.resolution))
        return _nearest_traversable(self.cost, *grid.shape, int(r), int(c), k)

    def _run(self, start: int, goal: int, targets: np.ndarray | None = None,
             stop_after: int = 0) -> None:
        self._search_id += 1
        if targets is None:
            targets = self._no_targets
        weight = self.config.heuristic_weight if goal >= 0 else 0.0
        if weight > 0 and len(self._hypot_table) == 0:
            self._hypot_table = _hypot_table(*self.grid.shape)
        self._keys, self._vals = _search(self.cost, start, goal, *self.grid.shape, weight,
                                         self._hypot_table, self._dist, self._parent,
                                         self._stamp, self._search_id, self._keys, self._vals,
                                         targets, stop_after)

    def _nearest_reachable(self, xy: np.ndarray, radius: float, start: int) -> int:
        """Flat index of the traversable cell within ``radius`` of ``xy`` nearest to
        ``start`` by path (the search's parents lead back to ``start``), or -1."""
        grid = self.grid
        r, c = grid.world_to_cell(np.asarray(xy, float))
        k = int(math.ceil(radius / grid.resolution))
        rows = slice(max(r - k, 0), min(r + k + 1, grid.shape[0]))
        cols = slice(max(c - k, 0), min(c + k + 1, grid.shape[1]))
        rr, cc = np.ogrid[rows, cols]
        disk = np.zeros(grid.shape, bool)  # Only the window around xy can hold targets.
        disk[rows, cols] = (((rr - r) ** 2 + (cc - c) ** 2 <= (radius / grid.resolution) ** 2)
                            & self.traversable[rows, cols])
        targets = np.flatnonzero(disk)
        if len(targets) == 0:
            return -1
        self._run(start, -1, disk.reshape(-1), 1)
        reached = targets[self._stamp[targets] == -self._search_id]
        return int(reached[np.argmin(self._dist[reached])]) if len(reached) else -1

    def distances_from(self, xy: np.ndarray, targets: np.ndarray | None = None,
                       stop_after: int = 0) -> np.ndarray:
        """Path cost (metres, wall penalty included) from ``xy`` to the cells; inf if none.

        Args:
            xy: Start point in the ``map`` frame.
            targets: Optional (rows, cols) bool mask of cells of interest.
            stop_after: Stop once this many target cells are reached (0: search all); the
                cells not reached by then read inf.
        """
        out = np.full(self.grid.shape, np.inf)
        start = self.nearest_traversable(xy)
        if start < 0:
            return out
        if targets is None and stop_after == 0:  # Every cell: the bucket queue.
            self._search_everywhere(start)
        else:
            mask = None if targets is None else np.ascontiguousarray(targets.reshape(-1))
            self._run(start, -1, mask, stop_after)
        reached = np.abs(self._stamp) == self._search_id
        out.reshape(-1)[reached] = self._dist[reached] * self.grid.resolution
        return out

    def distances_near(self, xy: np.ndarray, cells: np.ndarray, half: int) -> np.ndarray:
        """The least path cost (metres, as :meth:`distances_from`) from ``xy`` to the
        (2 half + 1)-cell square around each cell, the square clipped to the grid; inf where
        none of it is reached. The same numbers as the least of :meth:`distances_from`'s map
        over each square, read at the squares alone (no pass over the whole map).

        Args:
            xy: Start point in the ``map`` frame.
            cells: (k, 2) (row, col) cells inside the grid.
            half: Square half-side, cells.
        """
        out = np.full(len(cells), np.inf)
        start = self.nearest_traversable(xy)
        if start < 0 or len(cells) == 0:
            return out
        self._search_everywhere(start)
        _window_min(self._dist, self._stamp, self._search_id, *self.grid.shape,
                    np.ascontiguousarray(cells, np.int64).reshape(-1, 2), half,
                    self.grid.resolution, out)
        return out

    def distances_to_windows(self, xy: np.ndarray, cells: np.ndarray, half: int,
                             stop_after: int = 0) -> np.ndarray:
        """The least path cost (metres) from ``xy`` to the (2 half + 1)-cell square around
        each cell (clipped to the grid), the squares' cells being the search's targets: the
        numbers of ``distances_from(xy, squares, stop_after)``'s least over each square,
        read at the squares alone.

        Args:
            xy: Start point in the ``map`` frame.
            cells: (k, 2) (row, col) cells inside the grid.
            half: Square half-side, cells.
            stop_after: Stop once this many target cells are reached (0: search all); the
                squares not reached by then read inf (or an upper bound).
        """
        out = np.full(len(cells), np.inf)
        start = self.nearest_traversable(xy)
        if start < 0 or len(cells) == 0:
            return out
        cells = np.ascontiguousarray(cells, np.int64).reshape(-1, 2)
        rows, cols = self.grid.shape
        if self._windows is None:
            self._windows = np.zeros(rows * cols, np.bool_)
        # One mask for every call, its squares set and cleared again: no pass over the map.
        _fill_windows(self._windows, rows, cols, cells, half, True)
        self._run(start, -1, self._windows, stop_after)
        _fill_windows(self._windows, rows, cols, cells, half, False)
        _window_min(self._dist, self._stamp, self._search_id, rows, cols, cells, half,
                    self.grid.resolution, out)
        return out

    def _search_everywhere(self, start: int) -> None:
        """Dijkstra from cell ``start`` to every reachable cell (the bucket queue)."""
        self._search_id += 1
        self._bucket_cells, self._bucket_nexts = _bucket_search(
            self.cost, start, *self.grid.shape, self._dist, self._stamp, self._search_id,
            self._bucket_cells, self._bucket_nexts, self._bucket_heads)

    def plan(self, start_xy: np.ndarray, goal_xy: np.ndarray,
             goal_radius: float = 1.0) -> np.ndarray | None:
        """A* path from ``start_xy`` to the traversable cell nearest ``goal_xy``, or, when
        that one cannot be reached (it lies beyond a wall), to the nearest by path of the
        traversable cells within ``goal_radius``.

        Returns:
            (k, 2) waypoints in the ``map`` frame (start to goal), or None if no path.
        """
        start = self.nearest_traversable(start_xy)
        goal = self.nearest_traversable(goal_xy, goal_radius)
        if start < 0 or goal < 0:
            return None
        self._run(start, goal)
        if self._stamp[goal] != -self._search_id:
            goal = self._nearest_reachable(goal_xy, goal_radius, start)
            if goal < 0:
                return None
        cells = _trace_back(self._parent, start, goal)
        rc = np.column_stack(np.divmod(cells, self.grid.shape[1]))
        return self.grid.cell_to_world(rc)


def path_length(path: np.ndarray) -> float:
    """Length of a polyline (k, 2) in metres."""
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0
