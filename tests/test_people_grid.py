"""Pedestrians in the grid world (issue 51): the crowd of the MuJoCo worlds walking on the
ground truth, seen by the grid lidar (sim/lidar.py's ray_discs), refusing the robot's moves
into it, counted in the metrics, and replayed by the seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mjexplore.episode import Episode, EpisodeConfig
from mjexplore.explorers import make_explorer
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.team import draw_starts
from mjexplore.sim.lidar import ray_discs
from mjexplore.sim.motion import BODY_RADIUS
from mjexplore.sim.people import PeopleConfig
from mjexplore.sim.simulator import SimConfig
from mjexplore.sim.world import make_world


def test_ray_discs_gives_the_analytic_distance():
    r = 0.25
    centres = np.array([[3.0, 0.0], [3.0, 5.0]])
    vec = np.array([[1.0, 0.0, 0.0],  # Through the first centre.
                    [0.0, 1.0, 0.0],  # Past both.
                    [-1.0, 0.0, 0.0]])  # Away from both.
    t, normals = ray_discs(np.array([0.0, 0.0, 0.132]), vec, centres, r)
    assert t[0] == pytest.approx(3.0 - r, abs=1e-12)
    np.testing.assert_allclose(normals[0], [-1.0, 0.0], atol=1e-12)
    assert np.isinf(t[1:]).all() and not normals[1:].any()
    # A beam off the centre by h meets the disc sqrt(r^2 - h^2) before the centre's
    # projection; the normal points from the centre to the hit.
    h = 0.1
    t, normals = ray_discs(np.array([0.0, h]), np.array([[1.0, 0.0]]), centres, r)
    assert t[0] == pytest.approx(3.0 - math.sqrt(r * r - h * h), abs=1e-12)
    np.testing.assert_allclose(normals[0], [-math.sqrt(r * r - h * h) / r, h / r], atol=1e-12)
    # The nearer of two discs on the way; from inside a disc, that disc is not seen.
    both = np.array([[3.0, 0.0], [1.5, 0.0]])
    assert ray_discs(np.zeros(2), np.array([[1.0, 0.0]]), both, r)[0][0] == \
        pytest.approx(1.5 - r)
    assert ray_discs(np.array([1.5, 0.0]), np.array([[1.0, 0.0]]), both, r)[0][0] == \
        pytest.approx(1.5 - r)


def _grid(people=15, seed=2, starts=None):
    config = SimConfig(dynamics="grid", people=PeopleConfig(count=people), seed=seed)
    return make_world(resolve_scene("office"), config, starts)


def _hold(crowd, i, where):
    """Person ``i`` stands at ``where`` (no goal to walk to)."""
    crowd.positions[i] = where
    crowd.goals[i], crowd.preferred[i] = where, 0.0


def test_the_grid_lidar_sees_a_person_ahead():
    """A person standing 1.2 m ahead of the robot stops exactly the beams that meet its
    disc, at the disc (as the MuJoCo lidar does, tests/test_people.py)."""
    world = _grid()
    assert world.lidar.people is world.crowd and len(world.crowd) == 15
    x, y, yaw = world.pose
    ahead = np.array([x + 1.2 * np.cos(yaw), y + 1.2 * np.sin(yaw)])
    world.lidar.people = None
    walls = world.lidar.cast(x, y, yaw).copy()  # The walls alone (-1: none in range).
    walls[walls < 0] = np.inf
    world.lidar.people = world.crowd
    _hold(world.crowd, 0, ahead)
    scan = world.step(0.1)[-1]
    front = np.abs(scan.angles) < 0.05
    assert np.all(scan.ranges[front] < 1.2 - 0.25 + 0.1)
    # The beams whose line passes within the radius of the person's centre, ahead.
    ox, oy, oyaw = scan.pose
    rel = world.crowd.positions[0] - (ox, oy)
    heading = oyaw + scan.angles
    along = rel[0] * np.cos(heading) + rel[1] * np.sin(heading)
    across = np.abs(rel[0] * np.sin(heading) - rel[1] * np.cos(heading))
    r = world.crowd.config.radius
    met = (along > 0) & (across < r - 1e-6)
    assert met.sum() >= 10
    expected = along[met] - np.sqrt(r * r - across[met] ** 2)
    np.testing.assert_allclose(scan.ranges[met], expected, atol=1e-5)
    assert np.all(scan.ranges[met] < walls[met])  # Nearer than the walls behind.


def test_a_robot_driving_at_a_person_is_stopped_and_counts_a_contact():
    world = _grid(people=1)
    x, y, yaw = world.pose
    _hold(world.crowd, 0, [x + np.cos(yaw), y + np.sin(yaw)])
    for _ in range(40):
        world.command(0.5, 0.0)
        world.step(0.1)
    gap = np.hypot(*(world.crowd.positions[0] - world.body_centre)) - BODY_RADIUS - 0.25
    assert gap > -0.02  # Refused before the bodies overlap.
    assert world.people_collisions >= 1 and world.in_collision
    assert world.people_min_distance < 0.05


def test_a_grid_team_shares_one_crowd():
    scene = resolve_scene("office")
    gt = scene.ground_truth
    starts = draw_starts(gt, scene.start, 2, np.random.default_rng([0, 2]))
    world = _grid(people=8, starts=starts)
    assert len(world.robots) == 2 and all(r.crowd is world.crowd for r in world.robots)
    assert all(r.lidar.people is world.crowd for r in world.robots)
    # Clear of every robot's start.
    centres = world.crowd.positions
    for p in starts:
        assert np.linalg.norm(centres - p[:2], axis=1).min() >= world.crowd.config.keep_clear
    for _ in range(10):
        for r in world.robots:
            r.command(0.2, 0.3)
        world.step_all(0.5)
    assert world.crowd.time == pytest.approx(5.0)
    assert all(np.isfinite(r.people_min_distance) for r in world.robots)


def _episode(seed):
    config = EpisodeConfig(max_time=30.0, sim=SimConfig(dynamics="grid",
                                                        people=PeopleConfig(count=5)))
    episode = Episode(resolve_scene("train_loop"), make_explorer("nearest"), seed, config)
    result = episode.run()
    return episode.world.crowd.positions.copy(), result.metrics


def test_a_grid_episode_among_people_is_replayed_by_its_seed():
    crowd_a, metrics_a = _episode(0)
    crowd_b, metrics_b = _episode(0)
    np.testing.assert_array_equal(crowd_a, crowd_b)
    assert metrics_a == metrics_b
    assert metrics_a["people"] == 5 and metrics_a["exploration_time_s"] == pytest.approx(30.0)
    for key in ("people_collisions", "people_min_distance_m", "time_stopped_s"):
        assert metrics_a[key] is not None
    crowd_c, _ = _episode(1)
    assert not np.array_equal(crowd_a, crowd_c)


def test_a_grid_world_without_people_has_no_crowd():
    world = make_world(resolve_scene("office"), SimConfig(dynamics="grid"))
    assert world.crowd is None and world.lidar.people is None
