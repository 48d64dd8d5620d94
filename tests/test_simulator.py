import math

import numpy as np
import pytest

from mjexplore.errors import UserInputError
from mjexplore.robot import motion_profile
from mjexplore.sim.simulator import BODY_CENTRE_X, BODY_RADIUS, SimConfig, Simulator


def mean_over_last(log_t, values, seconds):
    return values[log_t >= log_t[-1] - seconds].mean()


@pytest.mark.parametrize("profile, speed", [("sim", 0.4), ("sim", 0.5), ("real", 0.18)])
def test_reaches_commanded_linear_speed(box_room, profile, speed):
    folder, _ = box_room
    sim = Simulator(folder, SimConfig(profile=profile))
    sim.reset((0.8, 2.2, 0.0))
    sim.command(speed, 0.0)
    sim.step(2.5)
    log = sim.kinematics()
    assert mean_over_last(log.t, log.linear_velocity, 1.0) == pytest.approx(speed, rel=0.05)
    assert sim.collisions == 0


@pytest.mark.parametrize("rate", [0.5, 1.5, -1.8])
def test_reaches_commanded_angular_speed(box_room, rate):
    folder, _ = box_room
    sim = Simulator(folder)
    sim.reset((3.2, 2.2, 0.0))
    sim.command(0.0, rate)
    sim.step(3.0)
    log = sim.kinematics()
    assert mean_over_last(log.t, log.angular_velocity, 1.5) == pytest.approx(rate, rel=0.05)
    # Turning in place: the base barely moves.
    assert np.hypot(*(sim.pose[:2] - [3.2, 2.2])) < 0.05


@pytest.mark.parametrize("profile", ["sim", "real"])
def test_respects_speed_and_acceleration_limits(box_room, profile):
    folder, _ = box_room
    p = motion_profile(profile)
    sim = Simulator(folder, SimConfig(profile=profile))
    sim.reset((0.8, 2.2, 0.0))
    sim.command(5.0, 0.0)  # Far above the limit.
    sim.step(2.0 if profile == "sim" else 4.0)
    sim.command(-5.0, 9.0)
    sim.step(1.0)
    sim.command(0.0, -9.0)
    sim.step(1.0)
    log = sim.kinematics()
    dt = np.diff(log.t)
    # The set-point obeys the limits exactly.
    assert np.abs(log.cmd_linear).max() <= p.max_linear_speed + 1e-9
    assert np.abs(log.cmd_angular).max() <= p.max_angular_speed + 1e-9
    assert (np.abs(np.diff(log.cmd_linear)) / dt).max() <= p.max_linear_accel + 1e-6
    assert (np.abs(np.diff(log.cmd_angular)) / dt).max() <= p.max_angular_accel + 1e-6
    # The body follows within 5 %, plus the transient slip of the soft wheel contacts
    # (acceleration times their 0.01 s time constant) that unwinds when a ramp ends.
    slip = p.max_linear_accel * 0.01
    assert np.abs(log.linear_velocity).max() <= 1.05 * p.max_linear_speed + slip
    assert np.abs(log.angular_velocity).max() <= 1.05 * p.max_angular_speed
    window = 4  # 0.2 s at 20 Hz
    v = log.linear_velocity
    mean_accel = np.abs(v[window:] - v[:-window]) / (log.t[window:] - log.t[:-window])
    assert mean_accel.max() <= 1.15 * p.max_linear_accel


def test_odometry_tracks_truth_and_drifts_a_little(box_room):
    folder, _ = box_room
    sim = Simulator(folder)
    sim.reset((3.2, 2.2, 0.0))
    for k in range(210):  # A figure of eight of two 0.5 m circles, 21 s.
        sim.command(0.3, 0.6 if k < 105 else -0.6)
        sim.step(0.1)
    log = sim.kinematics()
    origin = sim.odom_origin
    c, s = math.cos(origin[2]), math.sin(origin[2])
    odom = sim.odom_pose
    odom_map = origin[:2] + np.array([c * odom[0] - s * odom[1], s * odom[0] + c * odom[1]])
    error = np.hypot(*(odom_map - sim.pose[:2]))
    assert log.path_length() > 4.0
    assert error < 0.03 * log.path_length()
    assert error > 1e-5  # Integrated from the wheels, not copied from the truth.
    assert np.abs(log.odom_pose[-1] - odom).max() < 1e-9


def test_collisions_are_counted(box_room):
    folder, interior = box_room
    sim = Simulator(folder)
    sim.reset((interior[2] - 1.0, 2.2, 0.0))  # Facing the east wall, 1 m away.
    sim.command(0.3, 0.0)
    sim.step(6.0)
    assert sim.collisions == 1  # One long push against the wall is one collision.
    assert sim.pose[0] < interior[2]  # It did not pass through.
    assert sim.is_upright
    sim.command(-0.3, 0.0)
    sim.step(1.5)
    assert not sim.in_collision
    sim.command(0.3, 0.0)
    sim.step(3.0)
    assert sim.collisions == 2


def test_same_commands_same_trajectory(box_room):
    folder, _ = box_room
    runs = []
    for _ in range(2):
        sim = Simulator(folder, SimConfig(seed=4))
        rng = np.random.default_rng(1)
        for _ in range(40):
            sim.command(rng.uniform(-0.5, 0.5), rng.uniform(-1.8, 1.8))
            sim.step(0.1)
        runs.append((sim.kinematics().as_table(), sim.latest_scan.ranges))
    assert np.array_equal(runs[0][0], runs[1][0])
    assert np.array_equal(runs[0][1], runs[1][1])



def test_sleeping_keeps_the_robot_awake_and_its_trajectory(box_room, monkeypatch):
    """MuJoCo's sleeping (on since the walls are static) never puts the robot to sleep,
    even after standing still, and leaves its trajectory, wall pushes included, the same
    bit for bit as with sleeping off."""
    import mujoco

    from mjexplore.sim import simulator as simulator_module

    folder, interior = box_room

    def run():
        sim = Simulator(folder, SimConfig(seed=4))
        sim.reset((interior[2] - 1.0, 2.2, 0.0))  # Facing the east wall, 1 m away.
        sim.step(3.0)  # At rest long enough for an automatic policy to sleep it.
        awake = int(sim.data.ntree_awake)
        sim.command(0.3, 0.0)
        sim.step(6.0)  # Into the wall and pushing against it.
        rng = np.random.default_rng(1)
        for _ in range(40):
            sim.command(rng.uniform(-0.5, 0.5), rng.uniform(-1.8, 1.8))
            sim.step(0.1)
        return sim, awake, sim.kinematics().as_table(), sim.latest_scan.ranges

    sim, awake, table, ranges = run()
    assert sim.model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
    assert awake == sim.model.ntree == 1
    assert sim.collisions >= 1  # The wall was pushed against.
    monkeypatch.setattr(simulator_module, "keep_awake", lambda model, body: None)
    plain, _, plain_table, plain_ranges = run()
    assert not plain.model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
    assert np.array_equal(table, plain_table)
    assert np.array_equal(ranges, plain_ranges)


def test_scans_arrive_at_the_lidar_rate_in_simulated_time(box_room):
    folder, _ = box_room
    sim = Simulator(folder)
    scans = sim.step(1.0)
    assert [round(s.stamp, 6) for s in scans] == [round(0.1 * k, 6) for k in range(1, 11)]
    assert sim.time == pytest.approx(1.0)


def test_rates_must_fit_the_physics_step(box_room):
    folder, _ = box_room
    with pytest.raises(UserInputError, match="whole number of physics steps"):
        Simulator(folder, SimConfig(sample_rate_hz=30.0))


def test_kinematic_mode_stops_at_unknown_ground_truth(tmp_path):
    """On an imported map, unknown cells are walls in the MJCF: the kinematic world must
    not drive into them (it used to treat them as free)."""
    from mjexplore.maps import FREE, OCCUPIED, UNKNOWN, GridMap
    from mjexplore.scenes.importer import scene_from_grid
    from mjexplore.scenes.scene import load_scene_files, write_scene

    data = np.full((60, 120), FREE, np.int8)  # 6 x 3 m at 0.05 m.
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = OCCUPIED
    data[1:-1, 80:90] = UNKNOWN  # An unknown strip from x = 4.0 m to 4.5 m.
    scene = scene_from_grid(GridMap(data, 0.05), "strip", {"source": "test"},
                            start=(1.0, 1.5, 0.0))
    files = load_scene_files(write_scene(scene, tmp_path / "strip"))
    sim = Simulator(files, SimConfig(dynamics="kinematic"))
    sim.reset((1.0, 1.5, 0.0))
    sim.command(0.5, 0.0)
    for _ in range(200):  # 20 s at 0.5 m/s: would reach x = 5.5 m through the strip.
        sim.step(0.1)
    front = sim.pose[0] + BODY_CENTRE_X + BODY_RADIUS  # The body circle's leading edge.
    assert 3.9 <= front <= 4.0 + 1e-6
    assert sim.in_collision


def test_a_body_touching_a_wall_may_move_away_from_it_but_not_nearer():
    from mjexplore.maps import FREE, OCCUPIED, GridMap
    from mjexplore.sim.motion import BODY_RADIUS, body_clearance, kinematic_step, wall_clearance

    data = np.full((40, 40), FREE, np.int8)
    data[:, :5] = OCCUPIED  # A wall along x = 0.25 m.
    gt = GridMap(data, 0.05)
    clearance = wall_clearance(gt)
    # Facing +x with the body closer to the wall than its radius (as a grid cell's
    # quantisation can leave it): forward takes it away, backward nearer.
    pose = (0.25 + BODY_RADIUS - 0.03 + 0.064, 1.0, 0.0)
    assert body_clearance(clearance, gt, *pose) < BODY_RADIUS
    moved, _, _, refused = kinematic_step(clearance, gt, pose, (0.5, 0.0), 0.1)
    assert not refused and moved[0] > pose[0]
    _, _, _, refused = kinematic_step(clearance, gt, pose, (-0.5, 0.0), 0.1)
    assert refused
