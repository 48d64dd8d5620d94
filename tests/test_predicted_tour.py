"""predicted_tour: pocket_nearest departing when the oracle's tour on a predicted map saves
more than a margin. On the truth with no margin it chooses as the oracle's lookahead; with
an endless margin as pocket_nearest; its planning map is the robot's map with the unknown
cells filled from the prediction where it is confident."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.explorer import ExplorationState
from mjexplore.errors import UserInputError
from mjexplore.explorers import make_explorer
from mjexplore.explorers.oracle import lookahead_expert
from mjexplore.explorers.pocket_nearest import PocketNearest
from mjexplore.explorers.predicted_tour import PredictedMapPlanner, PredictedTour
from mjexplore.mapping.prediction import MapPredictorNet, save_map_predictor
from mjexplore.maps import FREE, OCCUPIED, UNKNOWN
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import SimConfig

GRID = EpisodeConfig(max_time=600.0, sim=SimConfig(dynamics="grid"))


class _Ask:
    """Drives with a predicted tour; at each decision asks the oracle's lookahead and
    pocket_nearest on the same state and candidates."""

    name = "ask"

    def __init__(self, tour: PredictedTour) -> None:
        self.tour, self.oracle, self.prior = tour, lookahead_expert(), PocketNearest()
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def reset(self, rng: np.random.Generator) -> None:
        for e in (self.tour, self.oracle, self.prior):
            e.reset(rng)

    def select_goal(self, state):
        goal = self.tour.select_goal(state)
        if goal is None:
            return None
        t = self.tour
        valid = np.flatnonzero(t.mask)
        candidates = t.padded.node_positions[valid].astype(float)
        baseline = int(np.flatnonzero(valid == int(np.argmin(t.cost)))[0])
        oracle = self.oracle.expert_lookahead(state, candidates, baseline=baseline, gain_m=0.0)
        self.rows.append((goal, candidates[oracle], self.prior.select_goal(state)))
        return goal


def test_on_the_truth_without_margin_it_chooses_as_the_oracles_lookahead():
    ask = _Ask(PredictedTour(margin_m=0.0, source="truth", resolution=None))
    metrics = Episode(resolve_scene("train_loop"), ask, 0, GRID).run().metrics
    assert metrics["end_reason"] == "explored" and len(ask.rows) >= 5
    for i, (goal, oracle, _) in enumerate(ask.rows):
        np.testing.assert_allclose(goal, oracle, err_msg=f"decision {i}")
    assert ask.tour.departures > 0  # It did depart from pocket_nearest.
    assert any(not np.allclose(goal, prior) for goal, _, prior in ask.rows)


def test_with_an_endless_margin_it_keeps_pocket_nearests_node():
    ask = _Ask(PredictedTour(margin_m=1e9, source="inpainting"))
    Episode(resolve_scene("train_loop"), ask, 0, GRID).run()
    assert ask.rows and ask.tour.departures == 0
    for goal, _, prior in ask.rows:
        np.testing.assert_allclose(goal, prior)


def test_the_planning_map_fills_the_confident_unknown_cells(tmp_path):
    torch.manual_seed(0)
    save_map_predictor(tmp_path / "p.safetensors", MapPredictorNet(width=4))
    states = []

    class _Keep:
        name = "keep"

        def reset(self, rng):
            self.nearest = make_explorer("nearest")

        def select_goal(self, state):
            states.append(state)
            return self.nearest.select_goal(state)

    Episode(resolve_scene("train_loop"), _Keep(), 0,
            EpisodeConfig(max_time=20.0, sim=SimConfig(dynamics="grid"))).run()
    state = states[-1]
    known = state.grid.data >= 0
    unknown = ~known
    p = PredictedMapPlanner("learned", tmp_path / "p.safetensors").free_probability(state)
    assert p.shape == state.grid.shape
    low, high = np.quantile(p[unknown], [0.3, 0.7])  # The untrained net's middle.
    assert low < high
    planner = PredictedMapPlanner("learned", tmp_path / "p.safetensors", free_above=high,
                                  occupied_below=low)
    data = planner.planning_data(state)
    np.testing.assert_array_equal(data[known], state.grid.data[known])
    for cells, value in ((p >= high, FREE), (p <= low, OCCUPIED),
                         ((p > low) & (p < high), UNKNOWN)):
        assert (unknown & cells).any() and (data[unknown & cells] == value).all()


def test_a_missing_predictor_says_how_to_make_one(tmp_path):
    with pytest.raises(UserInputError, match="train-predictor"):
        PredictedTour(predictor=tmp_path / "none.safetensors")
    with pytest.raises(UserInputError, match="source"):
        PredictedTour(source="crystal_ball")


def test_a_coarse_wall_cell_is_seen_once_its_face_is_mapped():
    """On planning cells coarser than the map, a wall's cell stops being 'to see' once any
    of its cells is mapped (the lidar maps a wall's face, never its inside); other cells
    while at least half of theirs are unmapped."""
    from mjexplore.explorers.predicted_tour import PredictedPlan
    from mjexplore.maps import GridMap

    data = np.full((8, 8), UNKNOWN, np.int8)
    data[:, :4] = FREE
    data[0:4, 4] = OCCUPIED  # The face of the wall block (rows 0-3, cols 4-7) is mapped.
    grid = GridMap(data, 0.05, (0.0, 0.0, 0.0))
    truth = GridMap(np.where(np.arange(8)[None, :] >= 4, OCCUPIED, FREE).repeat(
        8, 0).astype(np.int8), 0.05, (0.0, 0.0, 0.0))
    planner = PredictedPlan(source="truth", resolution=0.2)
    planner.reset(np.random.default_rng(0))
    state = ExplorationState(grid, np.array([0.05, 0.05, 0.0]), 0.0, [], None,
                             np.zeros((0, 2)), ground_truth=truth)
    planner.ground_truth_costmap(state)
    planner._plan.data[...] = planner._planning_map(state)
    assert planner._plan.data[0, 1] == OCCUPIED and planner._plan.data[1, 1] == OCCUPIED
    unknown = planner.coarse_unknown(grid)
    assert not unknown[0, 0] and not unknown[0, 1]  # Free; a wall whose face is mapped.
    assert unknown[1, 1]  # A wall cell with nothing of it mapped yet.


def test_predicted_plan_on_the_truth_explores_with_few_give_ups():
    """The planner's viewpoints are driven to on the robot's own map; on the truth within
    5 m it explores without standing at viewpoints that see nothing (each such stop would be
    given up as 'seen_open')."""
    scene = resolve_scene("train_loop")
    explorer = make_explorer("predicted_plan_truth")
    m = Episode(scene, explorer, 0, GRID).run().metrics
    assert m["end_reason"] == "explored"
    assert m["given_up"]["seen_open"] <= m["decisions"] // 3


def test_pocket_predicted_reads_the_pockets_from_the_predicted_map():
    """Its building is the robot's map with the unknown cells predicted free (p >= 0.5) or
    walls; the known cells stay as mapped; it explores a scene with that rule."""
    from mjexplore.explorers.predicted_tour import PredictedPocketNearest
    from mjexplore.maps import GridMap

    explorer = PredictedPocketNearest(source="inpainting")
    data = np.full((40, 40), UNKNOWN, np.int8)
    data[:, :20] = FREE
    data[10, :20] = OCCUPIED
    grid = GridMap(data, 0.05)
    explorer.predictor = lambda channels: np.where(  # Free above the row of 0.2 m cells 5.
        np.arange(channels.shape[-2])[:, None] < 5, 0.9, 0.1).repeat(
        channels.shape[-1], axis=1).astype(np.float32)
    state = ExplorationState(grid, np.zeros(3), 0.0, [], None, np.zeros((0, 2)))
    built = explorer.building(state).data
    np.testing.assert_array_equal(built[:, :20], data[:, :20])  # Known cells as mapped.
    assert (built[:20, 20:] == FREE).all() and (built[20:, 20:] == OCCUPIED).all()
    m = Episode(resolve_scene("train_loop"), make_explorer("pocket_predicted_inpainting"), 0,
                GRID).run().metrics
    assert m["end_reason"] == "explored"


def test_predicted_drive_drives_on_the_prediction_until_the_map_says_otherwise():
    """Its driving costmap is the robot's map with the predicted cells filled in (a
    predicted corridor is traversable before it is seen); a cell the robot maps as a wall
    afterwards blocks at once, and a mapped cell overrides the prediction."""
    from mjexplore.explorers.predicted_tour import PredictedDrive
    from mjexplore.maps import GridMap
    from mjexplore.topology.gvd import DynamicGVD

    data = np.full((40, 80), UNKNOWN, np.int8)
    data[:, :40] = FREE
    data[[0, -1], :40] = OCCUPIED
    truth = data.copy()
    truth[:, 40:] = FREE
    truth[[0, -1], :] = OCCUPIED
    grid = GridMap(data, 0.05)
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied)

    class _Tracker:
        pass

    tracker = _Tracker()
    tracker.gvd = gvd
    explorer = PredictedDrive(source="truth")
    explorer.reset(np.random.default_rng(0))
    costmap = explorer.driving_costmap(grid)
    assert not costmap.traversable.any()  # Nothing until the first decision.
    state = ExplorationState(grid, np.array([0.5, 1.0, 0.0]), 0.0, [], costmap,
                             np.zeros((0, 2)), ground_truth=GridMap(truth, 0.05),
                             extras={"tracker": tracker})
    explorer.planning_data(state)
    assert costmap.traversable[20, 60]  # Unknown on the map, free in the prediction.
    version = costmap.version
    data[10:30, 60] = OCCUPIED  # Mapped now: a wall across the predicted corridor.
    gvd.update(grid.occupied)
    cells = np.flatnonzero((np.arange(data.size) % 80 >= 50) & (np.arange(data.size) % 80 < 70))
    explorer.map_changed(grid, cells, gvd.distance2)
    assert costmap.version > version
    assert not costmap.traversable[20, 60] and not costmap.traversable[20, 58]
    assert (explorer._drive_map.data.reshape(-1)[cells] == np.where(
        data.reshape(-1)[cells] >= 0, data.reshape(-1)[cells],
        truth.reshape(-1)[cells])).all()


def test_predicted_drive_on_the_truth_explores_and_refuses_company():
    """On the truth within 5 m it explores a scene; with people (or teammates) in the world
    it is refused with a clear error, as its costmap holds no moving bodies."""
    from mjexplore.sim.people import PeopleConfig

    m = Episode(resolve_scene("train_loop"), make_explorer("predicted_drive_truth"), 0,
                GRID).run().metrics
    assert m["end_reason"] == "explored"
    crowd = EpisodeConfig(max_time=60.0, sim=SimConfig(dynamics="grid",
                                                      people=PeopleConfig(count=2)))
    with pytest.raises(UserInputError, match="without --robots or --people"):
        Episode(resolve_scene("train_loop"), make_explorer("predicted_drive_truth"), 0,
                crowd).run()
