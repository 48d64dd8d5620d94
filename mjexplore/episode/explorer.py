"""The explorer interface and the state every explorer sees at a decision.

An explorer is asked for a goal whenever the episode runner needs one (the previous goal
was reached, vanished or cannot be reached); it answers with a point in the ``map`` frame,
or None when it sees nothing left to explore. Classic planners and learned policies sit
behind the same interface, so one harness evaluates them all.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np
import numpy.typing as npt

from mjexplore.maps import GridMap
from mjexplore.navigation.planner import Costmap
from mjexplore.topology.frontiers import Frontier


@dataclasses.dataclass
class ExplorationState:
    """What an explorer may look at when choosing a goal.

    Attributes:
        grid: The partial map.
        pose: Robot (x, y, yaw) in the ``map`` frame.
        time: Simulated time, seconds.
        frontiers: Frontiers of ``grid``.
        costmap: The planner's costmap of ``grid``.
        visited: (k, 2) positions the robot has passed, metres (decimated).
        blacklist: (k, 2) goals that proved unreachable or unobservable, metres.
        blacklist_radius: Goals within this distance of a blacklisted one are out, metres.
        ground_truth: The true map, only for explorers allowed to know it (the oracle).
        sensor_range: The lidar's range, metres.
        target_ratio: The exploration ratio at which the episode counts as explored.
        extras: Lazily computed helpers shared between explorers (TER, ...).
    """

    grid: GridMap
    pose: np.ndarray
    time: float
    frontiers: list[Frontier]
    costmap: Costmap
    visited: np.ndarray
    blacklist: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    blacklist_radius: float = 0.5
    ground_truth: GridMap | None = None
    sensor_range: float = 6.0
    target_ratio: float = 0.985
    extras: dict = dataclasses.field(default_factory=dict)

    def allowed(self, points: npt.ArrayLike) -> np.ndarray:
        """Which of the (n, 2) candidate goals are not blacklisted."""
        points = np.asarray(points, float).reshape(-1, 2)
        if len(self.blacklist) == 0:
            return np.ones(len(points), bool)
        d = np.linalg.norm(points[:, None] - self.blacklist[None], axis=2)
        return (d > self.blacklist_radius).all(axis=1)

    def frontier_distances(self, radius: float = 0.5, nearest_only: bool = False) -> np.ndarray:
        """Path cost (metres) to the nearest traversable cell within ``radius`` of each
        frontier's goal (a square of that half-side); inf if unreachable.

        With ``nearest_only`` the search stops at the first frontier reached: only that
        frontier's distance is exact, the others read inf or more.
        """
        if not self.frontiers:
            return np.zeros(0)
        k = max(1, int(round(radius / self.grid.resolution)))
        cells = np.array([f.goal_cell for f in self.frontiers], np.int64)
        return self.costmap.distances_to_windows(self.pose[:2], cells, k,
                                                 1 if nearest_only else 0)


class Explorer(Protocol):
    """Chooses exploration goals."""

    name: str

    def reset(self, rng: np.random.Generator) -> None:
        """Starts a new episode."""

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        """A goal (x, y) in the ``map`` frame, or None if nothing is left to explore."""
