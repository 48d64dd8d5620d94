"""The control period's fast paths give what the plain formulations give, to the bit (issue 16:
the same seed drives the same trajectory)."""

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.maps import FREE, GridMap
from mjexplore.navigation.navigator import Navigator, NavigatorConfig, pursuit_points
from mjexplore.navigation.planner import Costmap, PlannerConfig
from mjexplore.robot import motion_profile
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import SimConfig
from mjexplore.topology.gvd import DynamicGVD


def _reference(path, x, y, lookahead):
    """Nearest point and lookahead point as whole-array numpy computes them."""
    d = np.hypot(path[:, 0] - x, path[:, 1] - y)
    nearest = int(np.argmin(d))
    ahead = path[nearest:]
    seg = np.hypot(*np.diff(ahead, axis=0).T) if len(ahead) > 1 else np.zeros(0)
    along = np.concatenate([[0.0], np.cumsum(seg)])
    target = nearest + min(int(np.searchsorted(along, lookahead)), len(ahead) - 1)
    return nearest, d[nearest], target, float(np.hypot(*(path[target] - (x, y))))


@pytest.mark.parametrize("n", [1, 2, 7, 60])
def test_pursuit_points_match_the_whole_array_computation(n):
    rng = np.random.default_rng(n)
    for _ in range(50):
        path = np.cumsum(rng.normal(0.0, 0.07, (n, 2)), axis=0)
        if n > 2:
            path[n // 2] = path[0]  # A tie for the nearest point: the first one counts.
        seg = np.hypot(*np.diff(path, axis=0).T)
        x, y = rng.normal(0.0, 0.3, 2)
        lookahead = float(rng.choice([0.05, 0.6, 100.0]))
        got = pursuit_points(path[:, 0].copy(), path[:, 1].copy(), seg, x, y, lookahead)
        assert got == _reference(path, x, y, lookahead)


def test_remaining_length_is_the_path_length_from_the_nearest_point():
    data = np.full((60, 100), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    data[:45, 50:53] = 100  # A wall to go round.
    grid = GridMap(data, 0.1)
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    costmap = Costmap(grid, gvd.distance2, PlannerConfig())
    nav = Navigator(motion_profile("sim"), NavigatorConfig())
    assert nav.set_goal(np.array([8.0, 1.0]), costmap, np.array([2.0, 1.0, 0.0]), 0.0)
    path = nav.path
    rng = np.random.default_rng(0)
    for pose in rng.uniform((1.0, 1.0, -3.0), (9.0, 5.0, 3.0), (30, 3)):
        d = np.hypot(path[:, 0] - pose[0], path[:, 1] - pose[1])
        k = int(np.argmin(d))
        expected = float(d[k] + np.hypot(*np.diff(path[k:], axis=0).T).sum())
        assert nav.remaining_length(pose) == expected


def test_an_open_goal_is_judged_on_the_map_as_it_is_now():
    episode = Episode(resolve_scene("maze"), NearestFrontier(), 0,
                      EpisodeConfig(sim=SimConfig(dynamics="grid")))
    state = episode.mapper.state
    inner = np.zeros(state.shape, bool)
    inner[20:-20, 20:-20] = True
    unknown = np.argwhere((state < 0) & inner)[0]
    episode.agent.goal = episode.mapper.grid.cell_to_world(unknown)
    assert episode.agent.goal_still_open()
    state[unknown[0] - 10:unknown[0] + 11, unknown[1] - 10:unknown[1] + 11] = FREE
    assert not episode.agent.goal_still_open()  # Mapped since it was last asked.
    elsewhere = np.argwhere((state < 0) & inner)[0]
    episode.agent.goal = episode.mapper.grid.cell_to_world(elsewhere)
    assert episode.agent.goal_still_open()  # A new goal: its own cells.
