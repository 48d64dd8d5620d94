"""N robots in one MuJoCo world: the team's MJCF, start poses, lidars that see teammates,
robot-robot collisions, and a team of one that is the single robot."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from conftest import shared_data

from mjexplore.errors import UserInputError
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.scenes.scene import clearance
from mjexplore.scenes.team import (
    EXPLORE_BENCH_TEAM_STARTS,
    check_starts,
    draw_starts,
    explore_bench_starts,
    parse_starts,
    team_spec,
)
from mjexplore.sim.grid_world import GridWorld
from mjexplore.sim.lidar import ray_boxes
from mjexplore.sim.simulator import SimConfig, Simulator, robot_seed
from mjexplore.sim.world import make_world


@pytest.fixture(scope="module")
def office():
    return resolve_scene("office")


@pytest.fixture(scope="module")
def open_spot(office):
    """The office's most open point: 2.4 m from any wall."""
    g = office.ground_truth
    c = clearance(g.free, g.resolution)
    r, col = np.unravel_index(np.argmax(c), c.shape)
    return g.cell_to_world(np.array([r, col]))


def test_team_spec_has_n_prefixed_robots(office):
    starts = [(13.0, 17.8, 0.0), (14.5, 16.0, 1.0), (12.0, 16.0, -1.0)]
    model = team_spec(office.xml, starts).compile()
    names = [model.body(i).name for i in range(model.nbody)]
    for i, (x, y, yaw) in enumerate(starts):
        assert f"robot_{i}/base_link" in names
        assert model.actuator(f"robot_{i}/wheel_left").id >= 0
        assert model.sensor(f"robot_{i}/imu_gyro").id >= 0
        assert model.site(f"robot_{i}/base_scan").id >= 0
        assert model.geom(f"robot_{i}/silhouette").contype == 0
        base = model.body(f"robot_{i}/base_link")
        np.testing.assert_allclose(base.pos[:2], (x, y))
        assert math.isclose(2 * math.atan2(base.quat[3], base.quat[0]), yaw, abs_tol=1e-9)
    assert "base_link" not in names  # The scene's own robot is replaced.
    assert model.nu == 2 * len(starts) and model.nsensor == 2 * len(starts)


def test_lidars_see_teammates_not_themselves(office, open_spot):
    x, y = open_spot
    team = Simulator(office, starts=[(x - 0.75, y, 0.0), (x + 0.75, y, math.pi)])
    a, b = (r.latest_scan for r in team.robots)
    # Beam 0 of each looks at the other: lidar 0.064 m behind base_link, the teammate's
    # box (0.281 m long, centred 0.064 m behind its axle) facing it.
    expected = 1.5 + 0.064 + 0.064 - 0.1405
    assert a.ranges[0] == pytest.approx(expected, abs=1e-3)
    assert b.ranges[0] == pytest.approx(expected, abs=1e-3)
    # Beams looking away see the walls, more than 1.5 m off, not their own silhouette.
    assert a.ranges[180] > 1.5 and b.ranges[180] > 1.5


@pytest.mark.parametrize("dynamics", ["physics", "kinematic"])
def test_robots_collide_with_each_other(office, open_spot, dynamics):
    x, y = open_spot
    team = Simulator(office, SimConfig(dynamics=dynamics),
                     starts=[(x - 0.75, y, 0.0), (x + 0.75, y, math.pi)])
    for _ in range(60):
        for r in team.robots:
            r.command(0.3, 0.0)
        team.step_all(0.1)
    assert team.robot_collisions == 1  # One long push: one collision.
    assert [r.robot_contacts for r in team.robots] == [1, 1]
    assert [r.collisions for r in team.robots] == [0, 0]  # Walls are counted apart.
    assert all(r.in_collision for r in team.robots)
    bodies = [np.array(r.body_centre) for r in team.robots]
    # The bodies touch and do not pass through each other.
    assert np.hypot(*(bodies[0] - bodies[1])) > 0.2
    assert team.robots[0].pose[0] < team.robots[1].pose[0]
    assert team.warnings() == {}


@pytest.mark.parametrize("dynamics", ["physics", "kinematic", "grid"])
def test_team_of_one_is_the_single_robot(office, dynamics):
    config = SimConfig(dynamics=dynamics, seed=3)
    single = make_world(office, config)
    team = make_world(office, config, [office.start])
    assert isinstance(team, GridWorld if dynamics == "grid" else Simulator)
    robot = team.robots[0]
    rng = np.random.default_rng(0)
    for _ in range(100):
        v, w = rng.uniform(-0.2, 0.5), rng.uniform(-1.0, 1.0)
        single.command(v, w)
        robot.command(v, w)
        a, b = single.step(0.1), team.step_all(0.1)[0]
    tolerance = 0.0 if dynamics == "grid" else 1e-9  # The grid world's pose is exact.
    np.testing.assert_allclose(robot.pose, single.pose, rtol=0.0, atol=tolerance)
    np.testing.assert_allclose(robot.odom_pose, single.odom_pose, rtol=0.0, atol=tolerance)
    np.testing.assert_array_equal(a[-1].ranges, b[-1].ranges)
    assert len(robot.kinematics_rows) == len(single.kinematics_rows)


def test_each_robot_has_its_own_noise_and_logs(office, open_spot):
    x, y = open_spot
    config = SimConfig(lidar=None, seed=5, odometry_error="typical")
    team = Simulator(office, starts=[(x - 1.0, y, 0.0), (x + 1.0, y, 0.0)], config=config)
    assert robot_seed(5, 0) == 5 and robot_seed(5, 1) != 5
    team.robots[0].command(0.3, 0.0)
    team.step_all(2.0)
    k0, k1 = (r.kinematics() for r in team.robots)
    assert len(k0.t) == len(k1.t) == 41
    assert k0.linear_velocity[-1] > 0.2 and abs(k1.linear_velocity[-1]) < 1e-3
    assert team.robots[1].pose[0] == pytest.approx(x + 1.0, abs=1e-3)


def test_random_driving_raises_no_warnings(office):
    """Menagerie's model test: step the team under random commands, no MuJoCo warning."""
    starts = draw_starts(office.ground_truth, office.start, 3, np.random.default_rng(1))
    team = Simulator(office, starts=starts)
    rng = np.random.default_rng(2)
    for _ in range(100):
        for r in team.robots:
            r.command(rng.uniform(-0.5, 0.5), rng.uniform(-1.8, 1.8))
        team.step_all(0.1)
    assert team.warnings() == {}
    assert all(r.is_upright for r in team.robots)


def test_a_robot_alone_is_its_worlds_robot_0(office):
    """One world class: a robot alone (the scene's MJCF untouched) is the world's robot 0,
    stepped by the world; a team's robots are stepped together by theirs."""
    alone = Simulator(office)
    assert alone.robots == [alone] and alone.name == "robot_0"
    team = Simulator(office, starts=[office.start, (office.start[0] + 1.0, office.start[1], 0.0)])
    assert team.robots[0] is team and len(team) == 2
    assert len(team.step_all(0.2)) == 2 and len(team.step(0.1)) == 1


def test_parse_starts():
    assert parse_starts("1,2,0.5;3,4") == [(1.0, 2.0, 0.5), (3.0, 4.0, 0.0)]
    for bad in ("1,2,3,4", "a,b", "1;2,3", "nan,1"):
        with pytest.raises(UserInputError, match="X,Y"):
            parse_starts(bad)


def test_check_starts_refuses_walls_and_overlaps(office):
    g = office.ground_truth
    x, y, yaw = office.start
    check_starts(g, [(x, y, yaw)])
    with pytest.raises(UserInputError, match="apart"):
        check_starts(g, [(x, y, yaw), (x + 0.3, y, yaw)])
    with pytest.raises(UserInputError, match="outside"):
        check_starts(g, [(x, y, yaw), (-50.0, 0.0, 0.0)])


def test_draw_starts_is_seeded_and_keeps_clear(office):
    g = office.ground_truth
    a = draw_starts(g, office.start, 3, np.random.default_rng(7))
    b = draw_starts(g, office.start, 3, np.random.default_rng(7))
    c = draw_starts(g, office.start, 3, np.random.default_rng(8))
    assert a == b and a != c and a[0] == tuple(office.start)
    check_starts(g, a, min_separation=1.0)
    free_clearance = clearance(g.free, g.resolution)
    for x, y, _ in a[1:]:
        r, col = g.world_to_cell(np.array([x, y]))
        assert free_clearance[r, col] >= 0.5
        assert 1.0 <= math.hypot(x - a[0][0], y - a[0][1]) <= 3.0


@pytest.mark.parametrize("name", sorted(EXPLORE_BENCH_TEAM_STARTS))
def test_explore_bench_placements_are_free(name):
    scene = resolve_scene(shared_data("explore_bench", f"{name}.yaml"))
    for placement in ("close", "far"):
        starts = explore_bench_starts(name, placement)
        check_starts(scene.ground_truth, starts)
        d = math.hypot(starts[0][0] - starts[1][0], starts[0][1] - starts[1][1])
        assert (d < 4.0) == (placement == "close")


def test_explore_bench_placements_refuse_other_maps():
    with pytest.raises(UserInputError, match="not one of its maps"):
        explore_bench_starts("office", "close")
    with pytest.raises(UserInputError, match="unknown"):
        explore_bench_starts("room", "near")


def test_the_mujoco_world_refuses_the_grid_dynamics(office):
    with pytest.raises(UserInputError, match="runs without MuJoCo"):
        Simulator(office, starts=[office.start], config=SimConfig(dynamics="grid"))


def test_model_compiles_fast(office):
    """Eight robots' model compiles in well under a second (no <replicate> sites)."""
    starts = draw_starts(office.ground_truth, office.start, 8, np.random.default_rng(0))
    spec = team_spec(office.xml, starts)
    model = spec.compile()
    assert model.nbody == 1 + 3 * 8
    assert isinstance(mujoco.MjData(model), mujoco.MjData)


def test_silhouette_rays_match_mujoco(office, open_spot):
    """ray_boxes meets the silhouettes where MuJoCo's own rays do, turned or not."""
    x, y = open_spot
    rng = np.random.default_rng(4)
    starts = [(x, y, 0.3), (x + 1.2, y + 0.4, 1.1), (x - 0.9, y - 1.0, -2.0)]
    team = Simulator(office, starts=starts)
    lidar = team.robots[0].lidar
    d = team.data
    origin = d.site_xpos[lidar.site_id].copy()
    angles = rng.uniform(-np.pi, np.pi, 500)
    vec = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    ids = lidar._silhouettes  # Robot 1's and 2's, as robot 0's lidar sees them.
    dist, which, normal = ray_boxes(origin, vec, d.geom_xpos[ids],
                                    d.geom_xmat[ids].reshape(-1, 3, 3),
                                    team.model.geom_size[ids[0]])
    group = np.array([0, 0, 0, 0, 0, 1], np.uint8)
    geomid = np.zeros(1, np.int32)
    hits = 0
    for k in range(len(vec)):
        n = np.zeros(3)
        expected = mujoco.mj_ray(team.model, d, origin, vec[k], group, 0,
                                 team.robots[0]._base, geomid, n)
        assert dist[k] == pytest.approx(expected, abs=1e-9)
        if expected >= 0:
            hits += 1
            assert ids[which[k]] == geomid[0]
            np.testing.assert_allclose(normal[k], n, atol=1e-9)
    assert hits > 20


def test_grid_team_sees_and_blocks_teammates(office, open_spot):
    x, y = open_spot
    team = make_world(office, SimConfig(dynamics="grid"),
                      [(x - 0.75, y, 0.0), (x + 0.75, y, math.pi)])
    assert isinstance(team, GridWorld) and team.robots[0] is team
    expected = 1.5 + 0.064 + 0.064 - 0.1405  # As the MuJoCo lidars see each other.
    for r in team.robots:
        assert r.latest_scan.ranges[0] == pytest.approx(expected, abs=1e-3)
    for _ in range(60):
        for r in team.robots:
            r.command(0.3, 0.0)
        team.step_all(0.1)
    assert team.robot_collisions == 1 and [r.robot_contacts for r in team.robots] == [1, 1]
    assert all(r.in_collision for r in team.robots)
    a, b = (np.array(r.body_centre) for r in team.robots)
    assert np.hypot(*(a - b)) >= 2 * 0.194 - 0.05
    assert isinstance(make_world(office, starts=[office.start]), Simulator)
