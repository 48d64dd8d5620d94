"""The grid world: the kinematic world's motion and readings without MuJoCo."""

import dataclasses
import math

import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.robot import motion_profile
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.scene import clearance, load_scene_files, write_scene
from mjexplore.sim.grid_world import GridWorld
from mjexplore.sim.lidar import LidarConfig, lidar_model
from mjexplore.sim.odometry import ODOMETRY_ERRORS
from mjexplore.sim.simulator import BODY_CENTRE_X, BODY_RADIUS, SimConfig, Simulator
from mjexplore.sim.world import make_world

GRID = SimConfig(dynamics="grid")
KINEMATIC = SimConfig(dynamics="kinematic")


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    """A generated 24 x 16 m office."""
    scene = generate_scene("office", 24, 16, seed=3)
    return load_scene_files(write_scene(scene, tmp_path_factory.mktemp("grid") / "office"))


def _random_free_poses(scene, n, seed):
    """``n`` poses where the body fits, uniformly over the free space."""
    gt = scene.ground_truth
    rng = np.random.default_rng(seed)
    cells = np.argwhere(clearance(gt.free, gt.resolution) > BODY_RADIUS + 0.1)
    xy = gt.cell_to_world(cells[rng.choice(len(cells), n, replace=False)])
    return np.column_stack([xy, rng.uniform(-math.pi, math.pi, n)])


def test_make_world_builds_the_world_dynamics_asks_for(box_room):
    folder, _ = box_room
    assert isinstance(make_world(folder, GRID), GridWorld)
    assert isinstance(make_world(folder, KINEMATIC), Simulator)
    with pytest.raises(UserInputError, match="make_world"):
        Simulator(folder, GRID)


def test_grid_lidar_reads_the_mujoco_lidars_ranges(office):
    """The grid lidar's true distances against mj_multiRay's on the MJCF's wall boxes at
    200 poses over the whole office: hit or miss agree for 99.5 % of the beams and the
    ranges to within one cell (0.05 m) for 99.5 % of those both hit (corners where boxes
    and cells meet at a point may differ)."""
    kinematic = Simulator(office, KINEMATIC)
    grid = GridWorld(office, GRID)
    same_class, close, exact = [], [], []
    for pose in _random_free_poses(office, 200, seed=0):
        kinematic.reset(tuple(pose))
        mujoco_dist = kinematic.lidar.cast(kinematic.data).copy()
        grid_dist = grid.lidar.cast(*pose)
        limit = kinematic.lidar.config.range_max
        hit_m = (mujoco_dist >= 0) & (mujoco_dist <= limit)
        hit_g = (grid_dist >= 0) & (grid_dist <= limit)
        same_class.append(hit_m == hit_g)
        both = hit_m & hit_g
        diff = np.abs(mujoco_dist[both] - grid_dist[both])
        close.append(diff <= 0.05)
        exact.append(diff <= 1e-6)
    assert np.concatenate(same_class).mean() >= 0.995
    assert np.concatenate(close).mean() >= 0.995
    assert np.concatenate(exact).mean() >= 0.99  # Face distances, not cell centres.


def test_same_commands_drive_the_kinematic_worlds_trajectory_and_scans(office):
    """Same motion model, same seed: the same kinematics log and noisy scans as the
    kinematic world, collisions included."""
    lidar = LidarConfig(noise_std=0.01)
    worlds = [make_world(office, SimConfig(dynamics=d, lidar=lidar, seed=5))
              for d in ("kinematic", "grid")]
    rng = np.random.default_rng(1)
    scans = [[], []]
    for _ in range(300):  # 30 s of random driving, bumping into walls.
        v, w = rng.uniform(-0.2, 0.5), rng.uniform(-1.8, 1.8)
        for world, out in zip(worlds, scans):
            world.command(v, w)
            out.extend(s.ranges for s in world.step(0.1))
    kinematic, grid = (w.kinematics().as_table() for w in worlds)
    assert kinematic.shape == grid.shape
    assert np.allclose(kinematic, grid, atol=1e-9, equal_nan=True)
    assert worlds[0].collisions == worlds[1].collisions > 0
    a, b = np.array(scans[0]), np.array(scans[1])
    assert a.shape == b.shape == (300, 360)
    assert np.mean(np.isclose(a, b, atol=1e-5) | (np.isinf(a) & np.isinf(b))) >= 0.995
    assert worlds[1].latest_scan.stamp == pytest.approx(30.0)


def test_cannot_drive_through_a_wall(box_room):
    folder, interior = box_room
    world = GridWorld(folder, GRID)
    world.reset((interior[2] - 1.0, 2.2, 0.0))  # Facing the east wall, 1 m away.
    world.command(0.5, 0.0)
    for _ in range(60):  # 6 s: would be 2 m further.
        world.step(0.1)
    front = world.pose[0] + BODY_CENTRE_X + BODY_RADIUS  # The body circle's leading edge.
    assert interior[2] - 0.05 <= front <= interior[2] + 1e-6  # Stopped within a cell.
    assert world.in_collision and world.collisions == 1  # One long push: one collision.
    assert world.velocity[0] == 0.0
    ahead = world.latest_scan.ranges[0]  # Beam 0 looks ahead from base_scan.
    assert ahead == pytest.approx(interior[2] - world.latest_scan.pose[0], abs=1e-4)
    world.command(-0.3, 0.0)
    world.step(1.0)
    assert not world.in_collision and world.pose[0] < interior[2] - 0.3


def test_unknown_ground_truth_blocks_the_grid_world(tmp_path):
    """On an imported map, unknown cells are walls in the MJCF and in the grid world."""
    from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
    from mjexplore.scenes.importer import scene_from_grid

    data = np.full((60, 120), FREE, np.int8)  # 6 x 3 m at 0.05 m.
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    data[1:-1, 80:90] = UNKNOWN  # An unknown strip from x = 4.0 m to 4.5 m.
    scene = scene_from_grid(GridMap(data, 0.05), "strip", {"source": "test"},
                            start=(1.0, 1.5, 0.0))
    world = GridWorld(load_scene_files(write_scene(scene, tmp_path / "strip")), GRID)
    world.reset((1.0, 1.5, 0.0))
    world.command(0.5, 0.0)
    for _ in range(200):  # 20 s at 0.5 m/s: would reach x = 5.5 m through the strip.
        world.step(0.1)
    front = world.pose[0] + BODY_CENTRE_X + BODY_RADIUS
    assert 3.9 <= front <= 4.0 + 1e-6
    assert world.in_collision
    # The lidar sees the strip as a wall too.
    assert world.latest_scan.ranges[0] == pytest.approx(4.0 - world.latest_scan.pose[0],
                                                        abs=1e-4)


@pytest.mark.parametrize("profile", ["sim", "real"])
def test_speed_and_acceleration_limits_hold_in_the_log(box_room, profile):
    folder, _ = box_room
    p = motion_profile(profile)
    world = GridWorld(folder, SimConfig(dynamics="grid", profile=profile))
    world.reset((3.2, 2.2, 0.0))
    for v, w, seconds in [(5.0, 0.0, 0.6), (-5.0, 9.0, 1.0), (0.3, -9.0, 1.0), (0.0, 0.0, 1.0)]:
        world.command(v, w)  # Far above the limits.
        world.step(seconds)
    log = world.kinematics()
    dt = np.diff(log.t)
    assert np.allclose(dt, 0.05)
    for vel, cmd, top, accel in [
            (log.linear_velocity, log.cmd_linear, p.max_linear_speed, p.max_linear_accel),
            (log.angular_velocity, log.cmd_angular, p.max_angular_speed, p.max_angular_accel)]:
        assert np.abs(vel).max() <= top + 1e-9 and np.abs(cmd).max() <= top + 1e-9
        assert (np.abs(np.diff(vel)) / dt).max() <= accel + 1e-6
        assert (np.abs(np.diff(cmd)) / dt).max() <= accel + 1e-6
        assert (np.abs(np.diff(cmd)) / dt).max() >= accel - 1e-6  # The limit was reached.
    wheel = (np.abs(log.linear_velocity) + np.abs(log.angular_velocity) * 0.287 / 2) / 0.033
    assert wheel.max() <= p.max_wheel_speed + 1e-6
    assert np.isnan(log.imu_gyro).all()  # No dynamics, no IMU.


def test_odometry_equals_the_integrated_pose(box_room):
    folder, _ = box_room
    world = GridWorld(folder, GRID)
    world.reset((3.2, 2.2, 0.4))
    for k in range(100):
        world.command(0.3, 0.8 if k < 50 else -0.8)
        world.step(0.1)
    x0, y0, yaw0 = world.odom_origin
    c, s = math.cos(yaw0), math.sin(yaw0)
    ox, oy, oyaw = world.odom_pose
    assert np.allclose([x0 + c * ox - s * oy, y0 + s * ox + c * oy], world.pose[:2], atol=1e-9)
    assert math.remainder(yaw0 + oyaw - world.pose[2], 2 * math.pi) == pytest.approx(0, abs=1e-9)
    assert world.kinematics().path_length() > 2.5


@pytest.mark.parametrize("dynamics", ["grid", "kinematic"])
def test_gyro_heading_turns_with_the_base_in_the_training_worlds(box_room, dynamics):
    """With an exact gyro the odometry's heading is the true one though the wheels' track
    width and radii are off; with the typical gyro it is off by its scale and bias only."""
    folder, _ = box_room
    typical = ODOMETRY_ERRORS["typical"]
    exact_gyro = dataclasses.replace(typical, gyro_scale_std=0.0, gyro_bias_std=0.0,
                                     gyro_noise_density=0.0)
    for error in (exact_gyro, typical):
        world = make_world(folder, SimConfig(dynamics=dynamics, odometry_heading="imu",
                                             odometry_error=error, seed=4))
        world.reset((3.2, 2.2, 0.4))
        turned = 0.0
        for _ in range(40):
            before = world.pose[2]
            world.command(0.0, 1.0)
            world.step(0.1)
            turned += math.remainder(world.pose[2] - before, 2 * math.pi)
        heading = world.odom_pose[2]  # The odom frame starts at the reset pose.
        g = world.odometry.gyro
        expected = g.scale * turned + g.bias * world.time
        # The rate noise over the turn, three standard deviations.
        tolerance = 3 * error.gyro_noise_density * math.sqrt(world.time) + 1e-9
        assert math.remainder(heading - expected, 2 * math.pi) == pytest.approx(
            0.0, abs=tolerance)
        assert abs(turned) > 3.0
    # The wheels alone would have read the same turn off by their track width's error.
    assert world.odometry.error.track_scale != 1.0


def test_lds01_in_the_grid_world_matches_the_kinematic_one(box_room):
    """Motion skew, range noise and dropouts: the same readings as the kinematic world
    (beams within a skew chunk's travel, the same draws)."""
    folder, _ = box_room
    worlds = [make_world(folder, SimConfig(dynamics=d, lidar=lidar_model("lds01"), seed=2))
              for d in ("kinematic", "grid")]
    for world in worlds:
        world.reset((3.2, 2.2, 0.0))
        world.command(0.3, 0.8)
        world.step(2.0)
    a, b = (w.latest_scan for w in worlds)
    assert a.stamp == b.stamp and a.time_increment == b.time_increment
    assert np.array_equal(np.isnan(a.ranges), np.isnan(b.ranges))  # The same dropout draws.
    valid = np.isfinite(a.ranges) & np.isfinite(b.ranges)
    assert valid.mean() > 0.7
    assert np.abs(a.ranges[valid] - b.ranges[valid]).max() < 0.01


def test_same_seed_same_episode(tmp_path, monkeypatch):
    """A whole nearest-frontier episode in the grid world, twice with one seed: the same
    trajectory, scans and metrics; another seed differs."""
    from mjexplore.episode import Episode, EpisodeConfig, engine
    from mjexplore.episode.nearest import NearestFrontier

    # Until the episode engine builds its world with make_world.
    monkeypatch.setattr(engine, "Simulator", make_world, raising=False)
    scene = load_scene_files(write_scene(generate_scene("rooms", 12, 9, seed=1),
                                         tmp_path / "rooms"))
    config = EpisodeConfig(max_time=120.0, sim=SimConfig(
        dynamics="grid", lidar=LidarConfig(noise_std=0.01)))
    runs = []
    for seed in (7, 7, 8):
        episode = Episode(scene, NearestFrontier(), seed, config)
        assert isinstance(episode.sim, GridWorld)
        result = episode.run()
        runs.append((result.kinematics.as_table(), episode.sim.latest_scan.ranges,
                     result.metrics))
    assert runs[0][2]["exploration_ratio"] > 0.5
    assert np.array_equal(runs[0][0], runs[1][0], equal_nan=True)
    assert np.array_equal(runs[0][1], runs[1][1])
    assert runs[0][2]["exploration_time_s"] == runs[1][2]["exploration_time_s"]
    assert runs[2][0].shape != runs[0][0].shape or not np.array_equal(
        runs[0][0], runs[2][0], equal_nan=True)


def test_model_and_data_show_the_robot_for_rendering(box_room):
    folder, _ = box_room
    world = GridWorld(folder, GRID)
    world.reset((2.0, 1.5, 1.0))
    world.command(0.3, 0.5)
    world.step(1.0)
    d = world.data
    base = world.model.body("base_link").id
    assert np.allclose(d.xpos[base][:2], world.pose[:2])
    assert math.atan2(d.xmat[base][3], d.xmat[base][0]) == pytest.approx(world.pose[2])
    assert world.warnings() == {} and world.is_upright and not world.physics_fault
