"""The ladder's explorers: pocket_truth, distance_advantage and the horizon oracle.

Each is asked, at every decision of a real grid-world episode on the small canonical loop
(driven by pocket_nearest), what it would choose on the same state, beside the rule it
extends; the horizon oracle also drives episodes of its own.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.explorers import make_explorer
from mjexplore.explorers.distance_advantage import DistanceAdvantage
from mjexplore.explorers.map_planner import HorizonOracle
from mjexplore.explorers.pocket_nearest import PocketNearest, TruePocketNearest
from mjexplore.maps import UNKNOWN
from mjexplore.navigation.tour import CoarseGraph
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import SimConfig
from mjexplore.topology.pockets import node_frontiers, pocket_areas

SCENE = "train_loop"
GRID = EpisodeConfig(max_time=600.0, sim=SimConfig(dynamics="grid"))


class _Ask:
    """Drives with pocket_nearest; at each decision asks the other explorers on the same
    state and keeps their costs."""

    name = "ask"

    def __init__(self) -> None:
        self.drive = PocketNearest()
        self.plain = PocketNearest(pocket_m=0.0)
        self.truth = TruePocketNearest()
        self.advantage = DistanceAdvantage()
        self.flat = DistanceAdvantage(remoteness=0.0)
        self.rows: list[dict] = []

    def reset(self, rng: np.random.Generator) -> None:
        for e in (self.drive, self.plain, self.truth, self.advantage, self.flat):
            e.reset(rng)

    def select_goal(self, state):
        goal = self.drive.select_goal(state)
        row = {"goal": goal}
        for key in ("plain", "truth", "advantage", "flat"):
            explorer = getattr(self, key)
            row[key] = explorer.select_goal(state)
            row[f"{key}_cost"] = explorer.cost.copy()
        frontiers = state.extras["tracker"].frontiers(state.grid)
        padded = self.truth.padded
        nodes, which = node_frontiers(padded, state.grid, frontiers)
        small = np.zeros(len(padded.node_mask), bool)
        if len(nodes):
            small[nodes] = pocket_areas(state.grid, state.ground_truth,
                                        [frontiers[i] for i in which]) < 0.5
        row["small"] = small
        row["mask"] = self.advantage.mask.copy()
        valid = np.flatnonzero(row["mask"])
        graph = CoarseGraph(state.grid, state.costmap.traversable)
        between = graph.distance_matrix(padded.node_positions[valid].astype(float))
        np.fill_diagonal(between, np.inf)
        row["remote"] = (np.minimum(between.min(axis=1), 50.0) if len(valid) > 1
                         else np.zeros(len(valid)))
        self.rows.append(row)
        return goal


@pytest.fixture(scope="module")
def decisions() -> list[dict]:
    explorer = _Ask()
    result = Episode(resolve_scene(SCENE), explorer, 0, GRID).run()
    assert result.metrics["end_reason"] == "explored"
    assert len(explorer.rows) >= 5
    return explorer.rows


def test_pocket_truth_adds_50_m_to_each_truly_small_pocket(decisions):
    assert any(row["small"][row["mask"]].any() for row in decisions), \
        "no decision had a frontier with a small true pocket: the test shows nothing"
    for row in decisions:
        m = row["mask"]
        expected = row["plain_cost"][m] + np.float32(50.0) * row["small"][m]
        np.testing.assert_allclose(row["truth_cost"][m], expected, rtol=0, atol=1e-3)


def test_distance_advantage_subtracts_the_path_to_the_nearest_other_candidate(decisions):
    parted = 0
    for row in decisions:
        m = row["mask"]
        np.testing.assert_array_equal(row["flat_cost"][m], row["plain_cost"][m])
        np.testing.assert_allclose(row["advantage_cost"][m],
                                   row["plain_cost"][m] - row["remote"], atol=1e-3)
        parted += row["advantage"] is not None and not np.allclose(row["advantage"],
                                                                   row["plain"])
    assert parted, "distance advantage chose the nearest node at every decision"


def test_pocket_advantage_is_distance_advantage_on_the_pocket_prior():
    explorer = make_explorer("pocket_advantage")
    assert isinstance(explorer, DistanceAdvantage)
    assert explorer.pocket_m == 50.0 and explorer.name == "pocket_advantage"
    assert make_explorer("distance_advantage").pocket_m == 0.0


class _Horizon(HorizonOracle):
    """Keeps the planning map of each decision and the robot's map beside it."""

    def __init__(self, horizon: float) -> None:
        super().__init__(horizon)
        self.maps: list[tuple[np.ndarray, np.ndarray]] = []

    def prepare(self, state) -> None:
        super().prepare(state)
        self.maps.append((self._plan.data.copy(), state.grid.known.copy()))


def test_horizon_oracle_plans_on_the_truth_within_the_horizon_only():
    explorer = _Horizon(2.0)
    scene = resolve_scene(SCENE)
    config = dataclasses.replace(GRID, max_time=60.0)
    Episode(scene, explorer, 0, config).run()
    gt = scene.ground_truth
    assert explorer.maps
    for plan, known in explorer.maps:
        distance = cv2.distanceTransform((~known).astype(np.uint8), cv2.DIST_L2,
                                         cv2.DIST_MASK_PRECISE) * gt.resolution
        inside = distance <= 2.0
        np.testing.assert_array_equal(plan[inside], gt.data[inside])
        assert (plan[~inside] == UNKNOWN).all()
        assert (~inside & (gt.data != UNKNOWN)).any()  # Some truth is withheld.


def test_horizon_oracle_with_the_whole_truth_explores_as_the_oracle_does():
    scene = resolve_scene(SCENE)
    times = {}
    for name, explorer in (("oracle", make_explorer("oracle")),
                           ("whole", HorizonOracle(1000.0)),
                           ("2m", make_explorer("oracle_2m")),
                           ("nearest", make_explorer("nearest"))):
        metrics = Episode(scene, explorer, 0, GRID).run().metrics
        assert metrics["end_reason"] == "explored", name
        times[name] = metrics["exploration_time_s"]
    assert times["whole"] == times["oracle"], times  # The same plans.
    assert times["whole"] < times["nearest"], times
