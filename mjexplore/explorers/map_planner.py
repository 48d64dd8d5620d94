"""The horizon oracle: the oracle's coverage planner given the truth only within ``horizon``
metres of what the robot has mapped, a bound on what perfect prediction up to that distance
is worth (between nearest-frontier's nothing and the full oracle's everything).

At every decision it makes its *planning map*, the ground truth where a mapped cell lies
within ``horizon`` and unknown beyond, and runs
:class:`~mjexplore.explorers.oracle.OracleExplorer`'s plan on it (viewpoints that see the
cells still needed, a greedy cover, an OR-Tools open tour, pruning by what the tour sees on
the way): what each viewpoint sees is ray cast on the planning map, the cells to see are its
observable cells still unknown in the robot's map, and the paths are searched on its
traversable cells. As the oracle drives on the ground truth, it drives on its planning map
(the navigation costmap is updated in place at each decision). Like the oracle's, its plan
leaves unseen the share of the planning map's cells that the target ratio plus ``margin``
allows, the least worth a detour; with the whole truth within the horizon it plans as the
oracle does.
"""

from __future__ import annotations

import cv2
import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.explorers.oracle import OracleExplorer
from mjexplore.mapping.metrics import observable_ground_truth
from mjexplore.maps import UNKNOWN, GridMap
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.navigation.tour import CoarseGraph


def _distance_to(mask: np.ndarray) -> np.ndarray:
    """(rows, cols) float32 Euclidean distance in cells from each cell to the nearest cell
    of ``mask`` (a large value everywhere when ``mask`` is empty)."""
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


class HorizonOracle(OracleExplorer):
    """The oracle's planner on the truth within ``horizon`` metres of the mapped cells (see
    the module docstring). Privileged: it reads the ground truth.

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
        self._costmap: Costmap | None = None

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self._cells = np.zeros((0, 2), np.int64)  # The viewpoints' (row, col) cells.

    def ground_truth_costmap(self, state: ExplorationState) -> Costmap:
        """The costmap it navigates on: of its planning map, all unknown until the first
        decision, then updated in place at each."""
        gt = state.ground_truth
        self._plan = GridMap(np.full(gt.shape, UNKNOWN, gt.data.dtype), gt.resolution,
                             gt.origin)
        self._dist2 = np.zeros(gt.shape, np.float32)
        self._costmap = Costmap(self._plan, self._dist2, PlannerConfig())
        return self._costmap

    def prepare(self, state: ExplorationState) -> None:
        """This decision's planning map, its costmap and path graph, viewpoints and views;
        the previous plan is carried over where its viewpoints are still candidates."""
        gt = state.ground_truth
        if gt is None:
            raise ValueError("the horizon oracle needs the ground truth "
                             "(ExplorationState.ground_truth)")
        if self._costmap is None or self._plan.shape != gt.shape:
            self.ground_truth_costmap(state)
        plan_map = self._plan
        inside = _distance_to(state.grid.known) * gt.resolution <= self.horizon
        plan_map.data[...] = np.where(inside, gt.data, UNKNOWN)
        self._dist2[...] = _distance_to(~plan_map.free) ** 2
        self._costmap.update(None)
        self.graph = CoarseGraph(plan_map, self._costmap.traversable)
        observable = observable_ground_truth(plan_map).known.reshape(-1)
        need = observable & (state.grid.data.reshape(-1) < 0)
        near = (_distance_to(need.reshape(gt.shape)) * gt.resolution
                <= state.sensor_range)
        cells = np.argwhere(self.viewpoint_cells(self._costmap, state.pose) & near)
        index = {tuple(c): i for i, c in enumerate(cells)}
        carried = [index.get(tuple(self._cells[i])) for i in self.plan]
        self.plan = [i for i in carried if i is not None]
        self.current = (None if self.current is None
                        else index.get(tuple(self._cells[self.current])))
        self._cells = cells
        self.set_views(plan_map, cells, observable, need, state.sensor_range)

    def replan(self, state: ExplorationState) -> list[int]:
        self.prepare(state)
        return super().replan(state)
