import math

import numpy as np
import pytest
from conftest import box_room_grid

from mjexplore.errors import UserInputError
from mjexplore.robot import TURTLEBOT3_WAFFLE
from mjexplore.scenes.importer import scene_from_grid
from mjexplore.scenes.scene import write_scene
from mjexplore.sim.odometry import (
    ODOMETRY_ERRORS,
    WheelOdometry,
    compose_pose,
    gyro,
    odom_in_map,
    odometry_error,
    relative_pose,
    wheel_odometry,
)
from mjexplore.sim.simulator import SimConfig, Simulator

RUN_M = 10.0
TYPICAL = ODOMETRY_ERRORS["typical"]


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    """A 12 x 2 m room: 10 m of straight run along x."""
    grid, _ = box_room_grid(inner_w=12.0, inner_h=2.0)
    out = tmp_path_factory.mktemp("hall") / "scene"
    write_scene(scene_from_grid(grid, "hall", {"source": "test"}, start=(0.8, 1.2, 0.0)), out)
    return out


def drive_straight(folder, **config) -> Simulator:
    """Drives 10 m straight ahead at 0.5 m/s in full physics and stops."""
    sim = Simulator(folder, SimConfig(**config))
    start = sim.pose.copy()
    while np.hypot(*(sim.pose[:2] - start[:2])) < RUN_M - 0.05:  # The stop takes 5 cm.
        sim.command(0.5, 0.0)
        sim.step(0.05)
    sim.command(0.0, 0.0)
    sim.step(1.0)
    return sim


def odometry_in_map(sim: Simulator) -> np.ndarray:
    return odom_in_map(sim.odom_origin, sim.odom_pose[None])[0]


def test_no_error_is_the_exact_odometry_whatever_the_seed(hall):
    exact = drive_straight(hall, seed=0)
    again = drive_straight(hall, seed=7, odometry_error="none")
    assert exact.odometry.error is None
    assert np.array_equal(exact.kinematics().odom_pose, again.kinematics().odom_pose)
    # Exact geometry: only the soft contacts' creep, well under 0.5 % of the run.
    run = np.hypot(*(exact.pose[:2] - exact.odom_origin[:2]))
    assert run == pytest.approx(RUN_M, abs=0.02)
    assert np.hypot(*(odometry_in_map(exact)[:2] - exact.pose[:2])) < 0.005 * RUN_M


def test_typical_error_drifts_within_its_band_and_differs_between_seeds(hall):
    exact = drive_straight(hall)
    creep = np.hypot(*(odometry_in_map(exact)[:2] - exact.pose[:2]))
    bound = TYPICAL.straight_drift_bound(RUN_M)
    b = TURTLEBOT3_WAFFLE.wheel_separation
    ends = []
    for seed in (1, 2, 3):
        sim = drive_straight(hall, seed=seed, odometry_error="typical")
        assert np.array_equal(sim.pose, exact.pose)  # The errors are the odometry's only.
        end = odometry_in_map(sim)
        drift = np.hypot(*(end[:2] - sim.pose[:2]))
        assert creep < drift <= bound + creep
        # The heading error is the drawn wheels' curvature over the run, give or take
        # the random slip's three standard deviations.
        e = sim.odometry.error
        curvature = (e.right_scale - e.left_scale) / (b * e.track_scale)
        slip_heading_std = math.sqrt(2 * TYPICAL.slip_variance * RUN_M) / b
        assert end[2] - sim.pose[2] == pytest.approx(curvature * RUN_M,
                                                     abs=3 * slip_heading_std + 1e-3)
        ends.append(end)
    for i in range(3):
        for j in range(i):
            assert np.hypot(*(ends[i][:2] - ends[j][:2])) > 0.05


def test_error_spread_matches_the_documented_magnitudes():
    """300 robots each drive 10 m straight (wheel angles fed directly): the spread of
    their odometry's end points is the configured one."""
    r = TURTLEBOT3_WAFFLE.wheel_radius
    steps = 400
    ends = []
    for seed in range(300):
        odom = WheelOdometry(error=odometry_error("typical", seed))
        odom.reset(np.zeros(2), 0.0)
        for k in range(1, steps + 1):
            angle = k * RUN_M / steps / r
            odom.update(np.array([angle, angle]), k * 0.05)
        ends.append(odom.pose)
    ends = np.array(ends)
    along, cross = TYPICAL.straight_drift_std(RUN_M)
    assert np.std(ends[:, 0] - RUN_M) == pytest.approx(along, rel=0.15)
    assert np.std(ends[:, 1]) == pytest.approx(cross, rel=0.15)
    assert np.hypot(ends[:, 0] - RUN_M, ends[:, 1]).max() <= TYPICAL.straight_drift_bound(RUN_M)


def test_gyro_heading_spread_matches_the_documented_magnitudes():
    """300 robots with a gyro heading stand still for 100 s, then turn in place by 2 pi
    while their wheels slip and their track width is off: the heading errors are the
    gyro's (bias and noise, then its scale), not the wheels'."""
    r, b = TURTLEBOT3_WAFFLE.wheel_radius, TURTLEBOT3_WAFFLE.wheel_separation
    still, turned, wheels_only = [], [], []
    for seed in range(300):
        errors = odometry_error("typical", seed)
        odom = WheelOdometry(error=errors, gyro=gyro("typical", seed))
        wheels = WheelOdometry(error=errors)
        for o in (odom, wheels):
            o.reset(np.zeros(2), 0.0, true_yaw=0.5)
        for k in range(1, 2001):  # 100 s at 20 Hz.
            odom.update(np.zeros(2), k * 0.05, true_yaw=0.5)
        still.append(odom.pose[2])
        start = odom.pose[2]
        for k in range(1, 201):  # 2 pi in 10 s.
            yaw = 0.5 + 2 * math.pi * k / 200
            angle = (2 * math.pi * k / 200) * b / 2 / r
            for o in (odom, wheels):
                o.update(np.array([-angle, angle]), 100.0 + k * 0.05, true_yaw=yaw)
        turned.append(odom.pose[2] - start - odom.gyro.bias * 10.0)
        wheels_only.append(wheels.pose[2])
    still = np.array(still)
    turned = np.array([math.remainder(t - 2 * math.pi, 2 * math.pi) for t in turned])
    assert np.std(still) == pytest.approx(TYPICAL.gyro_heading_std(100.0), rel=0.15)
    assert np.std(turned) == pytest.approx(2 * math.pi * TYPICAL.gyro_scale_std, rel=0.15)
    # The wheels' heading over the same turn is off by their track width's and mean
    # radius's errors.
    wheel_turn = np.array([math.remainder(t, 2 * math.pi) for t in wheels_only])
    assert np.std(wheel_turn) == pytest.approx(
        2 * math.pi * math.hypot(TYPICAL.track_std, TYPICAL.wheel_scale_std), rel=0.15)


def test_gyro_heading_in_physics_differs_between_seeds_and_keeps_the_wheel_errors(hall):
    wheels = drive_straight(hall, seed=1, odometry_error="typical")
    ends = []
    for seed in (1, 2):
        sim = drive_straight(hall, seed=seed, odometry_error="typical",
                             odometry_heading="imu")
        assert np.array_equal(sim.pose, wheels.pose)
        end = odometry_in_map(sim)
        # 10 m straight: the heading is off by the gyro's bias and noise over the run
        # (about 21 s), not by the wheels' curvature.
        g = sim.odometry.gyro
        assert end[2] - sim.pose[2] == pytest.approx(
            g.bias * sim.time, abs=3 * TYPICAL.gyro_noise_density * math.sqrt(sim.time) + 2e-4)
        ends.append(end)
    # Seed 1's wheels are the same with either heading: the same distance driven.
    assert np.hypot(*(ends[0][:2] - wheels.odom_origin[:2])) == pytest.approx(
        np.hypot(*(odometry_in_map(wheels)[:2] - wheels.odom_origin[:2])), abs=1e-3)
    assert abs(ends[0][2] - ends[1][2]) > 1e-5


def test_unknown_odometry_heading_is_refused():
    with pytest.raises(UserInputError, match="wheels, imu"):
        SimConfig(odometry_heading="compass")
    with pytest.raises(ValueError, match="true yaw"):
        wheel_odometry("typical", "imu", 0).reset(np.zeros(2), 0.0)


def test_unknown_odometry_error_is_refused():
    with pytest.raises(UserInputError, match="none, typical"):
        SimConfig(odometry_error="bad")


def test_pose_composition_inverts():
    a = np.array([1.0, -2.0, 2.5])
    b = np.array([-0.3, 4.0, -2.9])
    assert np.allclose(compose_pose(a, relative_pose(a, b)), b)
    assert np.allclose(relative_pose(a, compose_pose(a, b)), b)
