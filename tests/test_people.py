"""Pedestrians (mjexplore/sim/people.py): the social force model walking people between
goals around the walls, seeded, never inside a wall, out of a robot's way, and a crowd the
building cannot hold refused."""

from __future__ import annotations

import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.people import Crowd, PeopleConfig


@pytest.fixture(scope="module")
def office():
    return resolve_scene("office").ground_truth


def _walk(gt, seed, seconds=20.0, count=10, robots=None):
    crowd = Crowd(PeopleConfig(count=count), gt, np.random.default_rng(seed),
                  keep_clear=np.array([[13.0, 17.8]]))
    track = [crowd.positions.copy()]
    for _ in range(int(seconds / 0.5)):
        crowd.step(0.5, robots)
        track.append(crowd.positions.copy())
    return crowd, np.array(track)


def test_a_seed_replays_the_same_crowd(office):
    _, a = _walk(office, 3)
    _, b = _walk(office, 3)
    _, c = _walk(office, 4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_people_walk_between_goals_and_stay_out_of_the_walls(office):
    crowd, track = _walk(office, 0, seconds=60.0)
    cfg = crowd.config
    start = track[0]
    assert np.linalg.norm(start - [13.0, 17.8], axis=1).min() >= cfg.keep_clear
    # Apart at the start: a body's width between any two.
    gaps = np.linalg.norm(start[:, None] - start[None], axis=2) + np.eye(len(start)) * 99
    assert gaps.min() >= 2 * cfg.radius
    rc = office.world_to_cell(track.reshape(-1, 2))
    assert office.free[rc[:, 0], rc[:, 1]].all()  # Never on a wall cell.
    speeds = np.linalg.norm(np.diff(track, axis=0), axis=2) / 0.5
    assert speeds.max() <= 1.3 * cfg.speed[1] + 1e-9
    assert speeds.mean() > 0.4  # They walk, and not only in place.
    # Goals 3 m or more away, most beyond 20 m: most reach one in a minute, few give up.
    assert crowd.goals_reached >= len(crowd) // 2
    assert crowd.goals_abandoned <= crowd.goals_reached


def test_people_step_around_a_standing_robot(office):
    robot = np.array([[13.0, 17.8]])
    crowd = Crowd(PeopleConfig(count=6), office, np.random.default_rng(1))
    # Every goal right past the robot: each walks by it.
    for i in range(len(crowd)):
        crowd.send(i, robot[0] + (0.0, 2.0))
    crowd.positions[:] = robot[0] - (0.0, 2.0) + np.linspace(-1.0, 1.0, 6)[:, None] * (1, 0)
    nearest = []
    for _ in range(80):
        crowd.step(0.1, robot)
        nearest.append(crowd.distances_to(robot)[0])
    assert min(nearest) > 0.194 - 0.05  # The robot's bounding circle, barely touched.


def test_a_crowd_the_building_cannot_hold_is_refused(office):
    with pytest.raises(UserInputError, match=r"holds \d+ walking; give --people \d+"):
        Crowd(PeopleConfig(count=100_000), office, np.random.default_rng(0))
    with pytest.raises(UserInputError, match="0 or more"):
        PeopleConfig(count=-1)
    assert len(Crowd(PeopleConfig(), office, np.random.default_rng(0))) == 0


def test_people_walk_in_the_mujoco_world_seen_by_the_lidar(office):
    """Physics and kinematic worlds carry the crowd: mocap bodies moved every sample,
    cast by the lidar, replayed by the seed."""
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.simulator import SimConfig, Simulator

    scene = resolve_scene("office")
    config = SimConfig(dynamics="kinematic", people=PeopleConfig(count=15), seed=2)
    a, b = Simulator(scene, config), Simulator(scene, config)
    for _ in range(20):
        a.command(0.2, 0.3)
        b.command(0.2, 0.3)
        a.step(0.5)
        b.step(0.5)
        np.testing.assert_array_equal(a.crowd.positions, b.crowd.positions)
    mocap = a.data.mocap_pos[:, :2]
    np.testing.assert_allclose(mocap, a.crowd.positions)
    assert a.time == pytest.approx(10.0) and a.crowd.time == pytest.approx(10.0)
    # A person standing 1.2 m ahead of the robot at its start (free space there) stops the
    # beams that meet its disc.
    c = Simulator(scene, config)
    x, y, yaw = c.pose
    ahead = np.array([x + 1.2 * np.cos(yaw), y + 1.2 * np.sin(yaw)])
    c.crowd.positions[0] = ahead
    c.crowd.goals[0], c.crowd.preferred[0] = ahead, 0.0
    scan = c.step(0.1)[-1]
    front = np.abs(scan.angles) < 0.05
    assert (c.lidar._geomid == -2).any()
    assert np.all(scan.ranges[front] < 1.2 - 0.25 + 0.1)
    # The grid world carries people too (tests/test_people_grid.py).
    assert SimConfig(dynamics="grid", people=PeopleConfig(count=3)).people.count == 3


def test_a_robot_driving_at_a_person_is_stopped_and_counts_a_contact():
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.simulator import SimConfig, Simulator

    scene = resolve_scene("office")
    sim = Simulator(scene, SimConfig(dynamics="kinematic",
                                     people=PeopleConfig(count=1, speed=(0.6, 0.6))))
    x, y, yaw = sim.pose
    # The person stands 1 m ahead of the robot, and stays (no goal to walk to).
    sim.crowd.positions[:] = [x + np.cos(yaw), y + np.sin(yaw)]
    sim.crowd.goals[:] = sim.crowd.positions
    sim.crowd.preferred[:] = 0.0
    for _ in range(40):
        sim.command(0.5, 0.0)
        sim.step(0.1)
    gap = np.hypot(*(sim.crowd.positions[0] - sim.body_centre)) - 0.194 - 0.25
    assert gap > -0.02  # Refused before the bodies overlap.
    assert sim.people_collisions >= 1 and sim.in_collision


def test_explore_refuses_more_people_than_fit_before_building_the_world(tmp_path, capsys):
    """Exit 2 with the number that fits, at once (not after compiling a model with a body
    for each person)."""
    from mjexplore.cli import main

    out = tmp_path / "run"
    assert main(["explore", "--scene", "train_loop", "--people", "100000", "--max-time", "5",
                 "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "do not fit" in err and "give --people" in err
    assert not out.exists()


def test_a_team_among_people_counts_them_per_robot():
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.scenes.canonical import resolve_scene
    from mjexplore.sim.simulator import SimConfig

    config = EpisodeConfig(max_time=15.0, sim=SimConfig(dynamics="kinematic",
                                                        people=PeopleConfig(count=4)))
    m = Episode(resolve_scene("train_loop"), [make_explorer("nearest") for _ in range(2)], 0,
                config).run().metrics
    assert m["robots"] == 2 and m["people"] == 4
    assert m["people_collisions"] == sum(r["people_collisions"] for r in m["per_robot"])
    for r in m["per_robot"]:
        assert r["people_min_distance_m"] is not None and r["time_stopped_s"] >= 0.0


def _episode_with_a_person_ahead(distance: float):
    """A robot alone in the office (kinematic world) with one person standing ``distance``
    metres ahead of it, after two control periods."""
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.sim.simulator import SimConfig

    config = EpisodeConfig(max_time=20.0, sim=SimConfig(dynamics="kinematic",
                                                        people=PeopleConfig(count=1)))
    ep = Episode(resolve_scene("office"), make_explorer("nearest"), 0, config)
    crowd = ep.world.crowd
    x, y, yaw = ep.world.pose
    crowd.positions[:] = [x + distance * np.cos(yaw), y + distance * np.sin(yaw)]
    crowd.goals[:] = crowd.positions
    crowd.preferred[:] = 0.0
    for _ in range(2):
        ep.step()
    return ep, crowd.positions[0].copy()


def test_a_person_the_robot_sees_is_no_wall_in_its_map_but_an_obstacle_in_its_costmap():
    ep, person = _episode_with_a_person_ahead(1.5)
    grid = ep.mapper.grid
    assert list(ep.bodies.seen[0]) == [0] and ep.bodies.people_returns > 0
    r, c = grid.world_to_cell(person[None])[0]
    assert not grid.occupied[r - 6:r + 7, c - 6:c + 7].any()  # No wall within 0.3 m.
    costmap = ep.agents[0]._costmap
    assert r * grid.shape[1] + c in set(costmap.body_cells.tolist())
    assert costmap.cost[r * grid.shape[1] + c] < 0  # Not traversable.


def test_a_walking_crowd_leaves_no_phantom_walls_in_the_map():
    """Every occupied cell of the robot's map lies on or beside a ground-truth wall, all
    the way through (mapping the people's returns leaves ~25 phantom wall cells here)."""
    from mjexplore.episode import Episode, EpisodeConfig
    from mjexplore.explorers import make_explorer
    from mjexplore.sim.simulator import SimConfig

    config = EpisodeConfig(max_time=60.0, sim=SimConfig(dynamics="kinematic",
                                                        people=PeopleConfig(count=20)))
    ep = Episode(resolve_scene("office"), make_explorer("nearest"), 1, config)
    gt, grid = ep.scene.ground_truth, ep.mapper.grid
    walls = gt.occupied
    near = np.zeros_like(walls)
    rows, cols = walls.shape
    for dr in range(-2, 3):  # Within two cells (0.1 m) of a wall.
        for dc in range(-2, 3):
            near[max(dr, 0):rows + min(dr, 0), max(dc, 0):cols + min(dc, 0)] |= \
                walls[max(-dr, 0):rows + min(-dr, 0), max(-dc, 0):cols + min(-dc, 0)]
    phantom = 0
    while ep.step():
        phantom = max(phantom, int(grid.occupied[~near].sum()))
    assert ep.bodies.people_returns > 0  # People were seen.
    assert phantom == 0


def test_a_person_in_a_doorway_is_waited_for_not_taken_for_a_wall():
    """In a costmap, a person standing in the only door blocks the way; the way is known
    to open without the person (the robot waits, the frontier behind is not given up)."""
    from mjexplore.maps import FREE, OCCUPIED, GridMap
    from mjexplore.navigation.bodies import BodyCostmap
    from mjexplore.topology.gvd import DynamicGVD

    data = np.full((60, 100), FREE, np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    data[:, 48:52] = OCCUPIED
    data[20:40, 48:52] = FREE  # A 1 m door at x = 2.5 m.
    grid = GridMap(data, 0.05)
    gvd = DynamicGVD(grid.shape)
    gvd.update(grid.occupied, grid.known)
    costmap = BodyCostmap(grid, gvd.distance2, person_radius=0.55)
    start, goal = np.array([1.0, 1.5]), np.array([4.0, 1.5])
    assert costmap.plan(start, goal, 0.3) is not None
    costmap.set_bodies(np.zeros((0, 2)), np.array([[2.5, 1.5]]))
    cost = costmap.cost.copy()
    assert costmap.plan(start, goal, 0.3) is None
    assert costmap.blocked_by_bodies(start, goal, 0.3)
    assert costmap.reachable_without_bodies(start, goal[None])
    np.testing.assert_array_equal(costmap.cost, cost)  # The person is back in.
    costmap.set_bodies(np.zeros((0, 2)), np.array([[4.0, 2.5]]))  # Walked through.
    assert costmap.plan(start, goal, 0.3) is not None


def test_a_density_sets_the_count_per_scene(office, capsys):
    from mjexplore.cli import main
    from mjexplore.sim.people import for_scene

    maze = resolve_scene("maze").ground_truth
    dense = PeopleConfig(density=2.0)
    counts = [for_scene(dense, gt).count for gt in (office, maze)]
    assert counts[0] > counts[1] > 0  # More floor, more people.
    assert for_scene(PeopleConfig(density=4.0), office).count == pytest.approx(
        2 * counts[0], abs=1)
    assert for_scene(PeopleConfig(count=3), office).count == 3
    with pytest.raises(UserInputError, match="not both"):
        PeopleConfig(count=3, density=1.0)
    assert main(["explore", "--scene", "office", "--people", "3", "--people-density", "1",
                 "--out", "unused"]) == 2
    assert "not both" in capsys.readouterr().err
