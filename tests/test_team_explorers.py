"""Coordination baselines: frontier regions, greedy and optimal assignment by path cost,
MMPF's robot-robot repulsion, and coordinated teams in episodes."""

from __future__ import annotations

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.explorer import ExplorationState
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.episode.team import TeamView
from mjexplore.errors import UserInputError
from mjexplore.explorers.potential import PotentialField
from mjexplore.explorers.team import (
    UNREACHABLE,
    TeamPotentialField,
    assign,
    frontier_regions,
    make_team_explorers,
)
from mjexplore.maps import FREE, GridMap
from mjexplore.navigation.planner import Costmap
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.simulator import SimConfig


@pytest.fixture(scope="module")
def rooms(tmp_path_factory):
    return load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                        tmp_path_factory.mktemp("rooms") / "scene"))


def test_frontier_regions_group_near_frontiers():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0], [2.9, 0.0], [5.5, 1.0]])
    np.testing.assert_array_equal(frontier_regions(points, 3.0), [0, 0, 1, 0, 1])
    np.testing.assert_array_equal(frontier_regions(points, 0.1), [0, 1, 2, 3, 4])
    assert len(frontier_regions(np.zeros((0, 2)), 3.0)) == 0


def test_greedy_and_optimal_assignment_differ_where_they_should():
    cost = np.array([[1.0, 2.0], [2.0, 10.0]])
    # Greedy takes the cheapest pair (robot 0 to region 0) and leaves robot 1 the dear
    # one: 11 in all; the optimal assignment swaps them: 4.
    np.testing.assert_array_equal(assign(cost, "greedy"), [0, 1])
    np.testing.assert_array_equal(assign(cost, "optimal"), [1, 0])
    # More robots than regions: one is left without; unreachable regions are not given.
    wide = np.array([[1.0], [2.0], [3.0]])
    for method in ("greedy", "optimal"):
        out = assign(wide, method)
        assert sorted(out.tolist()) == [-1, -1, 0] and out[0] == 0
        np.testing.assert_array_equal(assign(np.full((2, 2), UNREACHABLE), method), [-1, -1])
    with pytest.raises(ValueError):
        assign(cost, "random")


def test_mmpf_repulsion_raises_the_field_near_teammates():
    data = np.full((100, 100), FREE, np.int8)
    grid = GridMap(data, 0.05)
    costmap = Costmap(grid, np.full(grid.shape, 1e6))
    view = TeamView(0, np.array([[1.0, 1.0, 0.0], [4.0, 4.0, 0.0]]), [None, None],
                    [costmap, costmap], np.array([True, True]))
    state = ExplorationState(grid, view.poses[0], 0.0, [], costmap, np.zeros((0, 2)),
                             extras={"team": view})
    field = TeamPotentialField()
    potential = np.zeros((25, 25))
    field.add_potential(state, potential, 4)
    near = potential[19, 19]  # The coarse cell of the teammate at (4, 4) m: the peak.
    assert near == pytest.approx(80.0 * (2.5 - 0.2), rel=0.05)
    assert potential[5, 5] == 0.0  # The robot's own place is not repelled.
    assert potential[19, 19 - 13] == 0.0  # Beyond 2.5 m (Manhattan).
    PotentialField().add_potential(state, potential, 4)  # The single robot's: nothing.


def test_make_team_explorers():
    greedy = make_team_explorers("assign_greedy", 3)
    assert len(greedy) == 3 and len({id(e.coordinator) for e in greedy}) == 1
    assert [e.name for e in make_team_explorers("assign_optimal", 2)] == ["assign_optimal"] * 2
    assert all(isinstance(e, TeamPotentialField) for e in make_team_explorers("mmpf", 2))
    with pytest.raises(UserInputError, match="naive team"):
        make_team_explorers("nearest", 2)


@pytest.mark.parametrize("method", ["assign_greedy", "assign_optimal", "mmpf"])
def test_coordinated_teams_explore(rooms, method):
    config = EpisodeConfig(sim=SimConfig(dynamics="kinematic"), start_jitter=(0.0, 0.0),
                           max_time=600.0)
    result = Episode(rooms, make_team_explorers(method, 2), 0, config).run()
    m = result.metrics
    assert m["end_reason"] == "explored", m
    assert all(r["decisions"] > 0 for r in m["per_robot"])


def test_assigned_robots_head_for_different_regions(rooms):
    config = EpisodeConfig(sim=SimConfig(dynamics="kinematic"), start_jitter=(0.0, 0.0))
    explorers = make_team_explorers("assign_optimal", 2, region_radius=3.0)
    episode = Episode(rooms, explorers, 0, config)
    apart = []
    while episode.step():
        goals = [a.goal for a in episode.agents]
        points = np.array([f.goal for f in episode.tracker.frontiers(episode.mapper.grid)])
        if all(g is not None for g in goals) and len(points) and \
                frontier_regions(points, 3.0).max() >= 1:  # Two regions at least.
            apart.append(float(np.hypot(*(goals[0] - goals[1]))))
    assert apart and np.median(apart) > 3.0
    naive = Episode(rooms, [NearestFrontier(), NearestFrontier()], 0, config)
    assert naive.agents[0].explorer is not naive.agents[1].explorer
