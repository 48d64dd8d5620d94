"""Predicted tour: ``pocket_nearest``, departing from its choice when the oracle's planner,
run on a *predicted* map, says another frontier saves more than ``margin_m``.

At each decision the partial map's unknown cells are filled from a prediction
(:class:`PredictedMapPlanner`): free where the predicted free probability is at least
``free_above``, a wall where it is at most ``occupied_below``, unknown where the
prediction is uncertain in between; the planner works on the predictor's 0.2 m cells.
The oracle's coverage planner
(:class:`~mjexplore.explorers.map_planner.PlanningMapOracle`) plans a tour of viewpoints
that see the predicted map's cells still unknown, and scores each valid TER frontier node
by the path to it plus the tour that is left after it
(:meth:`~mjexplore.explorers.oracle.OracleExplorer.expert_lookahead`); the robot keeps
``pocket_nearest``'s node unless the best one is shorter by more than ``margin_m``. It
drives on its own map, as every explorer does.

Beside it, the other explorers on a prediction: :class:`PredictedPlan` (the horizon
oracle's plan on the prediction, followed on the robot's map), :class:`PredictedDrive` (the
same, driving on the prediction) and :class:`PredictedPocketNearest` (pockets read from
the predicted map).

The prediction's ``source``:

* ``learned``: the map predictor (:mod:`mjexplore.mapping.prediction`, ``mjexplore
  train-predictor``);
* ``inpainting``: OpenCV's inpainting of the known map (the non-learned ablation);
* ``truth``: the ground truth (privileged: what perfect prediction is worth; with a margin
  of 0 it chooses as the oracle's lookahead does).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from mjexplore.episode.explorer import ExplorationState
from mjexplore.errors import UserInputError
from mjexplore.explorers.map_planner import PlanningMapOracle, _distance_to
from mjexplore.explorers.oracle import LOOKAHEAD_MARGIN
from mjexplore.explorers.pocket_nearest import PocketNearest, TruePocketNearest
from mjexplore.mapping.prediction import CONFIDENT
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from mjexplore.navigation.planner import Costmap, PlannerConfig

SOURCES = ("learned", "inpainting", "truth")
MAP_PREDICTOR = "models/map_predictor/predictor.safetensors"
# The planning cells: the predictor's (0.2 m). On the office's 0.05 m cells a decision's
# views, cover and paths took 6.7 s (median); on 0.2 m cells, a small fraction of that.
PLAN_RESOLUTION = 0.2


def free_probability(grid: GridMap, predictor: Any = None) -> np.ndarray:
    """(rows, cols) float32 predicted free probability of every cell of ``grid``: the
    learned ``predictor``'s (:func:`~mjexplore.mapping.prediction.map_predictor`) or, with
    None, OpenCV's inpainting; the coarse prediction spread over its blocks."""
    from mjexplore.mapping.prediction import block_size, coarse_channels, inpainted

    channels = coarse_channels(grid)
    coarse = predictor(channels) if predictor is not None else inpainted(channels)
    k = block_size(grid)
    return np.repeat(np.repeat(coarse, k, 0), k, 1)[:grid.shape[0], :grid.shape[1]]


class PredictedMapPlanner(PlanningMapOracle):
    """The oracle's planner on the robot's map with its unknown cells predicted.

    Args:
        source: ``learned``, ``inpainting`` or ``truth`` (see the module docstring).
        predictor: The learned predictor's weights file (a relative path is looked up from
            the working directory, then from the repository root).
        free_above: Least free probability of a cell planned as free.
        occupied_below: Greatest free probability of a cell planned as a wall.
        **kwargs: :class:`~mjexplore.explorers.map_planner.PlanningMapOracle`'s settings
            (``resolution``: of the planning cells) and the oracle's.

    Raises:
        UserInputError: an unknown source, or a learned predictor that cannot be loaded.
    """

    def __init__(self, source: str = "learned", predictor: str | os.PathLike = MAP_PREDICTOR,
                 free_above: float = CONFIDENT[1], occupied_below: float = CONFIDENT[0],
                 **kwargs) -> None:
        if source not in SOURCES:
            raise UserInputError(f"prediction source {source!r} is unknown: use one of "
                                 f"{', '.join(SOURCES)}.")
        if not 0 <= occupied_below < free_above <= 1:
            raise ValueError("need 0 <= occupied_below < free_above <= 1")
        super().__init__(**kwargs)
        self.source = source
        self.free_above, self.occupied_below = free_above, occupied_below
        self.predictor = None
        if source == "learned":
            from mjexplore.mapping.prediction import map_predictor

            self.predictor = map_predictor(predictor)

    def free_probability(self, state: ExplorationState) -> np.ndarray:
        """(rows, cols) float32 predicted free probability of every cell of the map
        (:func:`free_probability`)."""
        return free_probability(state.grid, self.predictor)

    def planning_data(self, state: ExplorationState) -> np.ndarray:
        data = state.grid.data.copy()
        unknown = data < 0
        if self.source == "truth":
            if state.ground_truth is None:
                raise ValueError("predicted_tour on the truth needs the ground truth")
            data[unknown] = state.ground_truth.data[unknown]
            return data
        p = self.free_probability(state)
        data[unknown & (p >= self.free_above)] = FREE
        data[unknown & (p <= self.occupied_below)] = OCCUPIED
        return data


class PredictedTour(PocketNearest):
    """``pocket_nearest``'s node unless the tour on the predicted map saves more than
    ``margin_m`` with another (see the module docstring).

    Args:
        margin_m: Metres of path plus tour the best node must save over pocket_nearest's.
        source: The prediction: ``learned``, ``inpainting`` or ``truth``.
        predictor: The learned predictor's weights file.
        free_above: Least free probability of a cell planned as free.
        occupied_below: Greatest free probability of a cell planned as a wall.
        resolution: Cell side of the planning map, metres (None: the robot's map's).
        **kwargs: :class:`~mjexplore.explorers.pocket_nearest.PocketNearest`'s settings.
    """

    def __init__(self, margin_m: float = 5.0, source: str = "learned",
                 predictor: str | os.PathLike = MAP_PREDICTOR,
                 free_above: float = CONFIDENT[1], occupied_below: float = CONFIDENT[0],
                 resolution: float | None = PLAN_RESOLUTION,
                 **kwargs) -> None:
        if margin_m < 0:
            raise ValueError("margin_m must be >= 0 (metres)")
        self.margin_m = float(margin_m)
        # The lookahead's margin: its plan covers a little more than the target, so that it
        # does not send the robot back and forth for the last cells (see the oracle).
        # On 0.2 m cells 360 rays reach every cell within the lidar's 6 m (0.1 m apart there).
        rays = 720 if resolution is None else 360
        self.planner = PredictedMapPlanner(source, predictor, free_above, occupied_below,
                                           resolution=resolution, margin=LOOKAHEAD_MARGIN,
                                           rays=rays)
        super().__init__(**kwargs)
        self.name = "predicted_tour" if source == "learned" else f"predicted_tour_{source}"
        self.departures = 0

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.planner.reset(rng)
        self.departures = 0

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        goal = super().select_goal(state)
        if goal is None:
            return None
        assert self.padded is not None  # The decision's TER, made with the goal.
        valid = np.flatnonzero(self.mask)
        prior = int(np.argmin(self.cost))
        candidates = self.padded.node_positions[valid].astype(float)
        pick = self.planner.expert_lookahead(state, candidates, baseline=int(
            np.flatnonzero(valid == prior)[0]), gain_m=self.margin_m)
        if pick < 0 or valid[pick] == prior:
            return goal
        self.departures += 1
        return candidates[pick].copy()


class PredictedPlan(PredictedMapPlanner):
    """The oracle's coverage plan on the robot's map plus the prediction within ``horizon``
    metres of its mapped cells, followed on the robot's own map: the horizon oracle
    (:class:`~mjexplore.explorers.map_planner.HorizonOracle`) with the truth it reads
    replaced by a prediction.

    At each decision the planner re-plans (carrying its tour over where its viewpoints are
    still candidates) and the robot drives to the tour's first viewpoint when its own map
    has a path there (it stays the goal while it still sees unknown cells, as the
    oracle's); when the viewpoint lies in predicted space the robot's map cannot reach, it
    drives to the frontier of least path from the robot plus straight distance on to the
    viewpoint (the frontier's own test then applies). It never drives on the prediction.

    Args:
        horizon: How far beyond the mapped cells the prediction is planned on, metres.
        source: The prediction: ``learned``, ``inpainting`` or ``truth``.
        **kwargs: :class:`PredictedMapPlanner`'s settings.
    """

    plans_on_ground_truth = False  # It drives on the robot's map.

    def __init__(self, horizon: float = 5.0, source: str = "learned",
                 resolution: float | None = PLAN_RESOLUTION, **kwargs) -> None:
        if horizon < 0:
            raise ValueError("horizon must be >= 0 (metres)")
        kwargs.setdefault("rays", 720 if resolution is None else 360)
        super().__init__(source, resolution=resolution, **kwargs)
        self.horizon = float(horizon)
        self.name = "predicted_plan" if source == "learned" else f"predicted_plan_{source}"
        self.steered = 0  # Decisions sent to a frontier towards an unreachable viewpoint.

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.steered = 0

    def planning_data(self, state: ExplorationState) -> np.ndarray:
        data = super().planning_data(state)
        grid = state.grid
        outside = _distance_to(grid.known) * grid.resolution > self.horizon
        data[outside] = UNKNOWN
        return data

    def goal_open(self, grid) -> bool | None:
        """The current viewpoint stays worth reaching while it still sees ``min_gain``
        planning cells unknown in ``grid`` (on the planning cells); None for a frontier
        goal."""
        if self.current is None:
            return None
        views = self.views
        assert views is not None  # The current viewpoint is one of them.
        cells = views.idx[views.ptr[self.current]:views.ptr[self.current + 1]]
        return bool(self.coarse_unknown(grid).reshape(-1)[cells].sum() >= self.min_gain)

    def select_goal(self, state: ExplorationState) -> np.ndarray | None:
        viewpoint = super().select_goal(state)
        if viewpoint is None:
            return None
        costmap = state.costmap
        # A viewpoint given up before (the robot stood there and its cells stayed unknown,
        # or no path led there) is steered towards through a frontier instead.
        if state.allowed([viewpoint])[0] and \
                costmap.nearest_traversable(viewpoint, radius=0.3) >= 0 and np.isfinite(
                costmap.distances_from(state.pose[:2], _disk(costmap.grid, viewpoint, 0.3),
                                       stop_after=1)).any():
            return viewpoint
        self.current = None  # A frontier goal: the runner's frontier test applies.
        if not state.frontiers:
            return None
        goals = np.array([f.goal for f in state.frontiers], float)
        path = costmap.distances_from(state.pose[:2])
        cells = np.array([costmap.grid.world_to_cell(g) for g in goals])
        cost = path[cells[:, 0], cells[:, 1]] + np.linalg.norm(goals - viewpoint, axis=1)
        if not np.isfinite(cost).any():
            return None
        self.steered += 1
        return goals[int(np.argmin(cost))].copy()


class PredictedDrive(PredictedPlan):
    """:class:`PredictedPlan` that also drives on the prediction, as the horizon oracle
    drives on the truth.

    It drives on a costmap of its own (:meth:`driving_costmap`): the robot's map on its
    cells (0.05 m) with the unknown cells within ``horizon`` filled from the prediction where
    it is confident, made afresh at each decision and overwritten, scan by scan, wherever
    the robot's map has mapped a cell since (:meth:`map_changed`), so that the navigator
    re-plans as soon as a predicted corridor turns out to be a wall. Its viewpoints in
    predicted space are driven to directly. It explores alone and without people (its
    costmap holds no moving bodies).

    Args:
        horizon: How far beyond the mapped cells the prediction is planned and driven on,
            metres.
        source: The prediction: ``learned``, ``inpainting`` or ``truth``.
        **kwargs: :class:`PredictedMapPlanner`'s settings.
    """

    def __init__(self, horizon: float = 5.0, source: str = "learned", **kwargs) -> None:
        super().__init__(horizon, source, **kwargs)
        self.name = "predicted_drive" if source == "learned" else f"predicted_drive_{source}"
        self._drive: Costmap | None = None

    def driving_costmap(self, grid: GridMap) -> Costmap:
        """The costmap the robot drives on, over cells like ``grid``'s (the robot's map):
        all unknown until the first decision."""
        self._drive_map = GridMap(np.full(grid.shape, UNKNOWN, np.int8), grid.resolution,
                                  grid.origin)
        self._drive_d2 = np.zeros(grid.shape, np.float32)
        self._predicted_d2 = np.zeros(grid.shape, np.float32)
        self._drive = Costmap(self._drive_map, self._drive_d2, PlannerConfig())
        return self._drive

    def planning_data(self, state: ExplorationState) -> np.ndarray:
        data = super().planning_data(state)
        if self._drive is not None:  # The driving costmap follows each decision's map.
            self._drive_map.data[...] = data
            self._predicted_d2[...] = np.rint(_distance_to(data == OCCUPIED) ** 2)
            self._drive_d2[...] = self._predicted_d2
            tracker = state.extras.get("tracker")
            if tracker is not None:  # The robot's map's own distances where shorter.
                np.minimum(self._drive_d2, tracker.gvd.distance2, out=self._drive_d2)
            self._drive.update(None)
        return data

    def map_changed(self, grid: GridMap, cells: np.ndarray, distance2: np.ndarray) -> None:
        """Writes the robot's map's ``cells`` (flat indices) that it knows over the
        prediction, with their squared distances in cells to the nearest wall (the least of
        the prediction's and ``distance2``, the robot's map's), and updates their costs."""
        if self._drive is None:
            return
        live = grid.data.reshape(-1)[cells]
        mapped = live >= 0
        self._drive_map.data.reshape(-1)[cells[mapped]] = live[mapped]
        self._drive_d2.reshape(-1)[cells] = np.minimum(
            self._predicted_d2.reshape(-1)[cells], distance2.reshape(-1)[cells])
        self._drive.update(cells)


class PredictedPocketNearest(TruePocketNearest):
    """``pocket_nearest``'s rule with each frontier's pocket read from the predicted map
    instead of the pocket classifier: a frontier node counts ``pocket_m`` metres farther
    when the free space behind it on the robot's map with its unknown cells predicted
    (free at probability ``free_above`` or more, a wall otherwise) is below
    ``small_area_m2`` (:func:`~mjexplore.topology.pockets.pocket_areas`, as
    ``pocket_truth`` reads the truth).

    Args:
        source: ``learned`` (the map predictor) or ``inpainting``.
        predictor: The learned predictor's weights file.
        free_above: Least predicted free probability of a cell counted as free.
        **kwargs: :class:`~mjexplore.explorers.pocket_nearest.TruePocketNearest`'s settings.

    Raises:
        UserInputError: an unknown source, or a learned predictor that cannot be loaded.
    """

    def __init__(self, source: str = "learned", predictor: str | os.PathLike = MAP_PREDICTOR,
                 free_above: float = 0.5, **kwargs) -> None:
        if source not in ("learned", "inpainting"):
            raise UserInputError(f"prediction source {source!r} is unknown here: use learned "
                                 "or inpainting (pocket_truth reads the truth).")
        super().__init__(**kwargs)
        self.free_above = float(free_above)
        self.name = "pocket_predicted" if source == "learned" else \
            f"pocket_predicted_{source}"
        self.predictor = None
        if source == "learned":
            from mjexplore.mapping.prediction import map_predictor

            self.predictor = map_predictor(predictor)

    def building(self, state: ExplorationState) -> GridMap:
        grid = state.grid
        data = grid.data.copy()
        unknown = data < 0
        free = free_probability(grid, self.predictor) >= self.free_above
        data[unknown] = np.where(free[unknown], FREE, OCCUPIED)
        return GridMap(data, grid.resolution, grid.origin)


def _disk(grid, xy: np.ndarray, radius: float) -> np.ndarray:
    """(rows, cols) bool: the cells within ``radius`` metres of ``xy``."""
    r, c = grid.world_to_cell(np.asarray(xy, float))
    rr, cc = np.ogrid[:grid.shape[0], :grid.shape[1]]
    return (rr - r) ** 2 + (cc - c) ** 2 <= (radius / grid.resolution) ** 2
