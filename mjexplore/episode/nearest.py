"""Nearest frontier (Yamauchi 1997; the paper's "Cost", Explore-Bench's "cost").

Goal: the frontier with the shortest path from the robot over the known map.
"""

from __future__ import annotations

import numpy as np

from mjexplore.episode.explorer import ExplorationState


class NearestFrontier:
    name = "nearest"

    def reset(self, rng: np.random.Generator) -> None:
        del rng

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        if not state.frontiers:
            return None
        d = state.frontier_distances(nearest_only=True)
        if not np.isfinite(d).any():
            return None
        return state.frontiers[int(np.argmin(d))].goal
