"""Frontier TSP: a global tour over the known map's frontiers (in the style of TARE and
FUEL's global planning).

At each decision every frontier's goal (the free cell beside it) is a viewpoint; the
viewpoints are ordered as an open travelling-salesman tour from the robot over path
distances on the known map (:mod:`mjexplore.navigation.tour`: coarse-graph Dijkstra and
OR-Tools), and the robot drives to the first. Frontiers no path reaches are left out.
Unlike nearest-frontier, which takes the closest frontier and may leave a near one behind
to come back for it, the tour weighs every frontier's place in the whole route.
"""

from __future__ import annotations

import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.navigation.tour import CoarseGraph, TourConfig, open_tour


class FrontierTsp:
    """Args:
        tour: Tour solver settings.
        block: Fine cells per node of the path graph along each axis.
    """

    name = "frontier_tsp"

    def __init__(self, tour: TourConfig | None = None, block: int = 4) -> None:
        self.tour_config = tour or TourConfig()
        self.block = block

    def reset(self, rng: np.random.Generator) -> None:
        del rng
        self.tour: list[np.ndarray] = []

    def plan(self, state: ExplorationState) -> list[np.ndarray]:
        """The frontier goals in tour order (reachable ones only)."""
        if not state.frontiers:
            return []
        graph = CoarseGraph(state.grid, state.costmap.traversable, self.block)
        goals = np.array([f.goal for f in state.frontiers])
        distance = graph.distance_matrix(np.vstack([state.pose[:2], goals]))
        reachable = np.flatnonzero(np.isfinite(distance[0, 1:])) + 1
        if not len(reachable):
            return []
        keep = np.r_[0, reachable]
        # Warm start: the previous tour's order, where its goals are still frontiers.
        rank = {tuple(np.round(g, 3)): i for i, g in enumerate(self.tour)}
        warm = sorted(range(1, len(keep)),
                      key=lambda j: rank.get(tuple(np.round(goals[keep[j] - 1], 3)), len(rank)))
        order = open_tour(distance[np.ix_(keep, keep)], self.tour_config, initial=warm)
        self.tour = [goals[keep[j] - 1] for j in order]
        return self.tour

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        tour = self.plan(state)
        return tour[0].copy() if tour else None
