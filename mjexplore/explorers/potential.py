"""Multi-target potential field (Yu et al., MMPF, ICRA 2021; the paper's "Potential Field").

On a coarse copy of the costmap (cells of about ``coarse_cell`` metres), every frontier
cluster j attracts with a potential -K I_j / D_j(c), where I_j is its size (cells) and
D_j(c) the BFS wavefront distance from the cluster to cell c over traversable cells; cells
the robot has already passed are penalised (``visit_penalty`` per pass), which stops it
from going back and forth. From the robot's cell the field is descended greedily over
4-neighbours; the frontier it leads to is the goal (at a local minimum: the frontier with
the strongest pull at the robot).
"""

from __future__ import annotations

import numba
import numpy as np

from mjexplore.episode.explorer import ExplorationState

_D4R = np.array([-1, 1, 0, 0], np.int64)
_D4C = np.array([0, 0, -1, 1], np.int64)


@numba.njit(cache=True)
def _bfs(traversable, start, rows, cols, out):
    """4-neighbour BFS distance (cells) from ``start`` over ``traversable``; -1 unreached."""
    out[:] = -1
    queue = np.empty(rows * cols, np.int64)
    head, tail = 0, 1
    queue[0] = start
    out[start] = 0
    while head < tail:
        s = queue[head]
        head += 1
        r, c = s // cols, s % cols
        for k in range(4):
            rr, cc = r + _D4R[k], c + _D4C[k]
            if 0 <= rr < rows and 0 <= cc < cols:
                y = rr * cols + cc
                if traversable[y] and out[y] < 0:
                    out[y] = out[s] + 1
                    queue[tail] = y
                    tail += 1


@numba.njit(cache=True)
def _descend(potential, traversable, start, is_target, rows, cols, max_steps):
    """Greedy 4-neighbour descent; returns the target cell reached or -1."""
    s = start
    for _ in range(max_steps):
        if is_target[s] >= 0:
            return s
        r, c = s // cols, s % cols
        best, best_v = -1, potential[s]
        for k in range(4):
            rr, cc = r + _D4R[k], c + _D4C[k]
            if 0 <= rr < rows and 0 <= cc < cols:
                y = rr * cols + cc
                if traversable[y] and potential[y] < best_v:
                    best, best_v = y, potential[y]
        if best < 0:
            return -1
        s = best
    return -1


class PotentialField:
    """Args:
        coarse_cell: Side of the coarse cells, metres.
        gain: K.
        visit_penalty: Potential added per earlier pass of the robot through a cell.
    """

    name = "potential"

    def __init__(self, coarse_cell: float = 0.2, gain: float = 1.0,
                 visit_penalty: float = 0.1) -> None:
        self.coarse_cell = coarse_cell
        self.gain = gain
        self.visit_penalty = visit_penalty

    def reset(self, rng: np.random.Generator) -> None:
        del rng

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        if not state.frontiers:
            return None
        grid = state.grid
        f = max(1, min(int(round(self.coarse_cell / grid.resolution)), *grid.shape))
        rows, cols = grid.shape[0] // f, grid.shape[1] // f
        fine = state.costmap.traversable[: rows * f, : cols * f]
        traversable = fine.reshape(rows, f, cols, f).any(axis=(1, 3)).reshape(-1)

        def coarse(xy):
            r, c = grid.world_to_cell(np.asarray(xy)) // f
            return int(np.clip(r, 0, rows - 1) * cols + np.clip(c, 0, cols - 1))

        start = coarse(state.pose[:2])
        traversable[start] = True
        is_target = np.full(rows * cols, -1, np.int64)
        potential = np.zeros(rows * cols)
        dist = np.empty(rows * cols, np.int64)
        pull = np.zeros(len(state.frontiers))
        for j, front in enumerate(state.frontiers):
            cell = coarse(front.goal)
            traversable[cell] = True
            is_target[cell] = j
            _bfs(traversable, cell, rows, cols, dist)
            reached = dist >= 0
            potential[reached] -= self.gain * front.size / np.maximum(dist[reached], 1)
            pull[j] = front.size / max(dist[start], 1) if dist[start] >= 0 else 0.0
        if not pull.any():
            # The coarse grid lost the way (a door narrower than two coarse cells after
            # inflation): fall back on path distances over the fine costmap.
            d = state.frontier_distances(nearest_only=True)
            return state.frontiers[int(np.argmin(d))].goal if np.isfinite(d).any() else None
        for xy in state.visited:
            potential[coarse(xy)] += self.visit_penalty
        self.add_potential(state, potential.reshape(rows, cols), f)
        reached = _descend(potential, traversable, start, is_target, rows, cols, rows * cols)
        j = is_target[reached] if reached >= 0 else int(np.argmax(pull))
        return state.frontiers[j].goal

    def add_potential(self, state: ExplorationState, potential: np.ndarray, f: int) -> None:
        """Adds further terms to the (rows, cols) coarse ``potential`` (in place), whose
        cells are ``f`` map cells on a side; none here (the multi-robot field adds its
        robots' repulsion)."""
