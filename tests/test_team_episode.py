"""The team episode: one shared map, one navigator per robot with its teammates in its
costmap, waiting and yielding when blocked, the team's end of exploration and metrics."""

from __future__ import annotations

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.episode.nearest import NearestFrontier
from mjexplore.episode.team import TeamConfig
from mjexplore.errors import UserInputError
from mjexplore.mapping.occupancy import OccupancyMapper
from mjexplore.maps import FREE, OCCUPIED, GridMap
from mjexplore.navigation.bodies import BodyCostmap
from mjexplore.navigation.planner import Costmap
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.importer import scene_from_grid
from mjexplore.scenes.scene import load_scene_files, write_scene
from mjexplore.sim.simulator import SimConfig

RES = 0.05


def _config(**kwargs) -> EpisodeConfig:
    return EpisodeConfig(**{"sim": SimConfig(dynamics="kinematic"), "start_jitter": (0.0, 0.0),
                            **kwargs})


@pytest.fixture(scope="module")
def rooms(tmp_path_factory):
    return load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                        tmp_path_factory.mktemp("rooms") / "scene"))


@pytest.fixture(scope="module")
def dumbbell(tmp_path_factory):
    """Two 3 x 3 m rooms joined by a 4 m corridor 0.9 m wide (one robot at a time)."""
    data = np.full((round(3.4 / RES), round(10.4 / RES)), OCCUPIED, np.int8)
    w = round(0.2 / RES)
    data[w:-w, w:w + 60] = FREE  # West room, x 0.2-3.2 m.
    data[w:-w, -w - 60:-w] = FREE  # East room, x 7.2-10.2 m.
    mid = data.shape[0] // 2
    data[mid - 9:mid + 9, w + 60:-w - 60] = FREE  # The corridor, y 1.25-2.15 m.
    scene = scene_from_grid(GridMap(data, RES), "dumbbell", {"source": "test"},
                            start=(1.5, 1.7, 0.0))
    return load_scene_files(write_scene(scene, tmp_path_factory.mktemp("db") / "scene"))


class _GoTo:
    """Drives to a fixed point (a waypoint: it counts as open until reached), then stops."""

    name = "goto"
    waypoint = True

    def __init__(self, goal):
        self.goal = np.asarray(goal, float)
        self.done = False

    def reset(self, rng):
        del rng

    def select_goal(self, state):
        if np.hypot(*(state.pose[:2] - self.goal)) <= 1.0:
            self.done = True
        return None if self.done else self.goal


def test_team_costmap_blocks_teammates_and_restores():
    data = np.full((60, 100), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    grid = GridMap(data, RES)
    d2 = np.full(grid.shape, 1e6)
    plain = Costmap(grid, d2)
    team = BodyCostmap(grid, d2, teammate_radius=0.5)
    np.testing.assert_array_equal(team.cost, plain.cost)
    team.set_bodies(np.array([[2.5, 1.5]]))
    blocked = team.cost.reshape(grid.shape) < 0
    r, c = grid.world_to_cell(np.array([2.5, 1.5]))
    assert blocked[r, c] and blocked[r, c + 9] and not blocked[r, c + 11]
    v = team.version
    team.set_bodies(np.array([[4.0, 1.5]]))  # Moved: the old cells are free again.
    assert team.version > v
    assert team.cost.reshape(grid.shape)[r, c] == plain.cost.reshape(grid.shape)[r, c]
    team.update(None)  # A map update keeps the teammates in.
    assert (team.cost[team.body_cells] < 0).all()
    team.set_bodies(np.zeros((0, 2)))
    np.testing.assert_array_equal(team.cost, plain.cost)


def test_blocked_by_teammates_tells_a_closed_door_from_a_crowded_one():
    data = np.full((60, 100), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    data[:, 48:52] = OCCUPIED
    data[27:33, 48:52] = FREE  # A door 0.3 m... too narrow for the footprint: closed.
    grid = GridMap(data, RES)
    from mjexplore.topology.gvd import DynamicGVD

    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    team = BodyCostmap(grid, gvd.distance2, teammate_radius=0.5)
    start, goal = np.array([1.0, 1.5]), np.array([4.0, 1.5])
    assert team.plan(start, goal, 0.3) is None
    team.set_bodies(np.array([[2.0, 1.5]]))
    assert not team.blocked_by_bodies(start, goal, 0.3)  # Closed without them too.
    data[20:40, 48:52] = FREE  # A 1 m door: open, but the teammate stands in it.
    gvd.update(grid.occupied, grid.known)
    team.update(None)
    team.set_bodies(np.array([[2.5, 1.5]]))
    cost = team.cost.copy()
    assert team.plan(start, goal, 0.3) is None
    assert team.blocked_by_bodies(start, goal, 0.3)
    np.testing.assert_array_equal(team.cost, cost)  # Teammates back in.


def test_team_explores_a_scene(rooms):
    result = Episode(rooms, [NearestFrontier(), NearestFrontier()], 0,
                         _config(max_time=600.0)).run()
    m = result.metrics
    assert m["end_reason"] == "explored" and m["robots"] == 2
    assert m["t80_s"] <= m["t90_s"] <= m["t985_s"] == m["exploration_time_s"]
    assert 0.0 <= m["overlap_ratio"] <= 1.0
    assert m["path_length_m"] == pytest.approx(
        sum(r["path_length_m"] for r in m["per_robot"]), abs=0.01)
    assert m["max_path_length_m"] == max(r["path_length_m"] for r in m["per_robot"])
    for r, robot in enumerate(m["per_robot"]):
        assert robot["robot"] == f"robot_{r}"
        assert robot["path_length_m"] > 1.0 and robot["decisions"] > 0
        assert 0.2 < robot["coverage"] <= 1.0
    assert len(result.kinematics) == len(result.goals) == len(result.robot_curves) == 2
    assert result.ratio_curve[-1, 1] >= 0.985
    # Every scan of each robot went into the one map.
    assert len(result.ratio_curve) == sum(len(c) for c in result.robot_curves)


def test_team_explores_in_the_grid_world(rooms):
    config = EpisodeConfig(sim=SimConfig(dynamics="grid"), start_jitter=(0.0, 0.0),
                           max_time=600.0)
    m = Episode(rooms, [NearestFrontier(), NearestFrontier()], 0, config).run().metrics
    assert m["end_reason"] == "explored" and m["robots"] == 2


def test_one_explorer_in_a_list_is_the_single_robot_episode(rooms):
    """One engine: a robot alone is a team of one, with a single robot's results."""
    config = _config(max_time=400.0)
    single = Episode(rooms, NearestFrontier(), 3, config).run()
    alone = Episode(rooms, [NearestFrontier()], 3, config).run()
    assert alone.metrics == single.metrics and single.metrics["end_reason"] == "explored"
    np.testing.assert_array_equal(alone.ratio_curve, single.ratio_curve)
    np.testing.assert_array_equal(alone.goals, single.goals)


def test_a_team_explores_with_scan_matching_and_odometry_errors(rooms):
    """Each robot localises itself on the shared map (odometry with typical errors, scan
    matching); the team's ratio is what was really seen."""
    config = _config(max_time=600.0, localization="scan_matching",
                     sim=SimConfig(dynamics="kinematic", odometry_error="typical"))
    episode = Episode(rooms, [NearestFrontier(), NearestFrontier()], 0, config)
    assert all(a.localizer is not None for a in episode.agents)
    m = episode.run().metrics
    assert m["end_reason"] == "explored" and m["localization"] == "scan_matching"
    assert episode._seen is not episode.mapper  # The ratio is measured at the true poses.
    for a in episode.agents:  # Each estimate stayed near its robot.
        assert np.hypot(*(a.pose[:2] - a.sim.pose[:2])) < 0.3
    assert m["iou"] > 0.8


def test_robots_in_a_doorway_wait_and_one_yields(dumbbell):
    """Head-on in a corridor one robot wide: they wait, the second yields, both get
    through, and the episode does not end in a deadlock."""
    config = EpisodeConfig(max_time=150.0, target_ratio=1.0, start_jitter=(0.0, 0.0))
    west, east = (1.5, 1.7, 0.0), (8.9, 1.7, np.pi)
    explorers = [_GoTo((9.0, 1.7)), _GoTo((1.4, 1.7))]
    episode = Episode(dumbbell, explorers, 0, config, starts=[west, east],
                          team_config=TeamConfig(wait_timeout=60.0))
    reached = [False, False]
    while episode.step():
        poses = episode.world.poses()
        reached[0] |= poses[0, 0] > 7.5
        reached[1] |= poses[1, 0] < 2.9
        if all(reached):
            break
    m = episode.result().metrics
    assert all(reached), m
    assert m["waits"] >= 1 and m["yields"] >= 1
    assert m["robot_collisions"] <= 1
    assert m["collisions"] == 0


def test_teammates_are_not_mapped_as_walls(dumbbell):
    """Returns from a teammate are left out of the map (its face would read as a wall)."""
    starts = [(1.5, 1.0, 0.0), (1.5, 2.4, 0.0)]
    episode = Episode(dumbbell, [NearestFrontier(), NearestFrontier()], 0, _config(),
                          starts=starts)
    raw = episode.world.robots[0].latest_scan
    masked = episode.bodies.mask(0, raw, episode._body_centres())
    # The beams whose return came from robot 1's silhouette (the lidar's last cast).
    lidar = episode.world.robots[0].lidar
    teammate = lidar._geomid == lidar._silhouettes[0]
    assert teammate.sum() > 5
    assert np.isnan(masked.ranges[teammate]).all()
    assert np.isnan(masked.ranges).sum() == teammate.sum()
    face = np.array([1.436, 2.268])  # Under robot 0's lidar, on robot 1's face.
    for scan, occupied in ((raw, True), (masked, False)):
        mapper = OccupancyMapper.like(dumbbell.ground_truth)
        mapper.integrate(scan)
        r, c = mapper.grid.world_to_cell(face)
        assert (mapper.grid.data[r, c] == OCCUPIED) == occupied


def test_team_settings_are_checked(rooms):
    with pytest.raises(UserInputError, match="ground_truth"):
        Episode(rooms, [NearestFrontier()] * 2, 0, _config(localization="odometry"),
                team_config=TeamConfig(unknown_starts=True))
    with pytest.raises(UserInputError, match="one per robot"):
        Episode(rooms, [NearestFrontier()], 0, _config(), starts=[(1, 1, 0), (2, 2, 0)])
    with pytest.raises(ValueError):
        TeamConfig(wait_timeout=0.0)
