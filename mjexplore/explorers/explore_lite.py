"""explore_lite (m-explore, Hörner 2016): the ROS standard frontier explorer, ported.

Frontier search as in explore_lite's ``FrontierSearch::searchFrom``: a breadth-first
search over the free space connected to the robot finds frontier cells (unknown cells
with a free 4-neighbour), each new one grown into a frontier over its 8-connected frontier
neighbours. A frontier keeps its size (cells), its centroid and ``min_distance``, the
straight-line distance from the robot to its closest cell; frontiers shorter than
``min_frontier_size`` are dropped. Each is scored by ``frontierCost``::

    cost = potential_scale * min_distance * resolution - gain_scale * size * resolution

and the goal is the centroid of the cheapest frontier not on the blacklist (a frontier is
on it when its centroid lies within 5 cells, in x and in y, of a blacklisted goal).
explore_lite multiplies ``min_distance``, already in metres, by the resolution as well;
``resolution_scaled_distance`` keeps that (the port is faithful by default) or drops it.
The plan is remade every ``1 / planner_frequency`` seconds; a goal to which
``min_distance`` has not shrunk for ``progress_timeout`` seconds is blacklisted, as is a
goal the navigator cannot reach (move_base's abort, here the episode's refusal). With no
frontier left the explorer stops.

One deviation, for a failure of the package: explore_lite keeps the progress of the latest
goal only, so two frontiers whose costs trade places at every re-plan (the robot's move
towards one makes the other cheaper) restart each other's clock and the robot shuttles
between them for ever. Here every goal chosen within the last ``progress_timeout`` seconds
keeps its own progress record (goals within explore_lite's 5-cell tolerance are one), so
such a pair runs out of time like a single goal would.

Not ported: explore_lite hands the centroid to move_base, whose planner may cross unknown
space; ours plans on the known map, so a centroid is reached within the navigator's
tolerance from the known side.
"""

from __future__ import annotations

from typing import cast

import cv2
import numpy as np
import numpy.typing as npt

from mjexplore.episode.explorer import ExplorationState
from mjexplore.topology.frontiers import frontier_mask


class ExploreLite:
    """Args (explore_lite's parameters and defaults):
        potential_scale: Weight of the distance term.
        gain_scale: Weight of the frontier size term.
        min_frontier_size: Shortest frontier considered, metres.
        planner_frequency: Rate at which the plan is remade, Hz.
        progress_timeout: Seconds without getting closer before a goal is blacklisted.
        resolution_scaled_distance: Multiply the distance (metres) by the map resolution,
            as explore_lite's code does.
    """

    name = "explore_lite"

    def __init__(self, potential_scale: float = 3.0, gain_scale: float = 1.0,
                 min_frontier_size: float = 0.75, planner_frequency: float = 0.33,
                 progress_timeout: float = 30.0,
                 resolution_scaled_distance: bool = True) -> None:
        if planner_frequency <= 0 or progress_timeout <= 0 or min_frontier_size < 0:
            raise ValueError("planner_frequency and progress_timeout must be > 0, "
                             "min_frontier_size >= 0")
        self.potential_scale = potential_scale
        self.gain_scale = gain_scale
        self.min_frontier_size = min_frontier_size
        self.replan_period = 1.0 / planner_frequency
        self.progress_timeout = progress_timeout
        self.resolution_scaled_distance = resolution_scaled_distance

    def reset(self, rng: np.random.Generator) -> None:
        del rng
        self.blacklist: list[np.ndarray] = []
        # Per recent goal: [goal, least min_distance, time it was reached, last chosen].
        self.progress: list[list] = []

    def frontiers(self, state: ExplorationState) -> list[tuple[np.ndarray, int, float]]:
        """explore_lite's frontiers of the map: (centroid (x, y) in metres, size in cells,
        min_distance in metres), cheapest first."""
        grid = state.grid
        free = grid.free
        _, labels = cv2.connectedComponents(free.astype(np.uint8), connectivity=8)
        r, c = grid.world_to_cell(np.asarray(state.pose[:2], float))
        if not (0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]) or not free[r, c]:
            # The robot's own cell may be unknown or a wall cell under range noise: start
            # from the nearest free cell, as explore_lite searches from the nearest clear one.
            cells = np.argwhere(free)
            if not len(cells):
                return []
            r, c = cells[np.argmin(((cells - (r, c)) ** 2).sum(axis=1))]
        region = labels == labels[r, c]
        candidates = frontier_mask(grid, region)
        n, groups = cv2.connectedComponents(candidates.astype(np.uint8), connectivity=8)
        if n <= 1:
            return []
        rows, cols = np.nonzero(groups)
        ids = cast("npt.NDArray[np.int32]", groups[rows, cols])  # cv2's labels are int32.
        size = np.bincount(ids, minlength=n)
        xy = grid.cell_to_world(np.column_stack([rows, cols]))
        centroid = np.column_stack([np.bincount(ids, xy[:, 0], n),
                                    np.bincount(ids, xy[:, 1], n)]) / np.maximum(size, 1)[:, None]
        dist = np.linalg.norm(xy - np.asarray(state.pose[:2], float), axis=1)
        min_distance = np.full(n, np.inf)
        np.minimum.at(min_distance, ids, dist)
        res = grid.resolution
        keep = np.flatnonzero(size * res >= self.min_frontier_size)
        keep = keep[keep > 0]
        scale = res if self.resolution_scaled_distance else 1.0
        cost = (self.potential_scale * min_distance[keep] * scale -
                self.gain_scale * size[keep] * res)
        return [(centroid[k], int(size[k]), float(min_distance[k]))
                for k in keep[np.argsort(cost, kind="stable")]]

    @staticmethod
    def _near(a: np.ndarray, b: np.ndarray, resolution: float) -> bool:
        """explore_lite's goal tolerance: within 5 cells in x and in y."""
        return abs(a[0] - b[0]) < 5 * resolution and abs(a[1] - b[1]) < 5 * resolution

    def _on_blacklist(self, goal: np.ndarray, resolution: float) -> bool:
        return any(self._near(goal, b, resolution) for b in self.blacklist)

    def _stalled_for(self, goal: np.ndarray, distance: float, t: float,
                     resolution: float) -> float:
        """Seconds since ``min_distance`` to ``goal`` last shrank (its record is updated)."""
        self.progress = [r for r in self.progress if t - r[3] <= self.progress_timeout]
        for record in self.progress:
            if self._near(record[0], goal, resolution):
                if distance < record[1]:
                    record[1], record[2] = distance, t
                record[3] = t
                return t - record[2]
        self.progress.append([goal, distance, t, t])
        return 0.0

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        res = state.grid.resolution
        # Goals the episode refused or gave up on are move_base's aborted goals.
        for goal in state.blacklist:
            if not self._on_blacklist(goal, res):
                self.blacklist.append(np.asarray(goal, float))
        for goal, _, distance in self.frontiers(state):
            if self._on_blacklist(goal, res):
                continue
            if self._stalled_for(goal, distance, state.time, res) <= self.progress_timeout:
                return goal.copy()
            self.blacklist.append(goal)  # No progress for too long: give the goal up.
        return None
