"""Tours over places to visit: path distances between them and open travelling-salesman
tours, for the planners that order many goals at once (the ground-truth oracle, the
frontier-TSP explorer).

Path distances come from a coarse copy of the traversable cells (``block`` x ``block``
fine cells per node, 8-connected, a node traversable when any of its fine cells is), on
which one Dijkstra per place runs in scipy; at 0.05 m cells and ``block`` 4 a node is
0.2 m, so distances are within a few tenths of a metre of the fine planner's and a matrix
for dozens of places costs milliseconds. A wall thinner than the block cannot be crossed:
traversable cells lie at least the robot's radius from any wall, so cells on its two sides
never fall into neighbouring nodes.

The order is an open tour (start fixed, end free) solved with OR-Tools' routing solver:
cheapest-arc construction, then local search (2-opt, or-opt, relocation, ...) to a local
optimum, which is deterministic; ``time_limit`` caps the search.
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import cast

import numpy as np
from ortools.constraint_solver import pywrapcp, routing_enums_pb2
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from mjexplore.maps import GridMap

# Distances handed to the solver are integers: millimetres.
_SCALE = 1000.0
# Cost of an arc that does not exist (a place unreachable from another), in metres.
UNREACHABLE_M = 1.0e5


class CoarseGraph:
    """Shortest path distances over a grid's traversable cells, on coarse blocks.

    Args:
        grid: The map whose cells ``traversable`` refers to (for the frame).
        traversable: (rows, cols) bool, the cells the robot's centre may occupy.
        block: Fine cells per coarse node along each axis.
    """

    def __init__(self, grid: GridMap, traversable: np.ndarray, block: int = 4) -> None:
        self.grid = grid
        self.block = block
        rows, cols = traversable.shape
        br, bc = -(-rows // block), -(-cols // block)
        padded = np.zeros((br * block, bc * block), bool)
        padded[:rows, :cols] = traversable
        self.nodes = cast(np.ndarray, padded.reshape(br, block, bc, block).any(axis=(1, 3)))
        self.shape = (br, bc)
        index = np.full(br * bc, -1, np.int64)
        flat = np.flatnonzero(self.nodes)
        index[flat] = np.arange(len(flat))
        self._index = index.reshape(br, bc)
        self._flat = flat
        step = block * grid.resolution
        pad = np.pad(self._index, 1, constant_values=-1)
        srcs: list[np.ndarray] = []
        dsts: list[np.ndarray] = []
        ws: list[np.ndarray] = []
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = self._index
            b = pad[1 + dr:1 + dr + br, 1 + dc:1 + dc + bc]
            both = (a >= 0) & (b >= 0)
            srcs.append(a[both])
            dsts.append(b[both])
            ws.append(np.full(int(both.sum()), step * float(np.hypot(dr, dc))))
        src, dst, w = np.concatenate(srcs), np.concatenate(dsts), np.concatenate(ws)
        self._rows: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        n = len(flat)
        self.matrix = coo_matrix((np.concatenate([w, w]), (np.concatenate([src, dst]),
                                  np.concatenate([dst, src]))), shape=(n, n)).tocsr()

    def node_of(self, xy: np.ndarray, radius: float = 1.0) -> np.ndarray:
        """Graph node of each (n, 2) point in the ``map`` frame: its block's, or the
        nearest traversable block within ``radius`` metres; -1 where none."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        rc = self.grid.world_to_cell(xy) // self.block
        out = np.full(len(xy), -1, np.int64)
        k = int(np.ceil(radius / (self.block * self.grid.resolution)))
        br, bc = self.shape
        for i, (r, c) in enumerate(rc):
            r0, r1, c0, c1 = max(r - k, 0), min(r + k + 1, br), max(c - k, 0), min(c + k + 1, bc)
            if r0 >= r1 or c0 >= c1:
                continue
            rr, cc = np.nonzero(self.nodes[r0:r1, c0:c1])
            if len(rr):
                j = int(np.argmin((rr + r0 - r) ** 2 + (cc + c0 - c) ** 2))
                out[i] = self._index[rr[j] + r0, cc[j] + c0]
        return out

    @property
    def centres(self) -> np.ndarray:
        """(nodes, 2) centre of each node's block in the ``map`` frame, metres."""
        rc = np.column_stack(np.divmod(self._flat, self.shape[1])) * self.block
        return self.grid.cell_to_world(rc) + 0.5 * (self.block - 1) * self.grid.resolution

    def _search(self, sources: list[int]) -> None:
        """Dijkstra from the sources not searched yet; rows kept by source node."""
        todo = [v for v in dict.fromkeys(sources) if v not in self._rows]
        if todo:
            dist, pred = dijkstra(self.matrix, directed=False, indices=np.array(todo),
                                  return_predecessors=True)
            self._rows.update(zip(todo, zip(np.atleast_2d(dist), np.atleast_2d(pred))))

    def distances(self, sources: np.ndarray) -> np.ndarray:
        """(len(sources), nodes) path distances in metres from each source node (inf where
        unreachable). Searches are kept: the graph does not change."""
        nodes = [int(v) for v in np.atleast_1d(sources)]
        self._search(nodes)
        return np.array([self._rows[v][0] for v in nodes])

    def path(self, source: int, target: int) -> np.ndarray:
        """Nodes of the shortest path from ``source`` to ``target`` (both included; empty
        if none)."""
        self._search([source])
        pred = self._rows[source][1]
        nodes = [target]
        while nodes[-1] != source:
            if pred[nodes[-1]] < 0:
                return np.zeros(0, np.int64)
            nodes.append(int(pred[nodes[-1]]))
        return np.array(nodes[::-1], np.int64)

    def distance_matrix(self, points: np.ndarray, radius: float = 1.0) -> np.ndarray:
        """(n, n) path distances in metres between (n, 2) points; inf where either point
        has no node or no path joins them."""
        nodes = self.node_of(points, radius)
        n = len(nodes)
        out = np.full((n, n), np.inf)
        ok = np.flatnonzero(nodes >= 0)
        if len(ok):
            rows = self.distances(nodes[ok])
            out[np.ix_(ok, ok)] = rows[:, nodes[ok]]
        np.fill_diagonal(out, 0.0)
        return out


@dataclasses.dataclass(frozen=True, kw_only=True)
class TourConfig:
    """Settings of the tour solver.

    Attributes:
        time_limit: Wall-clock cap on the local search, seconds (the search usually stops
            earlier, at a local optimum).
        guided: Guided local search instead of plain descent: better tours, but it runs to
            ``time_limit`` and so depends on the machine's speed.
    """

    time_limit: float = 0.2
    guided: bool = False


def open_tour(distance: np.ndarray, config: TourConfig | None = None,
              initial: list[int] | None = None) -> list[int]:
    """The order in which to visit places 1..n-1 starting from place 0, ending anywhere.

    Args:
        distance: (n, n) path distances in metres (inf: no path); row and column 0 are the
            start.
        config: Solver settings.
        initial: A previous order of places (indices into 1..n-1) to start the search from;
            those no longer present are ignored.

    Returns:
        The indices 1..n-1 in visiting order (an empty list for n <= 1).
    """
    config = config or TourConfig()
    n = len(distance)
    if n <= 2:
        return list(range(1, n))
    if n == 3:
        return [1, 2] if tour_length(distance, [1, 2]) <= tour_length(distance, [2, 1]) else [2, 1]
    d = np.where(np.isfinite(distance), distance, UNREACHABLE_M)
    # An open path: a dummy end node that every place reaches for free.
    cost = np.zeros((n + 1, n + 1), np.int64)
    cost[:n, :n] = np.round(d * _SCALE).astype(np.int64)
    cost[n, :] = int(UNREACHABLE_M * _SCALE)
    cost[:, 0] = int(UNREACHABLE_M * _SCALE)
    manager = pywrapcp.RoutingIndexManager(n + 1, 1, [0], [n])
    routing = pywrapcp.RoutingModel(manager)
    routing.SetArcCostEvaluatorOfAllVehicles(routing.RegisterTransitMatrix(cost.tolist()))
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH if config.guided else
        routing_enums_pb2.LocalSearchMetaheuristic.GREEDY_DESCENT)
    params.time_limit.FromMilliseconds(max(1, int(config.time_limit * 1000)))
    solution = None
    if initial:
        seed_route = [i for i in initial if 0 < i < n]
        if len(seed_route) == n - 1:
            routing.CloseModelWithParameters(params)
            start = routing.ReadAssignmentFromRoutes([seed_route], True)
            if start is not None:
                solution = routing.SolveFromAssignmentWithParameters(start, params)
    if solution is None:
        solution = routing.SolveWithParameters(params)
    if solution is None:  # Cannot happen with a complete cost matrix; keep a usable order.
        return sorted(range(1, n), key=lambda i: d[0, i])
    order, index = [], routing.NextVar(routing.Start(0))
    index = solution.Value(index)
    while not routing.IsEnd(index):
        order.append(manager.IndexToNode(index))
        index = solution.Value(routing.NextVar(index))
    return order


def tour_length(distance: np.ndarray, order: list[int]) -> float:
    """Length in metres of the open path from place 0 through ``order``."""
    nodes = [0, *order]
    return float(sum(distance[a, b] for a, b in zip(nodes, nodes[1:])))


def exhaustive_open_tour(distance: np.ndarray) -> list[int]:
    """The optimal open tour by trying every order (for tests and tiny instances: n <= 9)."""
    n = len(distance)
    if n > 10:
        raise ValueError("exhaustive_open_tour is for at most 9 places besides the start")
    best = min(itertools.permutations(range(1, n)), key=lambda p: tour_length(distance, list(p)))
    return list(best)
