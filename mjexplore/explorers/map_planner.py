"""The oracle's coverage planner on a map short of the truth, made afresh at each decision:
the horizon oracle (the truth within ``horizon`` metres of what the robot has mapped), and
the planner that the prediction-based explorers run on a predicted map.

:class:`PlanningMapOracle` runs :class:`~mjexplore.explorers.oracle.OracleExplorer`'s plan
(viewpoints that see the cells still needed, a greedy cover, an OR-Tools open tour, pruning
by what the tour sees on the way) on its *planning map* (:meth:`PlanningMapOracle.
planning_data`): what each viewpoint sees is ray cast on the planning map, the cells to see
are its observable cells still unknown in the robot's map, and the paths are searched on
its traversable cells (a costmap of the planning map, updated in place at each decision).
Like the oracle's, a plan leaves unseen the share of the planning map's cells that the
target ratio plus ``margin`` allows, the least worth a detour. On the whole truth it makes
the oracle's plans: the costmap's squared distances to walls are the exact integers the
oracle's GVD gives, and the viewpoints it drops (beyond the lidar's range of every cell to
see) could add nothing to a plan.

:class:`HorizonOracle` plans on the truth within ``horizon`` metres of the robot's mapped
cells (unknown beyond) and, as the oracle drives on the ground truth, drives on that map:
what perfect prediction up to that distance is worth, between nearest-frontier's nothing
and the full oracle's everything.
"""

from __future__ import annotations

import cv2
import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.explorers.oracle import OracleExplorer
from mjexplore.mapping.metrics import observable_ground_truth
from mjexplore.mapping.prediction import block_shares
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap, is_free, is_occupied
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.navigation.tour import CoarseGraph


def _distance_to(mask: np.ndarray) -> np.ndarray:
    """(rows, cols) float32 Euclidean distance in cells from each cell to the nearest cell
    of ``mask`` (a large value everywhere when ``mask`` is empty)."""
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


class PlanningMapOracle(OracleExplorer):
    """The oracle's planner on a planning map made at each decision (see the module
    docstring); subclasses define :meth:`planning_data`.

    Args:
        resolution: Cell side of the map planned on, metres (a whole multiple of the
            robot's map's); None: the robot's map's. On coarser cells the views, the cover
            and the paths cost far less (at 0.2 m against 0.05 m, lists 16 times shorter):
            a coarse cell is a wall where at least ``wall_share`` of its cells are, free
            where at least half are, unknown otherwise; it is still to see where at least
            half of its cells are unmapped. Paths are searched on its cells (no coarser
            graph).
        wall_share: See ``resolution``. A thin wall crossing a coarse cell may hold less
            than a quarter of it: at the default the planner then sees through it.
        **kwargs: :class:`~mjexplore.explorers.oracle.OracleExplorer`'s settings.
    """

    def __init__(self, resolution: float | None = None, wall_share: float = 0.25,
                 **kwargs) -> None:
        if not 0 < wall_share <= 1:
            raise ValueError("wall_share must be in (0, 1]")
        super().__init__(**kwargs)
        self.resolution = resolution
        self.wall_share = wall_share
        self._costmap: Costmap | None = None

    def planning_data(self, state: ExplorationState) -> np.ndarray:
        """The planning map's cells at this decision (int8, the robot's map's shape)."""
        raise NotImplementedError

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self._cells = np.zeros((0, 2), np.int64)  # The viewpoints' (row, col) cells.
        self._view_cache: dict[tuple[int, int], np.ndarray] = {}  # Lists by viewpoint cell.
        self._cast_on: np.ndarray | None = None  # The planning map they were cast on.

    def _block(self, grid: GridMap) -> int:
        """The robot's map's cells per planning cell along each axis."""
        if self.resolution is None:
            return 1
        k = int(round(self.resolution / grid.resolution))
        if k < 1 or abs(k * grid.resolution - self.resolution) > 1e-6:
            raise ValueError(f"planning resolution {self.resolution} m is not a whole "
                             f"multiple of the map's {grid.resolution} m")
        return k

    def ground_truth_costmap(self, state: ExplorationState) -> Costmap:
        """The costmap of the planning map: all unknown until the first decision, then
        updated in place at each (what :class:`HorizonOracle` drives on)."""
        grid = state.ground_truth if state.ground_truth is not None else state.grid
        k = self._block(grid)
        shape = (-(-grid.shape[0] // k), -(-grid.shape[1] // k))
        self._plan = GridMap(np.full(shape, UNKNOWN, np.int8), grid.resolution * k,
                             grid.origin)
        self._dist2 = np.zeros(shape, np.float32)
        self._costmap = Costmap(self._plan, self._dist2, PlannerConfig())
        return self._costmap

    def unknown_cells(self, state: ExplorationState) -> np.ndarray:
        return self.coarse_unknown(state.grid).reshape(-1)

    def coarse_unknown(self, grid: GridMap) -> np.ndarray:
        """(planning rows, cols) bool: the planning cells still to see in ``grid``: at least
        half their cells unmapped, and a wall's cell only while none of its cells is mapped
        (the lidar maps a wall's face, never its inside)."""
        k = self._block(grid)
        if k == 1:
            return grid.data < 0
        shares = block_shares(grid.data < 0, k)
        unknown = shares >= 0.5
        if self._costmap is not None and self._plan.shape == shares.shape:
            walls = self._plan.data == OCCUPIED
            unknown[walls] = shares[walls] >= 1.0
        return unknown

    def _planning_map(self, state: ExplorationState) -> np.ndarray:
        """:meth:`planning_data` on the planning cells."""
        data = self.planning_data(state)
        k = self._block(state.grid)
        if k == 1:
            return data
        out = np.full(self._plan.shape, UNKNOWN, np.int8)
        out[block_shares(is_free(data), k) >= 0.5] = FREE
        out[block_shares(is_occupied(data), k) >= self.wall_share] = OCCUPIED
        return out

    def prepare(self, state: ExplorationState) -> None:
        """This decision's planning map, its costmap and path graph, viewpoints and views;
        the previous plan is carried over where its viewpoints are still candidates."""
        k = self._block(state.grid)
        if (self._costmap is None or self._plan.resolution != state.grid.resolution * k
                or self._plan.shape != (-(-state.grid.shape[0] // k),
                                        -(-state.grid.shape[1] // k))):
            self.ground_truth_costmap(state)
        assert self._costmap is not None  # Made just above when missing.
        plan_map = self._plan
        plan_map.data[...] = self._planning_map(state)
        # Squared distances in cells are integers: rounded, they are the GVD's exactly.
        self._dist2[...] = np.rint(_distance_to(~plan_map.free) ** 2)
        self._costmap.update(None)
        self.graph = CoarseGraph(plan_map, self._costmap.traversable, max(1, 4 // k))
        observable = observable_ground_truth(plan_map).known.reshape(-1)
        need = observable & self.unknown_cells(state)
        near = (_distance_to(need.reshape(plan_map.shape)) * plan_map.resolution
                <= state.sensor_range)
        cells = np.argwhere(self.viewpoint_cells(self._costmap, state.pose) & near)
        index = {tuple(c): i for i, c in enumerate(cells)}
        carried = [index.get(tuple(self._cells[i])) for i in self.plan]
        self.plan = [i for i in carried if i is not None]
        self.current = (None if self.current is None
                        else index.get(tuple(self._cells[self.current])))
        self._cells = cells
        self.set_views(plan_map, cells, observable, self._views_of(plan_map, cells, need,
                                                                   state.sensor_range), need)

    def _views_of(self, plan_map: GridMap, cells: np.ndarray, need: np.ndarray,
                  sensor_range: float) -> list[np.ndarray]:
        """What each viewpoint sees of the cells to see: kept from earlier decisions for
        the viewpoints farther than the lidar's range from every cell of the planning map
        that changed since, cast again for the others. A kept list may hold cells mapped
        since (:meth:`set_views` cuts them); it misses none still to see, as the cells to
        see change only where the planning map does, or by being mapped."""
        if self._cast_on is None or self._cast_on.shape != plan_map.shape:
            self._view_cache, self._cast_on = {}, plan_map.data.copy()
        changed = plan_map.data != self._cast_on
        if changed.any():
            dirty = _distance_to(changed) * plan_map.resolution <= sensor_range + \
                plan_map.resolution
            self._view_cache = {c: v for c, v in self._view_cache.items() if not dirty[c]}
            self._cast_on = plan_map.data.copy()
        keys = [tuple(c) for c in cells]
        todo = [i for i, key in enumerate(keys) if key not in self._view_cache]
        if todo:
            cast = self.cast_views(plan_map, cells[todo], need, sensor_range)
            self._view_cache.update(zip((keys[i] for i in todo), cast))
        return [self._view_cache[key] for key in keys]

    def replan(self, state: ExplorationState) -> list[int]:
        self.prepare(state)
        return super().replan(state)


class HorizonOracle(PlanningMapOracle):
    """The oracle's planner on the truth within ``horizon`` metres of the mapped cells,
    driving on it (see the module docstring). Privileged: it reads the ground truth.

    Args:
        horizon: How far beyond the mapped cells the truth is known, metres.
        **kwargs: :class:`~mjexplore.explorers.oracle.OracleExplorer`'s settings.
    """

    def __init__(self, horizon: float = 5.0, **kwargs) -> None:
        if horizon < 0:
            raise ValueError("horizon must be >= 0 (metres)")
        super().__init__(**kwargs)
        self.horizon = float(horizon)
        self.name = f"oracle_{horizon:g}m"

    def planning_data(self, state: ExplorationState) -> np.ndarray:
        gt = state.ground_truth
        if gt is None:
            raise ValueError("the horizon oracle needs the ground truth "
                             "(ExplorationState.ground_truth)")
        inside = _distance_to(state.grid.known) * gt.resolution <= self.horizon
        return np.where(inside, gt.data, UNKNOWN).astype(np.int8)
