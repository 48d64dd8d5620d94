"""A robot's costmap with its teammates in it: their bodies as obstacles.

Each robot of a team plans on the shared map, with the cells where its ``base_link`` would
bring its footprint into a teammate's body made untraversable (:class:`TeamCostmap`). The
teammates move, so the overlay is set anew every control period
(:meth:`TeamCostmap.set_teammates`); the cells it leaves get their map cost back. The
navigator sees the costmap's version change and checks its path against the new costs, so a
teammate that steps into the path makes the robot replan at once
(:class:`~mjexplore.navigation.navigator.Navigator`). Whether a goal is out of reach because
of the teammates alone, a way that will open when they move on, is asked with
:meth:`TeamCostmap.blocked_by_teammates`.
"""

from __future__ import annotations

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


class TeamCostmap(Costmap):
    """A :class:`Costmap` with the teammates' bodies as obstacles.

    Args:
        grid: The (shared) map, read live.
        distance2: Its squared distances to the nearest occupied cell, read live.
        config: Costmap settings.
        teammate_radius: Cells within this distance (metres) of a teammate's body centre
            are not traversable: the teammate's bounding circle plus this robot's footprint
            radius about ``base_link`` plus a margin.
    """

    def __init__(self, grid: GridMap, distance2: np.ndarray,
                 config: PlannerConfig | None = None, teammate_radius: float = 0.55) -> None:
        self.teammate_radius = float(teammate_radius)
        self._overlay = np.zeros(0, np.int64)
        self._offsets = disk_offsets(teammate_radius / grid.resolution)
        self._centres = np.zeros((0, 2), np.int64)
        self._mark = np.zeros(grid.data.size, bool)
        super().__init__(grid, distance2, config)

    @property
    def teammate_cells(self) -> np.ndarray:
        """Flat indices of the cells the teammates block now."""
        return self._overlay

    def update(self, cells: np.ndarray | None) -> None:
        super().update(cells)
        if len(self._overlay):
            self.cost[self._overlay] = -1.0

    def _cells_around(self, centres: np.ndarray) -> np.ndarray:
        grid = self.grid
        if len(centres) == 0:
            return np.zeros(0, np.int64)
        rc = grid.world_to_cell(np.asarray(centres, float).reshape(-1, 2))
        cells = (rc[:, None, :] + self._offsets[None]).reshape(-1, 2)
        rows, cols = grid.shape
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < rows) & (cells[:, 1] >= 0) & (
            cells[:, 1] < cols)
        flat = cells[inside, 0] * cols + cells[inside, 1]
        return np.unique(flat) if len(centres) > 1 else flat

    def set_teammates(self, centres: np.ndarray) -> None:
        """Makes the cells around the teammates' body centres ((k, 2) metres, ``map``
        frame) untraversable, and gives the cells they left their map costs back."""
        centres = np.asarray(centres, float).reshape(-1, 2)
        cells = self.grid.world_to_cell(centres)
        if cells.shape == self._centres.shape and np.array_equal(cells, self._centres):
            return  # The same cells as before.
        self._centres = cells
        old, self._overlay = self._overlay, self._cells_around(centres)
        mark = self._mark
        mark[self._overlay] = True
        left = old[~mark[old]]
        mark[self._overlay] = False
        self.update(left)

    def blocked_by_teammates(self, start_xy: np.ndarray, goal_xy: np.ndarray,
                             goal_radius: float) -> bool:
        """Whether a path to ``goal_xy`` exists on the map but the teammates block it (no
        path with them, one without). Costs are as before on return."""
        if len(self._overlay) == 0 or self.plan(start_xy, goal_xy, goal_radius) is not None:
            return False
        overlay, self._overlay = self._overlay, np.zeros(0, np.int64)
        try:
            super().update(overlay)
            return self.plan(start_xy, goal_xy, goal_radius) is not None
        finally:
            self._overlay = overlay
            self.cost[overlay] = -1.0
            self.version += 1


__all__ = ["TeamCostmap", "disk_offsets"]
