"""A robot's costmap with the moving bodies it knows in it: teammates and people.

Each robot plans on the map with the cells where its ``base_link`` would bring its
footprint into a moving body made untraversable (:class:`BodyCostmap`): a teammate's
(bounding circle plus the robot's footprint radius plus a margin) or a person's (the
person's disc, likewise). The bodies move, so the overlay is set anew every control period
(:meth:`BodyCostmap.set_bodies`); the cells it leaves get their map cost back. The navigator
sees the costmap's version change and checks its path against the new costs, so a body that
steps into the path makes the robot replan at once
(:class:`~mjexplore.navigation.navigator.Navigator`). Whether a goal is out of reach because
of the bodies alone, a way that will open when they move on, is asked with
:meth:`BodyCostmap.blocked_by_bodies`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np

from mjexplore.maps import GridMap
from mjexplore.navigation.planner import Costmap, PlannerConfig


def disk_offsets(radius_cells: float) -> np.ndarray:
    """(k, 2) integer (row, col) offsets of the cells whose centres lie within
    ``radius_cells`` of a cell's centre."""
    k = int(np.floor(radius_cells))
    r, c = np.mgrid[-k:k + 1, -k:k + 1]
    inside = r ** 2 + c ** 2 <= radius_cells ** 2
    return np.column_stack([r[inside], c[inside]])


class BodyCostmap(Costmap):
    """A :class:`Costmap` with moving bodies as obstacles.

    Args:
        grid: The (shared) map, read live.
        distance2: Its squared distances to the nearest occupied cell, read live.
        config: Costmap settings.
        teammate_radius: Cells within this distance (metres) of a teammate's body centre
            are not traversable: the teammate's bounding circle plus this robot's footprint
            radius about ``base_link`` plus a margin.
        person_radius: The same about a person's centre.
    """

    def __init__(self, grid: GridMap, distance2: np.ndarray,
                 config: PlannerConfig | None = None, teammate_radius: float = 0.55,
                 person_radius: float = 0.6) -> None:
        self.teammate_radius = float(teammate_radius)
        self.person_radius = float(person_radius)
        self._overlay = np.zeros(0, np.int64)
        self._offsets = disk_offsets(teammate_radius / grid.resolution)
        self._person_offsets = disk_offsets(person_radius / grid.resolution)
        self._centres = np.zeros((0, 3), np.int64)
        self._mark = np.zeros(grid.data.size, bool)
        super().__init__(grid, distance2, config)

    @property
    def body_cells(self) -> np.ndarray:
        """Flat indices of the cells the bodies block now."""
        return self._overlay

    def update(self, cells: np.ndarray | None) -> None:
        super().update(cells)
        if len(self._overlay):
            self.cost[self._overlay] = -1.0

    def _cells_around(self, centres: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        grid = self.grid
        if len(centres) == 0:
            return np.zeros(0, np.int64)
        rc = grid.world_to_cell(np.asarray(centres, float).reshape(-1, 2))
        cells = (rc[:, None, :] + offsets[None]).reshape(-1, 2)
        rows, cols = grid.shape
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < rows) & (cells[:, 1] >= 0) & (
            cells[:, 1] < cols)
        flat = cells[inside, 0] * cols + cells[inside, 1]
        return np.unique(flat) if len(centres) > 1 else flat

    def set_bodies(self, teammates: np.ndarray, people: np.ndarray | None = None) -> None:
        """Makes the cells around the teammates' body centres and the people's centres
        ((k, 2) metres each, ``map`` frame) untraversable, and gives the cells they left
        their map costs back."""
        teammates = np.asarray(teammates, float).reshape(-1, 2)
        people = np.zeros((0, 2)) if people is None else np.asarray(people, float).reshape(-1, 2)
        cells = self.grid.world_to_cell(np.concatenate([teammates, people]))
        cells = np.column_stack([cells, np.arange(len(cells)) >= len(teammates)])
        if cells.shape == self._centres.shape and np.array_equal(cells, self._centres):
            return  # The same cells as before.
        self._centres = cells
        overlay = self._cells_around(teammates, self._offsets)
        if len(people):
            overlay = np.unique(np.concatenate(
                [overlay, self._cells_around(people, self._person_offsets)]))
        old, self._overlay = self._overlay, overlay
        mark = self._mark
        mark[self._overlay] = True
        left = old[~mark[old]]
        mark[self._overlay] = False
        self.update(left)

    def blocked_by_bodies(self, start_xy: np.ndarray, goal_xy: np.ndarray,
                          goal_radius: float) -> bool:
        """Whether a path to ``goal_xy`` exists on the map but the bodies block it (no
        path with them, one without). Costs are as before on return."""
        if len(self._overlay) == 0 or self.plan(start_xy, goal_xy, goal_radius) is not None:
            return False
        with self._without_bodies():
            return self.plan(start_xy, goal_xy, goal_radius) is not None

    def reachable_without_bodies(self, start_xy: np.ndarray, goals_xy: np.ndarray) -> bool:
        """Whether a path from ``start_xy`` would reach one of ``goals_xy`` ((k, 2) metres,
        ``map`` frame) were the bodies not there. Costs are as before on return."""
        targets = np.zeros(self.grid.shape, bool)
        cells = self.grid.world_to_cell(np.asarray(goals_xy, float).reshape(-1, 2))
        inside = ((cells >= 0) & (cells < self.grid.shape)).all(axis=1)
        targets[cells[inside, 0], cells[inside, 1]] = True
        if len(self._overlay) == 0 or not targets.any():
            return False
        with self._without_bodies():
            return bool(np.isfinite(self.distances_from(start_xy, targets, 1)).any())

    @contextlib.contextmanager
    def _without_bodies(self) -> Iterator[None]:
        """The map's costs without the bodies, for the body of the ``with``."""
        overlay, self._overlay = self._overlay, np.zeros(0, np.int64)
        try:
            super().update(overlay)
            yield
        finally:
            self._overlay = overlay
            self.cost[overlay] = -1.0
            self.version += 1


__all__ = ["BodyCostmap", "disk_offsets"]
