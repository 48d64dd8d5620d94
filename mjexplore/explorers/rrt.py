"""RRT exploration (Umari and Mukhopadhyay, IROS 2017, rrt_exploration; the paper's "Sample").

Two rapidly-exploring random trees look for frontier points: a global tree that keeps
growing over the whole map (step ``global_eta``) and a local tree (step ``local_eta``)
that restarts at the robot every time it finds one. An extension toward a random sample
that runs into unknown space marks a frontier point there; one that hits an obstacle is
dropped; otherwise the tree grows. Points no longer next to unknown space are discarded
and the rest are merged by mean shift (``bandwidth``); as rrt_exploration's filter node
does, a merged point with less than ``min_gain`` square metres of unknown space within half
of ``info_radius`` is dropped (a few unknown cells inside a wall are no frontier). Each
candidate's utility is
``gain_weight * information_gain - path_cost``, with the information gain the unknown
area within ``info_radius`` of it, doubled within ``hysteresis_radius`` of the robot; the
best one is the goal. Trees grow by ``iterations_per_second`` for every simulated second
since the last decision (the detectors run continuously in the original).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.maps import window_counts

FREE_RUN, HIT_OBSTACLE, HIT_UNKNOWN = 0, 1, 2


@numba.njit(cache=True)
def _trace(data, x0, y0, x1, y1):
    """Walks a segment (cell units) over map values; (outcome, x, y) of the first
    non-free cell met (its centre), or (FREE_RUN, x1, y1)."""
    rows, cols = data.shape
    n = int(math.ceil(2.0 * max(abs(x1 - x0), abs(y1 - y0)))) + 1
    for i in range(1, n + 1):
        t = i / n
        x = x0 + (x1 - x0) * t
        y = y0 + (y1 - y0) * t
        r, c = int(math.floor(y)), int(math.floor(x))
        if r < 0 or r >= rows or c < 0 or c >= cols:
            return HIT_OBSTACLE, x, y
        v = data[r, c]
        if v < 0:
            return HIT_UNKNOWN, c + 0.5, r + 0.5
        if v >= 50:
            return HIT_OBSTACLE, x, y
    return FREE_RUN, x1, y1


@numba.njit(cache=True)
def _grow(data, nodes, n_nodes, samples, eta, points, n_points, reset_at_robot, robot):
    """Grows a tree toward each sample; returns (n_nodes, n_points, nodes)."""
    for i in range(len(samples)):
        sx, sy = samples[i, 0], samples[i, 1]
        best, best_d = 0, np.inf
        for j in range(n_nodes):
            d = (nodes[j, 0] - sx) ** 2 + (nodes[j, 1] - sy) ** 2
            if d < best_d:
                best, best_d = j, d
        nx, ny = nodes[best, 0], nodes[best, 1]
        d = math.sqrt(best_d)
        if d > eta:
            sx, sy = nx + (sx - nx) * eta / d, ny + (sy - ny) * eta / d
        outcome, hx, hy = _trace(data, nx, ny, sx, sy)
        if outcome == HIT_UNKNOWN:
            if n_points < len(points):
                points[n_points, 0], points[n_points, 1] = hx, hy
                n_points += 1
            if reset_at_robot:
                nodes[0, 0], nodes[0, 1] = robot[0], robot[1]
                n_nodes = 1
        elif outcome == FREE_RUN:
            if n_nodes == len(nodes):
                grown = np.empty((2 * len(nodes), 2))
                grown[:n_nodes] = nodes
                nodes = grown
            nodes[n_nodes, 0], nodes[n_nodes, 1] = sx, sy
            n_nodes += 1
    return n_nodes, n_points, nodes


def mean_shift(points: np.ndarray, bandwidth: float, iterations: int = 10) -> np.ndarray:
    """Flat-kernel mean shift; returns the distinct modes (merged within the bandwidth).

    Points are first pooled into cells of half the bandwidth (their means), which bounds
    the quadratic cost without moving any mode by more than that.
    """
    keys = np.floor(points / (bandwidth / 2)).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    counts = np.bincount(inverse).astype(float)
    points = np.column_stack([np.bincount(inverse, points[:, 0]),
                              np.bincount(inverse, points[:, 1])]) / counts[:, None]
    modes = points.copy()
    for _ in range(iterations):
        d = np.linalg.norm(modes[:, None] - points[None], axis=2)
        w = d <= bandwidth
        modes = (w[:, :, None] * points[None]).sum(axis=1) / w.sum(axis=1)[:, None]
    # Greedy merge in order: a mode is kept unless an earlier kept one lies within the
    # bandwidth (one vectorised pass per kept mode).
    suppressed = np.zeros(len(modes), bool)
    kept = []
    while not suppressed.all():
        i = int(np.argmin(suppressed))
        kept.append(i)
        suppressed |= np.hypot(*(modes - modes[i]).T) <= bandwidth
    return modes[kept].reshape(-1, 2)


def _unknown_area(grid, points: np.ndarray, radius: float) -> np.ndarray:
    """Square metres of unknown space within ``radius`` metres of each (n, 2) point."""
    k = max(1, int(round(radius / grid.resolution)))
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
    disk = (xx ** 2 + yy ** 2) <= k * k
    rows, cols = grid.shape
    counts = np.zeros(len(points))
    for i, (r, c) in enumerate(grid.world_to_cell(points).reshape(-1, 2)):
        r0, r1, c0, c1 = max(r - k, 0), min(r + k + 1, rows), max(c - k, 0), min(c + k + 1, cols)
        window = grid.data[r0:r1, c0:c1] < 0  # The disk's square, clipped to the grid.
        counts[i] = np.count_nonzero(window & disk[r0 - r + k:r1 - r + k, c0 - c + k:c1 - c + k])
    return counts * grid.resolution ** 2


class RRTExplorer:
    """Args follow rrt_exploration's parameters (metres); see the module docstring."""

    name = "rrt"

    def __init__(self, global_eta: float = 15.0, local_eta: float = 1.0,
                 iterations_per_second: int = 50, bandwidth: float = 0.3,
                 info_radius: float = 1.0, gain_weight: float = 3.0,
                 hysteresis_radius: float = 3.0, hysteresis_gain: float = 2.0,
                 min_gain: float = 0.2) -> None:
        self.global_eta = global_eta
        self.local_eta = local_eta
        self.iterations_per_second = iterations_per_second
        self.bandwidth = bandwidth
        self.info_radius = info_radius
        self.gain_weight = gain_weight
        self.hysteresis_radius = hysteresis_radius
        self.hysteresis_gain = hysteresis_gain
        self.min_gain = min_gain

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.global_nodes: np.ndarray | None = None
        self.local_nodes: np.ndarray | None = None
        self.points = np.zeros((0, 2))
        self.last_time = 0.0

    def _grow_trees(self, state: ExplorationState) -> None:
        grid = state.grid
        res = grid.resolution
        robot = (state.pose[:2] - grid.origin[:2]) / res
        if self.global_nodes is None:
            self.global_nodes = np.array([robot])
            self.n_global = 1
            self.local_nodes = np.array([robot])
            self.n_local = 1
        n_iter = max(200, int(self.iterations_per_second * (state.time - self.last_time)))
        self.last_time = state.time
        rows, cols = grid.shape
        buf = np.zeros((4 * n_iter, 2))
        n_points = 0
        for which, eta in (("global", self.global_eta), ("local", self.local_eta)):
            samples = self.rng.uniform((0, 0), (cols, rows), size=(n_iter, 2))
            nodes = self.global_nodes if which == "global" else self.local_nodes
            count = self.n_global if which == "global" else self.n_local
            count, n_points, nodes = _grow(grid.data, nodes, count, samples, eta / res, buf,
                                           n_points, which == "local", robot)
            if which == "global":
                self.global_nodes, self.n_global = nodes, count
            else:
                self.local_nodes, self.n_local = nodes, count
        new = grid.origin[:2] + buf[:n_points] * res
        # Keep one detection per cell: repeated hits on the same unknown cell add nothing.
        self.points = np.unique(np.concatenate([self.points, new]), axis=0)

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        self._grow_trees(state)
        grid = state.grid
        if len(self.points):
            cells = grid.world_to_cell(self.points)
            k = max(1, int(round(0.2 / grid.resolution)))
            keep = window_counts(grid.data < 0, cells, k) > 0
            self.points = self.points[keep]
        detected = mean_shift(self.points, self.bandwidth) if len(self.points) else np.zeros((0, 2))
        detected = detected[_unknown_area(grid, detected, 0.5 * self.info_radius) >=
                            self.min_gain]
        frontier_goals = np.array([f.goal for f in state.frontiers]).reshape(-1, 2)
        # The trees' detections first; if none of them can be reached, the map's frontiers,
        # which the detectors would find in time.
        for candidates in (detected, frontier_goals):
            candidates = candidates[state.allowed(candidates)]
            if len(candidates) == 0:
                continue
            utility = self._utility(state, candidates)
            if np.isfinite(utility).any():
                return candidates[int(np.argmax(utility))]
        return None

    def _utility(self, state: ExplorationState, candidates: np.ndarray) -> np.ndarray:
        """gain_weight * unknown area within info_radius (x hysteresis) - path cost."""
        grid = state.grid
        cells = grid.world_to_cell(candidates)
        gains = _unknown_area(grid, candidates, self.info_radius)
        near = np.hypot(*(candidates - state.pose[:2]).T) <= self.hysteresis_radius
        gains = np.where(near, gains * self.hysteresis_gain, gains)
        mask = np.zeros(grid.shape, bool)
        kk = max(1, int(round(0.5 / grid.resolution)))
        for r, c in cells:
            mask[max(r - kk, 0):r + kk + 1, max(c - kk, 0):c + kk + 1] = True
        dist = state.costmap.distances_from(state.pose[:2], mask)
        cost = np.array([dist[max(r - kk, 0):r + kk + 1, max(c - kk, 0):c + kk + 1].min()
                         for r, c in cells])
        utility = self.gain_weight * gains - cost
        utility[~np.isfinite(cost)] = -np.inf
        return utility
